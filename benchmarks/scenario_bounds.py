"""Are the bounds in a report honest? ``fsid run`` on every built-in scenario, then every
estimate in report.json that has a truth - each method's parameters, the compatibility
stage's sensor errors and their refit - is either within 3 of its reported std or belongs
to a fit the tool itself FAILs (verdict level FAIL; the compatibility stage has no
verdict, so its estimates must be within 3 std or carry no std).

Prints per scenario the estimates beyond 3 std in fits not FAILed (the violations) and
the count of those beyond in FAILed fits; the last line is the number of scenarios that
hold. ``--scenarios`` picks some; ``--keep DIR`` keeps the run folders.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
K = 3.0


def beyond(report: dict) -> tuple[list[str], list[str]]:
    """(violations, excused): estimates with a truth beyond K std, in fits not FAILed and
    in FAILed fits."""
    bad, excused = [], []
    for key, m in report.get("methods", {}).items():
        failed = (m.get("verdict") or {}).get("level") == "FAIL"
        for name, p in m.get("parameters", {}).items():
            tr, est, sd = p.get("truth"), p.get("estimate"), p.get("total_std") or p.get("std")
            if tr is None or est is None or not sd:
                continue
            z = abs(est - tr) / sd
            if z > K:
                (excused if failed else bad).append(f"{key} {name} {z:.1f}")
    comp = report.get("compatibility") or {}
    for part, rows in (
        ("compatibility", comp.get("parameters") or {}),
        ("compatibility refit", (comp.get("refit") or {}).get("parameters") or {}),
    ):
        for name, row in rows.items():
            tr, est, sd = row.get("truth"), row.get("estimate"), row.get("std")
            if tr is None or est is None or not sd:
                continue
            z = abs(est - tr) / sd
            if z > K:
                bad.append(f"{part} {name} {z:.1f}")
    return bad, excused


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="*", default=None)
    ap.add_argument("--keep", default=None)
    a = ap.parse_args()
    names = a.scenarios or sorted(p.stem for p in (ROOT / "scenarios").glob("*.toml"))
    base = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="fsid-bounds-"))
    fsid = Path(sys.executable).with_name("fsid")
    held = 0
    for name in names:
        out = base / name
        r = subprocess.run(
            [str(fsid), "run", str(ROOT / "scenarios" / f"{name}.toml"), "--out", str(out)],
            capture_output=True,
            text=True,
        )
        if r.returncode != 0 or not (out / "report.json").exists():
            print(f"{name}: fsid run failed ({r.returncode}): {r.stderr.strip().splitlines()[-1:]}")
            continue
        bad, excused = beyond(json.loads((out / "report.json").read_text()))
        held += not bad
        print(
            f"{name}: {'holds' if not bad else 'VIOLATED'}; beyond {K:g} std in FAILed fits: "
            f"{len(excused)}" + ("".join(f"\n    {b}" for b in bad))
        )
    print(f"{held}/{len(names)} scenarios hold (every estimate with a truth within {K:g} std or in a FAILed fit)")
    return 0 if held == len(names) else 1


if __name__ == "__main__":
    sys.exit(main())
