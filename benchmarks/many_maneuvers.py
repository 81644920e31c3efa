"""How output error scales with the number of maneuvers G fitted at once, against the
dense bookkeeping it replaced, in the same process.

A fit of G maneuvers has the shared derivatives plus each maneuver's own initial states;
maneuver k depends on the shared ones and its own only. Two measurements per G (the HFB-320
-like longitudinal case of ``estimators.datasets``, 400 samples per maneuver, x0 of all 4
states estimated per maneuver: 11 + 4 G free parameters):

1. the information matrix and gradient (``estimators.statistics.information_and_gradient``)
   from per-segment blocks (:class:`estimators.sensitivity.Sensitivity`) against the same
   sums over dense (N, n_out, n_free) arrays; they must agree to 1e-10 relative;
2. the change of the estimates when a held value moves (a consider parameter's Jacobian
   column): one Gauss-Newton step with the fit's sensitivities
   (:meth:`estimators.OutputError.step_from`) against a refit started at the estimates;
   printed as the largest difference over the shared derivatives relative to the largest
   change.

Prints per G the times and the ratios dense/blocks and refit/step. Measured on this 2-core
machine, quiet: dense/blocks 1.6, 6.6, 22.3x at G = 4, 16, 48 (equal to 1e-17); refit/step
6.9-7.1x, the step within 2-5 % of the refit's change. (The first run, beside a filter-error
fit, printed 2.9, 262 and 281x: the dense sums' time swings with the load; in the same
process the quiet numbers are the ones to quote.)

    python benchmarks/many_maneuvers.py [--segments 4 16 48]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from estimators import OutputError
from estimators import statistics as st
from estimators.datasets import longitudinal_example


def best_of(fn, runs: int = 3) -> float:
    """The shortest wall time of ``runs`` calls [s]."""
    out = np.inf
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        out = min(out, time.perf_counter() - t0)
    return out


def one(G: int) -> dict[str, float]:
    ex = longitudinal_example(seed=3, segments=G, n=400)
    res = OutputError(ex.model).fit(ex.segments, estimate_x0=True)
    E = [r.to_numpy() for r in res.residuals]
    L = st.whitener(res.R)
    dense = [np.asarray(S) for S in res.sensitivities]
    t_blocks = best_of(lambda: st.information_and_gradient(res.sensitivities, E, L))
    t_dense = best_of(lambda: st.information_and_gradient(dense, E, L))
    F_b = st.information_and_gradient(res.sensitivities, E, L)[0]
    F_d = st.information_and_gradient(dense, E, L)[0]
    agree = float(np.max(np.abs(F_b - F_d)) / np.max(np.abs(F_d)))

    held = ex.model.hold({"CDalpha2": 0.1})
    start = {n: res.params[n] for n in res.free_names}
    t0 = time.perf_counter()
    step = OutputError(held).step_from(res, ex.segments, estimate_x0=True)
    t_step = time.perf_counter() - t0
    t0 = time.perf_counter()
    refit = OutputError(held).fit(ex.segments, estimate_x0=True, start=start)
    t_refit = time.perf_counter() - t0
    names = [n for n in res.free_names if "[" not in n]
    d_step = (step.params[names] - res.params[names]).to_numpy()
    d_refit = (refit.params[names] - res.params[names]).to_numpy()
    return {
        "G": G,
        "n_free": len(res.free_names),
        "dense_s": t_dense,
        "blocks_s": t_blocks,
        "F_agree": agree,
        "refit_s": t_refit,
        "refit_iter": refit.iterations,
        "step_s": t_step,
        "step_vs_refit": float(np.max(np.abs(d_step - d_refit)) / np.max(np.abs(d_refit))),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--segments", type=int, nargs="+", default=[4, 16, 48])
    args = ap.parse_args()
    print(
        f"{'G':>3} {'n_free':>6} {'dense s':>8} {'blocks s':>8} {'ratio':>6} {'F agree':>8} "
        f"{'refit s':>8} {'iter':>4} {'step s':>7} {'ratio':>6} {'step-refit':>10}"
    )
    for G in args.segments:
        r = one(G)
        print(
            f"{r['G']:>3} {r['n_free']:>6} {r['dense_s']:>8.3f} {r['blocks_s']:>8.3f} "
            f"{r['dense_s'] / r['blocks_s']:>6.1f} {r['F_agree']:>8.1e} {r['refit_s']:>8.2f} "
            f"{r['refit_iter']:>4} {r['step_s']:>7.3f} {r['refit_s'] / r['step_s']:>6.1f} "
            f"{r['step_vs_refit']:>10.3f}"
        )


if __name__ == "__main__":
    main()
