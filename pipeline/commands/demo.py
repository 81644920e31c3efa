"""``fsid demo``: ``fsid run scenarios/default.toml`` into a fresh folder."""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.commands.arguments import print_outputs
from pipeline.errors import FsidError
from pipeline.jobs.failures import failure_recorded
from pipeline.paths import new_run_dir

HELP = "the main job on the built-in default scenario (no arguments needed)"


def default_scenario() -> Path:
    """scenarios/default.toml of this checkout."""
    path = Path(__file__).resolve().parents[2] / "scenarios" / "default.toml"
    if not path.exists():
        raise FsidError(f"built-in scenario {path} is missing: reinstall from the repository")
    return path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", help="output folder (default: a new folder under ./runs/)")


def run(args: argparse.Namespace) -> int:
    from pipeline.jobs.scenario import run_scenario  # the job loads numba, scipy, pandas: on use only

    out = new_run_dir("demo", args.out)
    with failure_recorded(out, "demo"):
        paths = run_scenario(default_scenario(), out)
    print_outputs(out, paths)
    print(f"\nreport:    {paths['report.md']}\nrecording: {paths['run.rrd']}  (open with: fsid view {out})")
    return 0
