"""Shared test set-up. The tests live by package and kind (estimators/, ingest/,
conditioning/, outputs/, sim/, closed_loop/, cli/); helpers shared by several folders
(_simdata: simulated flights cached per session, _roll) sit here, importable from every
folder because pytest puts this file's folder on sys.path.

Tiers: ``slow`` marks a test that flies JSBSim through a whole estimate, fuzzes a format a
thousand times or otherwise takes more than a few seconds; every test in closed_loop/ is
slow. ``make test-fast`` runs the rest (the edit loop, under a minute); ``make test`` all."""

from __future__ import annotations

from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
#: folders whose every test is slow
SLOW_FOLDERS = ("closed_loop",)


def pytest_collection_modifyitems(config, items):
    for item in items:
        rel = Path(str(item.fspath)).resolve().relative_to(HERE)
        if rel.parts[0] in SLOW_FOLDERS:
            item.add_marker(pytest.mark.slow)
