"""Wall time of the filter-error method, EKF and UKF against our output-error fit on the
problem of ``benchmarks/oem_speed.py``.

Problem: the HFB-320-like nonlinear longitudinal case of ``estimators.datasets`` (600
samples, 7 outputs, 11 free derivatives, starts 30% off, calm air). OEM: Gauss-Newton
with RK4 (as in oem_speed.py). FEM: nonlinear form (compiled RK4 prediction, constant
gain of the trim linearisation), process noise F estimated on every measured state
(it goes to zero: calm air) together with the 7 measurement-noise std - 22 unknowns
against OEM's 11. EKF/UKF: passes until the estimates settle (the default), sensor-noise std given, no
process noise; EKF-py, UKF-py with their per-sample Python loop instead of the compiled
segment loop (``compiled=False``; the noise-augmented UKF has only the Python loop).
Everything is compiled once before timing. Prints the median times over the runs, the
ratios to OEM (total and, for FEM, per Gauss-Newton iteration), and the largest
difference of each method's estimates from OEM's in OEM std. Target: FEM <= 3x OEM per
iteration. The last line is that ratio.

    python benchmarks/filters_speed.py [--runs 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from estimators import EKF, UKF, FilterError, OutputError
from estimators.datasets import HFB320_FREE, HFB320_NOISE, longitudinal_example


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    names = list(HFB320_FREE)
    ex = longitudinal_example(seed=7)
    sd = [HFB320_NOISE[o] for o in ex.model.outputs]
    methods = {
        "OEM": lambda: OutputError(ex.model),
        "FEM": lambda: FilterError(ex.model, form="nonlinear"),
        "EKF": lambda: EKF(ex.model, measurement_noise=sd),
        "EKF-py": lambda: EKF(ex.model, measurement_noise=sd, compiled=False),
        "UKF": lambda: UKF(ex.model, measurement_noise=sd),
        "UKF-py": lambda: UKF(ex.model, measurement_noise=sd, compiled=False),
        "UKF-aug": lambda: UKF(ex.model, measurement_noise=sd, augmented=True),
    }
    for make in methods.values():  # compile once (numba), not timed
        make().fit(ex.segments)
    times = {k: [] for k in methods}
    iters = {k: [] for k in methods}
    results = {}
    for run in range(args.runs):
        for name, make in methods.items():
            t0 = time.perf_counter()
            res = make().fit(ex.segments)
            times[name].append(time.perf_counter() - t0)
            iters[name].append(res.iterations)
            results[name] = res
        print(f"run {run}: " + ", ".join(f"{k} {v[-1]:.3f} s" for k, v in times.items()))
    oem = results["OEM"]
    t_oem = float(np.median(times["OEM"]))
    it_oem = float(np.median(iters["OEM"]))
    print(f"\n{'method':<9}{'median s':>10}{'iterations':>12}{'x OEM':>8}{'max |diff| / OEM std':>23}")
    for name in methods:
        t = float(np.median(times[name]))
        diff = max(abs(results[name].params[n] - oem.params[n]) / oem.std[n] for n in names)
        it = float(np.median(iters[name]))
        it_s = f"{it:.0f}" if name in ("OEM", "FEM") else f"{it:.0f} pass{'es' if it > 1 else ''}"
        print(f"{name:<9}{t:>10.3f}{it_s:>12}{t / t_oem:>8.2f}{diff:>23.2f}")
    fem_per_it = float(np.median(np.array(times["FEM"]) / np.array(iters["FEM"])))
    ratio = fem_per_it / (t_oem / it_oem)
    print(f"\nper Gauss-Newton iteration: OEM {1e3 * t_oem / it_oem:.1f} ms, FEM {1e3 * fem_per_it:.1f} ms")
    for f in ("EKF", "UKF"):
        print(
            f"{f} compiled segment loop / per-sample Python loop: "
            f"{np.median(times[f]) / np.median(times[f + '-py']):.2f}"
        )
    print(f"FEM / OEM wall time per iteration: {ratio:.2f} (target <= 3)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
