"""The README and docs/: short README with the own-log walkthrough up front, links that
resolve, commands that exist, and a Python example that runs."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from pipeline.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]


def test_readme_is_short_with_the_own_log_walkthrough_first():
    lines = README.read_text().splitlines()
    assert len(lines) <= 300
    start = next(i for i, line in enumerate(lines) if line.startswith("## Your own log"))
    end = next(i for i, line in enumerate(lines) if i > start and line.startswith("## "))
    assert end <= 120, f"the walkthrough ends at line {end}"
    steps = [line for line in lines[start:end] if re.match(r"\*\*\d\. ", line)]
    assert len(steps) == 5
    walkthrough = "\n".join(lines[start:end])
    for command in ("fsid aircraft init", "fsid fields", "fsid check", "fsid estimate", "fsid view"):
        assert command in walkthrough


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_relative_links_resolve(page):
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text()):
        if "://" in target:
            continue
        assert (page.parent / target).exists(), f"{page.name} links to missing {target}"


def test_readme_links_every_docs_page():
    text = README.read_text()
    for page in (ROOT / "docs").glob("*.md"):
        assert f"docs/{page.name}" in text, f"README does not link docs/{page.name}"


def test_commands_in_the_readme_exist():
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    used = set(re.findall(r"^\s*fsid ([a-z]+)", README.read_text(), flags=re.M))
    assert used - {"-"} <= set(sub.choices), used - set(sub.choices)


def test_the_readme_python_example_runs():
    block = re.search(r"## Python API in 20 lines\n\n```python\n(.*?)```", README.read_text(), flags=re.S)
    code = block.group(1)
    assert len(code.splitlines()) <= 20
    scope: dict = {}
    exec(compile(code, "README.md", "exec"), scope)
    res = scope["res"]
    assert res.converged
    truth = scope["ex"].truth["Cmq"]
    assert abs(res.params["Cmq"] - truth) < 4 * res.std["Cmq"]
