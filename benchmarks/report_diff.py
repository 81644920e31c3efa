"""Is a change behaviour-neutral? report.json of ``fsid demo`` and of ``fsid run`` on every
built-in scenario (seeds fixed by the scenarios), made by two revisions of the code and
compared field by field, timing fields and each run's own id left out.

``--base REV`` (default HEAD) is checked out into a temporary git worktree and run with the
same interpreter, its tree first on the path; the other side is the working tree.
Prints per report the number of differing fields and the first few (path: base -> new),
numbers equal when within ``--rtol`` (default 0: identical); the last line counts the
reports that are identical. ``--scenarios`` picks some; ``--keep DIR`` keeps the runs, and a
report already in DIR is not made again (so one base run serves many comparisons).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: keys whose values are wall-clock times (left out of the comparison)
TIMING_KEYS = ("seconds", "elapsed", "wall", "duration", "timing_s", "created")
#: keys that name one run (differ between any two runs by design)
IDENTITY_KEYS = ("run_id",)


def _timing(key: str) -> bool:
    k = key.lower()
    return k in IDENTITY_KEYS or any(t in k for t in TIMING_KEYS)


def differences(a, b, rtol: float = 0.0, path: str = "") -> list[str]:
    """The paths where the JSON values a and b differ (timing keys skipped)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if _timing(str(k)):
                continue
            if k not in a or k not in b:
                out.append(
                    f"{path}/{k}: {'missing' if k not in a else 'present'} -> {'missing' if k not in b else 'present'}"
                )
                continue
            out += differences(a[k], b[k], rtol, f"{path}/{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: length {len(a)} -> {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in differences(x, y, rtol, f"{path}[{i}]")]
    if isinstance(a, float) and isinstance(b, float):
        same = a == b or (math.isnan(a) and math.isnan(b)) or abs(a - b) <= rtol * max(abs(a), abs(b))
        return [] if same else [f"{path}: {a!r} -> {b!r}"]
    return [] if a == b else [f"{path}: {a!r} -> {b!r}"]


def run_all(tree: Path, out: Path, scenarios: list[str], reuse: bool = False) -> None:
    """fsid demo and fsid run of each scenario with ``tree``'s code into ``out``."""
    env = {**os.environ, "PYTHONPATH": str(tree) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    cli = [sys.executable, "-c", "import sys; from pipeline.cli import main; sys.exit(main())"]
    jobs = [("demo", ["demo"])] + [(s, ["run", str(tree / "scenarios" / f"{s}.toml"), "--quiet"]) for s in scenarios]
    for name, args in jobs:
        if reuse and (out / name / "report.json").exists():  # the base kept from an earlier run
            continue
        r = subprocess.run(cli + args + ["--out", str(out / name)], cwd=tree, env=env, capture_output=True, text=True)
        if r.returncode != 0:
            print(f"{tree.name}: {name} failed: {r.stderr.strip().splitlines()[-1:]}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="HEAD")
    ap.add_argument("--scenarios", nargs="*", default=None)
    ap.add_argument("--rtol", type=float, default=0.0)
    ap.add_argument("--keep", default=None)
    a = ap.parse_args()
    names = a.scenarios if a.scenarios is not None else sorted(p.stem for p in (ROOT / "scenarios").glob("*.toml"))
    work = Path(a.keep or tempfile.mkdtemp(prefix="fsid-diff-"))
    base_tree = work / "base-tree"
    if not base_tree.exists() and not all((work / "base" / n / "report.json").exists() for n in ["demo"] + names):
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(base_tree), a.base], cwd=ROOT, check=True, capture_output=True
        )
    try:
        run_all(base_tree, work / "base", names, reuse=True)
        shutil.rmtree(work / "new", ignore_errors=True)
        run_all(ROOT, work / "new", names)
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(base_tree)], cwd=ROOT, capture_output=True)
    same = 0
    for name in ["demo"] + names:
        fa, fb = work / "base" / name / "report.json", work / "new" / name / "report.json"
        if not (fa.exists() and fb.exists()):
            print(f"{name}: report.json missing ({'base' if not fa.exists() else 'new'})")
            continue
        d = differences(json.loads(fa.read_text()), json.loads(fb.read_text()), a.rtol)
        same += not d
        print(f"{name}: {'identical' if not d else f'{len(d)} fields differ'}" + "".join(f"\n    {x}" for x in d[:8]))
    print(f"{same}/{len(names) + 1} reports identical (timing fields and run ids left out) against {a.base}")
    return 0 if same == len(names) + 1 else 1


if __name__ == "__main__":
    sys.exit(main())
