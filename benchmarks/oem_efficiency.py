"""Statistical efficiency of the output-error method (Monte Carlo over noise seeds).

Problem: the HFB-320-like nonlinear longitudinal case of ``estimators.datasets``
(600 samples, 7 outputs, 11 free derivatives, starts 30% off), truth simulated with the
package's own RK4, white Gaussian noise on every output. For every parameter the script
prints the empirical std of the estimates over the seeds divided by the mean Cramér-Rao
std (an efficient, honest estimator gives 1) and the mean error in units of the empirical
std. Targets: ratio in [0.8, 1.25], |mean error| < 0.3 std. The last line is the worst
ratio.

    python benchmarks/oem_efficiency.py [--seeds 100] [--integrator rk4]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from estimators import OutputError
from estimators.datasets import HFB320_FREE, longitudinal_example


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--integrator", default="rk4")
    ap.add_argument("--seed-base", type=int, default=1000)
    args = ap.parse_args()
    names = list(HFB320_FREE)
    est, std, iters = [], [], []
    t0 = time.perf_counter()
    truth = None
    for seed in range(args.seeds):
        ex = longitudinal_example(seed=args.seed_base + seed, integrator=args.integrator)
        res = OutputError(ex.model, integrator=args.integrator).fit(ex.segments)
        if not res.converged:
            print(f"seed {seed}: not converged ({res.message})")
        est.append(res.params[names].to_numpy())
        std.append(res.std[names].to_numpy())
        iters.append(res.iterations)
        truth = np.array([ex.truth[n] for n in names])
    est, std = np.array(est), np.array(std)
    emp = est.std(axis=0, ddof=1)
    crb = std.mean(axis=0)
    ratio = emp / crb
    bias = (est.mean(axis=0) - truth) / emp
    print(
        f"OEM Monte Carlo: {args.seeds} seeds, 600 samples, 7 outputs, {len(names)} parameters, "
        f"{args.integrator}; {time.perf_counter() - t0:.1f} s, iterations median "
        f"{int(np.median(iters))} max {max(iters)}"
    )
    print(
        f"{'parameter':<10}{'truth':>10}{'mean est':>12}{'emp std':>11}{'mean CRB':>11}{'ratio':>8}{'bias/std':>10}  ok"
    )
    ok_all = True
    for i, n in enumerate(names):
        ok = 0.8 <= ratio[i] <= 1.25 and abs(bias[i]) < 0.3
        ok_all &= ok
        print(
            f"{n:<10}{truth[i]:>10.4g}{est[:, i].mean():>12.5g}{emp[i]:>11.4g}{crb[i]:>11.4g}"
            f"{ratio[i]:>8.3f}{bias[i]:>10.3f}  {'yes' if ok else 'NO'}"
        )
    worst = ratio[np.argmax(np.abs(np.log(ratio)))]
    print(f"all within targets: {'yes' if ok_all else 'NO'}")
    print(f"worst ratio (empirical std / CRB): {worst:.3f}")
    return 0 if ok_all else 1


if __name__ == "__main__":
    raise SystemExit(main())
