"""Simulated seconds per wall-clock second for the built-in ``default`` scenario.

Measures the whole `fsid simulate` work: JSBSim trim and flight, sensor models, writing
flight.mcap and flight.bin (truth.json is small and left out). Median of 5 runs after one
warm-up; the breakdown shows where the time goes. One more line times the JSBSim steps
alone (the flight's n_steps * substeps calls of FGFDMExec.run after the trim, no property
reads, no sensors, no writers): the floor JSBSim itself sets. The ratio is printed last.
Target: >= 300.

Run: ``.venv/bin/python benchmarks/sim_speed.py`` (2 cores shared with other work; the
wall figure moves with their load, the CPU figure less so).

Measured:
* before 2026-11-27: 137 (MCAP writer 38 % of the time, one mcap Writer.add_message per
  message; JSBSim properties read into a Python list per sample).
* 2026-11-27: 149-174 (fly 266-296 ms, mcap 65-70 ms, bin 12-14 ms; CPU 152-177
  simulated s per CPU s). The code before, run alternately with it under the same load:
  102-112 (mcap 203-232 ms). JSBSim steps alone: 208-260 ms, 231-289x, so the target
  is out of reach on this machine while default.toml's 6000 samples * 6 substeps =
  36000 FGFDMExec.run calls take longer than 200 ms; the rest (property reads, truth
  table, sensors, writers, the temporary JSBSim folder) is about 140 ms.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import sim  # noqa: E402
from pipeline.outputs.writers import write_dataflash, write_mcap  # noqa: E402


def jsbsim_steps(scenario) -> float:
    """Wall time (s) of the flight's JSBSim steps alone: trim as ``sim.fly`` does, then
    n_steps * substeps calls of FGFDMExec.run with nothing read or set in between."""
    from sim.flight import _make_fdm, _quiet_stdout, _trim

    with tempfile.TemporaryDirectory() as tmp:
        with _quiet_stdout():
            fdm = _make_fdm(scenario, Path(tmp))
            _trim(fdm, scenario)
        fdm["fcs/servo-quantize"] = 1.0
        run = fdm.run
        n = int(round(scenario.duration * scenario.rate_hz)) * scenario.substeps
        t0 = time.perf_counter()
        for _ in range(n):
            run()
        return time.perf_counter() - t0


def main(runs: int = 5) -> float:
    scenario = sim.load_scenario(ROOT / "scenarios" / "default.toml")
    parts: dict[str, list[float]] = {"fly": [], "mcap": [], "bin": [], "total": []}
    cpu: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(runs + 1):
            c0 = time.process_time()
            t0 = time.perf_counter()
            result = sim.fly(scenario)
            t1 = time.perf_counter()
            write_mcap(Path(tmp) / "flight.mcap", result)
            t2 = time.perf_counter()
            write_dataflash(Path(tmp) / "flight.bin", result)
            t3 = time.perf_counter()
            c3 = time.process_time()
            if k:
                cpu.append(c3 - c0)  # the first run warms caches and imports
                for key, v in zip(parts, (t1 - t0, t2 - t1, t3 - t2, t3 - t0)):
                    parts[key].append(v)
    med = {k: statistics.median(v) for k, v in parts.items()}
    print(f"scenario default: {scenario.duration:g} s simulated at {scenario.rate_hz:g} Hz, median of {runs} runs")
    for k in ("fly", "mcap", "bin"):
        print(f"  {k:5s} {med[k] * 1e3:7.1f} ms  ({med[k] / med['total']:.0%})")
    ratio = scenario.duration / med["total"]
    from dataclasses import replace

    one = replace(scenario, substeps=1)
    t_one = []
    for _ in range(runs):
        t0 = time.perf_counter()
        sim.fly(one)
        t_one.append(time.perf_counter() - t0)
    alt = med["total"] - med["fly"] + statistics.median(t_one)
    print(
        f"  (with substeps = 1, less faithful integration: fly {statistics.median(t_one) * 1e3:.1f} ms, "
        f"{scenario.duration / alt:.0f} simulated s per wall s)"
    )
    print(
        f"  (CPU time {statistics.median(cpu) * 1e3:.1f} ms: {scenario.duration / statistics.median(cpu):.0f} "
        "simulated s per CPU s; wall time grows when other processes share the cores)"
    )
    t_jsb = statistics.median(jsbsim_steps(scenario) for _ in range(runs))
    print(
        f"  (JSBSim steps alone: {t_jsb * 1e3:.1f} ms, {scenario.duration / t_jsb:.0f} simulated s per wall s; "
        "the ceiling of the ratio below)"
    )
    print(f"sim_speed: {ratio:.0f} simulated seconds per wall second (target >= 300)")
    return ratio


if __name__ == "__main__":
    main()
