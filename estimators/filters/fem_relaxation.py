"""The filter-error method's relaxation between the innovation covariance R and the
process noise F (Maine and Iliff): R in closed form from the innovations, F compensated
for the change, and F scaled down where the gain would over-correct a state
(diag(K C) > 1).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.filters.fem_problem import FemProblem

#: relative change of the innovation covariance's diagonal under which the relaxation has
#: settled (with det(R) settled too, the fit has converged)
R_SETTLED = 1e-2


def compensate(prob: FemProblem, phi: np.ndarray, R_old: np.ndarray, R_new: np.ndarray, res) -> np.ndarray:
    """F-R compensation (Maine and Iliff): after R changes from R_old to R_new, F_i is
    scaled by sum_k C_ki^2 / R_old,kk sqrt(R_new,kk / R_old,kk) / sum_k C_ki^2 / R_old,kk
    so that the gain, and the noise R - C P C^T it implies, stay consistent."""
    if not prob.estimate_F or not prob.noisy:
        return phi
    C2 = np.mean([r.C[0] ** 2 for r in res], axis=0)  # (m, n)
    w = 1.0 / np.diag(R_old)
    ratio = np.sqrt(np.diag(R_new) / np.diag(R_old))
    with np.errstate(invalid="ignore", divide="ignore"):
        fac = (C2.T @ (w * ratio)) / (C2.T @ w)
    out = phi.copy()
    sl = prob.fslice()
    f = np.asarray(prob.noisy)
    out[sl] = phi[sl] * np.where(np.isfinite(fac[f]) & (fac[f] > 0), fac[f], 1.0)
    return out


def feasible_start(prob: FemProblem, phi: np.ndarray, res, R: np.ndarray) -> tuple[np.ndarray, Any]:
    """The start with F scaled down, halving at most 30 times, until diag(K C) <= 1 and
    the filter's predictions stay finite: a start F too large for the start R over-corrects
    the states at every sample. The free F entries are scaled, else the fixed
    ones; unchanged when already feasible."""
    for _ in range(30):
        if not prob.noisy or (prob.constraint_ok(res) and np.isfinite(prob.cost(res)[0])):
            break
        if prob.estimate_F:
            phi = phi.copy()
            phi[prob.fslice()] *= 0.5
        else:
            prob.f_fixed = 0.5 * prob.f_fixed
        res = prob.filter(phi[None, :], R)
    return phi, res


def to_constraint(prob: FemProblem, phi: np.ndarray, res, R: np.ndarray, margin: float = 1e-4):
    """phi with its F scaled by the largest factor in (0, 1] (bisection, 30 steps) that
    keeps diag(K C) <= 1 - margin for the innovation covariance R, and its filter run;
    (phi, None) when no factor does or F is not estimated."""
    if not prob.estimate_F or not prob.noisy:
        return phi, None
    sl = prob.fslice()
    lo, hi, best = 0.0, 1.0, None
    for _ in range(30):
        s = 0.5 * (lo + hi)
        c = phi.copy()
        c[sl] *= s
        rc = prob.filter(c[None, :], R)
        if all(np.all(r.CK[0] <= 1.0 - margin) for r in rc):
            lo, best = s, (c, rc)
        else:
            hi = s
        if hi - lo < 1e-3 * hi:
            break
    return best if best is not None else (phi, None)


def relax(prob: FemProblem, phi, res, cost, Rh, R):
    """One relaxation update: R in closed form from the innovations (Rh) with F
    compensated for it (:func:`compensate`). When the compensated F raises det(R), it
    is halved back towards the old F (the reference software's rule); when the new R
    makes the gain over-correct (diag(K C) > 1), F is scaled down until it does not.
    The first candidate that lowers det(R) is taken, else the feasible one of least
    det(R): R must follow the innovations, or the relaxation stalls on a stale R.
    Returns (phi, res, cost, Rh, R, the relative change of R)."""
    change = float(np.max(np.abs(np.diag(Rh) / np.diag(R) - 1.0)))
    phi_c = compensate(prob, phi, R, Rh, res)
    cands = [phi_c, 0.5 * (phi_c + phi), phi]
    best = None
    for c in cands:
        rc = prob.filter(c[None, :], Rh)
        if not prob.constraint_ok(rc):
            c, rc = to_constraint(prob, c, rc, Rh)
        if rc is None:
            continue
        cc, Rc = prob.cost(rc)
        if not np.isfinite(cc):
            continue
        if cc <= cost * (1.0 + 1e-9):
            return c, rc, cc, Rc, Rh, change
        if best is None or cc < best[2]:
            best = (c, rc, cc, Rc)
    if best is not None:
        return (*best, Rh, change)
    return phi, res, cost, Rh, R, change
