"""Wall time of our output-error fit against the baseline a user would write without us.

Problem: the HFB-320-like nonlinear longitudinal case of ``estimators.datasets`` (600
samples, 11 free parameters, 7 outputs, starts 30% off). Baseline:
``scipy.optimize.least_squares`` (trust-region reflective, finite-difference Jacobian)
over a ``scipy.integrate.solve_ivp`` (RK45) simulation with linearly interpolated inputs,
residuals weighted by the sensor noise std. The baseline's settings are the cheapest we
found that converge: without ``max_step`` = sample interval RK45 steps over the input
steps and its adaptive steps make the finite-difference Jacobian noisy, and with the
default tolerances least_squares stops 10-40 std short of the optimum. Both must agree within 0.1 Cramér-Rao std on
every parameter. Prints per-run times and, last, the median ratio baseline/ours.

    python benchmarks/oem_speed.py [--runs 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import integrate, optimize

from estimators import OutputError
from estimators.datasets import HFB320_FREE, longitudinal_example
from estimators.model import Namespace


def baseline_fit(ex, rtol: float, atol: float, diff_step: float = 1e-5):
    """What a user writes by hand: solve_ivp + least_squares."""
    model = ex.model
    seg = ex.segments[0]
    names = list(HFB320_FREE)
    fixed = {p.name: p.value for p in model.parameters}
    c = Namespace(model.constants)
    t, U, Z = seg.t, seg.u, seg.z
    w = 1.0 / ex.noise_std

    def simulate(theta):
        p = Namespace({**fixed, **dict(zip(names, theta))})

        def rhs(tt, x):
            u = np.array([np.interp(tt, t, U[:, 0]), np.interp(tt, t, U[:, 1])])
            return np.array(model.f(x, u, p, c))

        sol = integrate.solve_ivp(rhs, (t[0], t[-1]), seg.x0, t_eval=t, rtol=rtol, atol=atol, max_step=t[1] - t[0])
        if not sol.success or sol.y.shape[1] != t.size:
            return np.full_like(Z, 1e6)
        return np.array(model.g(sol.y, U.T, p, c)).T

    def resid(theta):
        return ((Z - simulate(theta)) * w).ravel()

    x0 = np.array([fixed[n] for n in names])
    sol = optimize.least_squares(
        resid, x0, method="trf", x_scale=np.abs(x0), diff_step=diff_step, xtol=1e-12, ftol=1e-10, gtol=1e-10
    )
    return dict(zip(names, sol.x)), sol.nfev + sol.njev * len(names)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--rtol", type=float, default=1e-6)
    ap.add_argument("--atol", type=float, default=1e-8)
    args = ap.parse_args()
    names = list(HFB320_FREE)
    ex = longitudinal_example(seed=7)
    OutputError(ex.model).fit(ex.segments)  # compile once (numba), not timed
    ours, base, agree = [], [], True
    for run in range(args.runs):
        t0 = time.perf_counter()
        res = OutputError(ex.model).fit(ex.segments)
        t1 = time.perf_counter()
        est_b, nsim = baseline_fit(ex, args.rtol, args.atol)
        t2 = time.perf_counter()
        ours.append(t1 - t0)
        base.append(t2 - t1)
        diff = max(abs(est_b[n] - res.params[n]) / res.std[n] for n in names)
        agree &= diff < 0.1
        print(
            f"run {run}: ours {ours[-1]:.3f} s ({res.iterations} iterations), baseline "
            f"{base[-1]:.2f} s (~{nsim} simulations), max |difference| {diff:.3f} std"
        )
    if not agree:
        print("WARNING: baseline and ours differ by more than 0.1 std")
    ratio = float(np.median(np.array(base) / np.array(ours)))
    print(f"median wall-time ratio baseline/ours: {ratio:.1f}")
    return 0 if agree else 1


if __name__ == "__main__":
    raise SystemExit(main())
