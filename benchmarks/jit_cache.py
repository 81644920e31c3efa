"""What the on-disk kernel cache saves: ``fsid run scenarios/<scenario>.toml`` (the demo's
job by default) in a fresh Python process, three ways:

* in memory (``FSID_JIT_CACHE=0``): every model compiled with numba in every run, as
  before the cache (the baseline);
* cold: an empty cache folder, so the run compiles and writes its kernels;
* warm: the same folder again, so the run loads what the cold run compiled.

Prints wall time of each and the ratios to the baseline (warm last: the headline), and
checks that the three runs' report.json estimates are identical. Each run is a separate
process, so the numbers include Python start-up, the flight simulation and the I/O.

    python benchmarks/jit_cache.py [--scenario default] [--method ...]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(scenario: Path, out: Path, cache: Path, methods: list[str], **env: str) -> float:
    e = {**os.environ, "FSID_CACHE_DIR": str(cache), **env}
    e.pop("FSID_JIT", None)
    cmd = [sys.executable, "-m", "pipeline.cli", "run", str(scenario), "--out", str(out), "--quiet"]
    for m in methods:
        cmd += ["--method", m]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=ROOT, env=e, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        sys.exit(f"fsid run failed ({out.name}): {r.stderr.strip()[-500:]}")
    return dt


def estimates(out: Path) -> dict:
    rep = json.loads((out / "report.json").read_text())
    return {k: {n: p["estimate"] for n, p in m["parameters"].items()} for k, m in rep["methods"].items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="default")
    ap.add_argument("--method", action="append", default=[])
    a = ap.parse_args()
    scenario = ROOT / "scenarios" / f"{a.scenario}.toml"
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        times = {
            "in memory": run(scenario, tmp / "mem", tmp / "mem_cache", a.method, FSID_JIT_CACHE="0"),
            "cold": run(scenario, tmp / "cold", tmp / "cache", a.method),
            "warm": run(scenario, tmp / "warm", tmp / "cache", a.method),
        }
        same = estimates(tmp / "mem") == estimates(tmp / "cold") == estimates(tmp / "warm")
        n_files = len(list((tmp / "cache" / "kernels").glob("*.py")))
    base = times["in memory"]
    print(f"fsid run {scenario.name}: {n_files} kernel modules cached; estimates identical in the three runs: {same}")
    for k, v in times.items():
        print(f"  {k:10s} {v:6.1f} s   {v / base:5.2f} x in memory")
    print(f"warm / in-memory wall time: {times['warm'] / base:.2f}")


if __name__ == "__main__":
    main()
