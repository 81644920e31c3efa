"""Bounded Gauss-Newton with step halving or Levenberg-Marquardt damping.

The loop a likelihood fit runs on its free parameters (output error and its variants for
unstable aircraft use it; any estimator that supplies F, G and a trial cost can): linearise at
theta (information matrix F, gradient G, cost J), freeze the parameters held on a bound
whose gradient points outward (bounded-variable Gauss-Newton), solve for a step, and
accept it when the trial cost falls: halving the step (Gauss-Newton) or raising the
damping (Levenberg-Marquardt) until it does. The fit stops when its convergence measure
(det(R) for output error) changes by less than ``tol`` relative between iterations, when
no descent is left, or at ``max_iter``. A Nelder-Mead start (the problem's ``simplex``)
rescues a start from which no step lowers the cost.

The problem supplies the numbers (:class:`LeastSquaresProblem`); this module only decides
steps, so the same safeguards apply to every estimator that uses it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from estimators import statistics as st
from estimators.defaults import (
    BOUND_RTOL,
    DESCENT_RTOL,
    LM_LAMBDA_FACTOR,
    LM_LAMBDA_MIN,
    LM_LAMBDA_START,
    MAX_ITER,
    STEP_HALVINGS,
    TOL,
)

OPTIMIZERS = ("gauss-newton", "levenberg-marquardt")
FALLBACKS = ("auto", "always", "never")


class Linearisation(Protocol):
    """What a step needs at theta: ``F`` (n_free, n_free) information matrix, ``G``
    (n_free,) gradient of -J, ``J`` the cost, ``watched`` the convergence measure and
    ``report`` the cost columns of the history row (name -> value)."""

    F: np.ndarray
    G: np.ndarray
    J: float
    watched: float
    report: dict[str, float]


class LeastSquaresProblem(Protocol):
    """The estimator's side of :func:`minimise`."""

    def linearise(self, theta: np.ndarray) -> Linearisation:
        """F, G, J and the convergence measure at the parameter vector theta (n_all,)."""

    def cost_to_beat(self, lin: Linearisation, theta: np.ndarray) -> float:
        """The cost at theta that a trial step must lower."""

    def trial_cost(self, trial: np.ndarray, lin: Linearisation) -> float:
        """The cost at a trial vector (inf when its simulation fails)."""

    def simplex(self, theta: np.ndarray) -> np.ndarray:
        """A better start than theta from a derivative-free search."""


@dataclass(frozen=True)
class GaussNewtonSettings:
    """optimizer: "gauss-newton" (step halving) or "levenberg-marquardt"; max_iter: most
    iterations; tol: relative change of the convergence measure that ends the fit;
    step_halvings: most halvings (or damping increases) of a rejected step; fallback:
    "auto" runs the simplex when no step was accepted yet and none lowers the cost,
    "always" runs it first, "never" does not; cost_label: the convergence measure's name
    in the max_iter message."""

    optimizer: str = "gauss-newton"
    max_iter: int = MAX_ITER
    tol: float = TOL
    step_halvings: int = STEP_HALVINGS
    fallback: str = "auto"
    cost_label: str = "det(R)"


@dataclass
class Outcome:
    """The end of :func:`minimise`: theta (n_all,), whether it converged and why it
    stopped (``message``, "" when it converged plainly), the last iteration's number, the
    history rows (one per iteration: ``iteration``, the problem's cost columns, ``step``,
    ``lambda`` for Levenberg-Marquardt, the free parameters' values), whether the simplex
    ran, and how many steps were accepted."""

    theta: np.ndarray
    converged: bool = False
    message: str = ""
    iterations: int = 0
    history: list[dict[str, Any]] = field(default_factory=list)
    used_simplex: bool = False
    n_accepted: int = 0


@dataclass
class _Bounds:
    """The free parameters' indices into theta and their bounds (n_free,)."""

    free: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


def active_set(tf: np.ndarray, lo: np.ndarray, hi: np.ndarray, G: np.ndarray) -> np.ndarray:
    """(n_free,) bool: the parameters that may move. One held on a bound (within
    BOUND_RTOL relative) whose gradient G points outward is frozen for this step."""
    span = np.maximum(1.0, np.abs(tf))
    at_lo = tf <= lo + BOUND_RTOL * span
    at_hi = tf >= hi - BOUND_RTOL * span
    return ~((at_lo & (G < 0)) | (at_hi & (G > 0)))


