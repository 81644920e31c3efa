"""Statistical efficiency of the filter-error method in turbulence (Monte Carlo over seeds),
with output error on the same data for comparison.

Problem (model-simulated, ``estimators.process_noise_examples.dryden_short_period_example``):
a stable linear short period (HFB-320 class, 100 m/s) flying a 3-2-1-1 and a doublet
(1000 samples at 50 Hz) in Dryden vertical turbulence (sigma_w = 1.5 m/s, L = 150 m,
second-order Dryden shaping filter as two extra states driven by white noise), white
sensor noise on alpha, q, qdot, az; 5 free derivatives, starts 20% off; the initial gust
state is unknown to the estimators (x0 = 0). FEM estimates the derivatives, the
gust-filter noise intensity F_g2 and the 4 measurement-noise std (linear steady-state
filter); OEM fits the same model as if the air were calm.

Per parameter: ratio = empirical std of the estimates over the seeds / mean reported
std (Cramér-Rao), and bias = (mean estimate - truth) / empirical std. Targets for FEM:
ratio in [0.7, 1.4], |bias| < 0.5. OEM is reported as it comes out (its std do not
include the turbulence, its estimates are biased). The last line is the worst FEM ratio.

    python benchmarks/fem_efficiency.py [--seeds 50] [--seed-base 2000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from estimators import FilterError, OutputError
from estimators.process_noise_examples import dryden_short_period_example


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--seed-base", type=int, default=2000)
    args = ap.parse_args()
    runs = {"FEM": ([], []), "OEM": ([], [])}
    names = None
    truth = None
    t0 = time.perf_counter()
    times = {"FEM": 0.0, "OEM": 0.0}
    failures = {"FEM": 0, "OEM": 0}
    for seed in range(args.seeds):
        ex = dryden_short_period_example(seed=args.seed_base + seed)
        F_true = ex.process_noise[3, 3]
        if names is None:
            names = [p.name for p in ex.model.parameters if p.free] + ["F_g2"]
            truth = np.array([ex.truth.get(n, F_true) for n in names])
        for method in ("FEM", "OEM"):
            ts = time.perf_counter()
            try:
                if method == "FEM":
                    res = FilterError(ex.model, process_noise={"g2": 0.5 * F_true}).fit(ex.segments)
                else:
                    res = OutputError(ex.model).fit(ex.segments)
            except Exception as exc:  # report and go on: a benchmark counts failures
                failures[method] += 1
                print(f"seed {seed}: {method} failed: {type(exc).__name__}: {exc}")
                continue
            times[method] += time.perf_counter() - ts
            if not res.converged:
                failures[method] += 1
                print(f"seed {seed}: {method} not converged ({res.message})")
            nm = names if method == "FEM" else names[:-1]
            runs[method][0].append(res.params[nm].to_numpy())
            runs[method][1].append(res.std[nm].to_numpy())
    print(
        f"{args.seeds} seeds in {time.perf_counter() - t0:.1f} s "
        f"(FEM {times['FEM'] / args.seeds:.3f} s/fit, OEM {times['OEM'] / args.seeds:.3f} s/fit); "
        f"failures: FEM {failures['FEM']}, OEM {failures['OEM']}"
    )
    worst_bias = 0.0
    for method in ("FEM", "OEM"):
        est, std = (np.array(a) for a in runs[method])
        nm = names if method == "FEM" else names[:-1]
        tr = truth[: len(nm)]
        emp = est.std(axis=0, ddof=1)
        crb = std.mean(axis=0)
        ratio = emp / crb
        bias = (est.mean(axis=0) - tr) / emp
        print(f"\n{method}: {len(est)} fits")
        print(
            f"{'parameter':<10}{'truth':>10}{'mean est':>12}{'emp std':>11}{'mean CRB':>11}{'ratio':>8}{'bias/std':>10}"
        )
        for i, n in enumerate(nm):
            print(
                f"{n:<10}{tr[i]:>10.4g}{est[:, i].mean():>12.5g}{emp[i]:>11.4g}{crb[i]:>11.4g}"
                f"{ratio[i]:>8.2f}{bias[i]:>10.2f}"
            )
        if method == "FEM":
            worst_ratio = float(ratio[np.argmax(np.abs(np.log(ratio)))])
            worst_bias = float(np.max(np.abs(bias)))
    print(f"\nFEM worst |bias|/std: {worst_bias:.2f} (target < 0.5)")
    print(f"FEM worst ratio (empirical std / mean CRB): {worst_ratio:.2f} (target 0.7-1.4)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