def _line_search(
    problem: LeastSquaresProblem,
    lin: Linearisation,
    theta: np.ndarray,
    b: _Bounds,
    a: np.ndarray,
    lam: float,
    s: GaussNewtonSettings,
) -> tuple[np.ndarray | None, np.ndarray, float, float]:
    """One step on the active parameters ``a``: (accepted theta or None, the full step
    delta (n_free,), the last step factor, the damping after the search)."""
    fi = b.free
    J_now = problem.cost_to_beat(lin, theta)
    tf = theta[fi]
    alpha = 1.0
    delta = np.zeros_like(tf)
    if s.optimizer == "gauss-newton":
        delta[a] = st.solve_step(lin.F[np.ix_(a, a)], lin.G[a])
    for _ in range(s.step_halvings + 1):
        if s.optimizer == "levenberg-marquardt":
            delta = np.zeros_like(tf)
            delta[a] = st.solve_step(lin.F[np.ix_(a, a)], lin.G[a], lam)
            step = delta
        else:
            step = alpha * delta
        trial = theta.copy()
        trial[fi] = np.clip(tf + step, b.lower, b.upper)
        if problem.trial_cost(trial, lin) < J_now:
            return trial, delta, alpha, max(lam / LM_LAMBDA_FACTOR, LM_LAMBDA_MIN)
        alpha *= 0.5
        lam *= LM_LAMBDA_FACTOR
    return None, delta, alpha, lam


def _failed_search_message(n_accepted: int) -> str:
    if not n_accepted:
        return "no step lowered the cost (line search failed) - the start may be poor or the model may not describe the data"
    return (
        f"no step lowered the cost after {n_accepted} accepted steps (line "
        "search failed near the optimum: the finite-difference gradient is "
        "too coarse there; jacobian='central' refines it)"
    )


def minimise(
    problem: LeastSquaresProblem,
    theta: np.ndarray,
    free: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    names: list[str],
    settings: GaussNewtonSettings,
    on_iteration: Callable[[int, Linearisation, np.ndarray], None] | None = None,
) -> Outcome:
    """Minimise the problem's cost over the free parameters of theta (n_all,): ``free``
    their indices (n_free,), ``lower``/``upper`` their bounds, ``names`` their names (the
    history's columns, the identifiability message). ``on_iteration(iteration, lin,
    theta)`` is called once per iteration after the history row is written. Raises
    IdentifiabilityError when the information matrix at the start is singular."""
    s = settings
    b = _Bounds(free, lower, upper)
    out = Outcome(theta)
    if s.fallback == "always":
        out.theta = problem.simplex(out.theta)
        out.used_simplex = True
    lam = LM_LAMBDA_START
    cost_old = np.inf
    for it in range(1, s.max_iter + 1):
        out.iterations = it
        theta = out.theta
        lin = problem.linearise(theta)
        if it == 1:
            st.check_identifiable(lin.F, names, " at the start values")
        row: dict[str, Any] = {"iteration": it - 1, **lin.report, "step": np.nan}
        if s.optimizer == "levenberg-marquardt":
            row["lambda"] = lam
        row.update(zip(names, theta[free]))
        out.history.append(row)
        if on_iteration is not None:
            on_iteration(it - 1, lin, theta)
        if np.isfinite(cost_old) and abs(cost_old - lin.watched) <= s.tol * abs(lin.watched):
            out.converged = True
            break
        cost_old = lin.watched
        active = active_set(theta[free], lower, upper, lin.G)
        if not np.any(active):
            out.converged = True
            out.message = "every free parameter is held on a bound"
            break
        a = np.flatnonzero(active)
        trial, delta, alpha, lam = _line_search(problem, lin, theta, b, a, lam, s)
        row["step"] = alpha if s.optimizer == "gauss-newton" else 1.0
        if trial is not None:
            out.n_accepted += 1
            out.theta = trial
            continue
        if 0.5 * float(lin.G[a] @ delta[a]) <= DESCENT_RTOL * max(lin.J, 1.0):
            out.converged = True  # no descent left: at the minimum to round-off
            break
        if s.fallback == "auto" and not out.used_simplex and not out.n_accepted:
            out.theta = problem.simplex(theta)
            out.used_simplex = True
            cost_old = np.inf
            continue
        out.message = _failed_search_message(out.n_accepted)
        break
    else:
        out.message = f"stopped at max_iter={s.max_iter} before {s.cost_label} settled"
    return out
