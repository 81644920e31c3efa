"""The control-input delays and lags refined by the output-error fits' own likelihood
(:func:`refine_by_output_error`), and whether the fits want the inputs as logged instead
(:func:`logged_inputs_fit_better`)."""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from estimators.covariance.uncertainty import coloured_information
from estimators.statistics import whitener
from pipeline.conditioning.input_dynamics.regression import AT_END_S, DELAY_RANGE_S, LAG_RANGE_S

#: output-error refinement (:func:`refine_by_output_error`): Gauss-Newton iterations at
#: most, the step of its difference quotients [s], and when it stops (every change below
#: this fraction of its std)
REFINE_ITERATIONS = 10
REFINE_STEP_S = 0.002
REFINE_TOLERANCE = 0.1
#: ... or when a step lowers the weighted residual sum of squares (whitened by R: a
#: parameter 1 Cramér-Rao std off adds 1) by less than this (a delay and a lag seen on one
#: maneuver are nearly one parameter: steps trading them gain next to nothing)
REFINE_COST_GAIN = 1.0
#: the refinement's name in documents and reports
REFINE_METHOD = "output error"
#: what the refinement estimates
REFINED = ("delay_s", "lag_s")
#: output error's and equation error's values agree within this many combined std (else
#: the refined std is widened to their difference)
REFINE_AGREE = 3.0
#: the smallest std of a refined delay or lag [s]: output error's own std understates the
#: spread of its estimates over flights (the servo and the log's sample timing), and real
#: logs stamp their samples no better than that
REFINE_MIN_STD_S = 0.001


def _whitened(
    results: Mapping[str, Any], weights: Mapping[str, np.ndarray] | None = None
) -> tuple[list[np.ndarray], dict[str, np.ndarray]]:
    """Per fitted segment of every result (keys sorted) its residuals (N, n_out) times the
    whitening W of its result (W W^T = R^-1), missing samples 0; and the W used
    (``weights``, else each result's own R)."""
    if weights is None:
        weights = {k: whitener(np.atleast_2d(r.R)) for k, r in results.items()}
    if set(weights) != set(results):
        raise ValueError(f"the fits changed ({sorted(weights)} -> {sorted(results)})")
    out = []
    for k in sorted(results):
        for df in results[k].residuals:
            v = df.to_numpy(dtype=float)
            out.append(np.where(np.isfinite(v), v, 0.0) @ weights[k])
    return out, weights


def logged_inputs_fit_better(applied: Mapping[str, Mapping[str, float]], fit) -> str | None:
    """Why the output-error fits want the inputs as logged rather than with the delays and
    lags ``applied`` (surface -> {"delay_s", "lag_s"}), or None: ``fit(dynamics, None)``
    (as :func:`refine_by_output_error`'s) is run both ways; the logged inputs win when
    their fits converge and the fits with ``applied`` do not, or leave weighted residuals
    at least as large (each fit's residuals whitened by the logged fit's R: the same
    yardstick). For a refinement that could not settle: equation error's values are then
    worse than none."""
    try:
        logged = fit({}, None)
        moved = fit({s: dict(v) for s, v in applied.items()}, None)
    except Exception:  # noqa: BLE001 - either way failing: no verdict
        return None
    if not logged or not all(r.converged for r in logged.values()):
        return None
    if not all(r.converged for r in moved.values()):
        return "output error did not converge with them and did with the inputs as logged"
    v0, W = _whitened(logged)
    v1, _ = _whitened(moved, W)
    c0, c1 = (sum(float(np.sum(v * v)) for v in vs) for vs in (v0, v1))
    if c0 <= c1:
        return f"output error fits the inputs as logged at least as well (weighted residuals {c0:.6g} against {c1:.6g} with them)"
    return None


def refine_by_output_error(doc: dict[str, Any], fit, progress: Any = None) -> dict[str, Any]:
    """Refine the delays and lags ``doc`` applies (the document of
    :func:`estimate_input_dynamics`) by the output-error fits' own likelihood; when that
    succeeds they and their covariance replace the equation-error ones in ``doc``
    (``applied``, ``covariance``, each surface's ``refined``; the equation-error ones kept
    under ``equation_error``). Returns the refinement's document, also ``doc["refined"]``:
    status ("refined" or "not refined" with a reason), iterations, fits, seconds.

    ``fit(dynamics, starts)`` -> the output-error results (key -> EstimationResult) with
    ``dynamics`` (surface -> {"delay_s", "lag_s"}) applied to the data; ``starts``: None
    (a fit from the model's starts), key -> parameter values (a fit from there) or key ->
    EstimationResult (that result moved by one Gauss-Newton step, OutputError.step_from).

    Gauss-Newton on the delays and lags with the aerodynamic estimates profiled out: the
    sensitivity of the fits' whitened residuals to a delay or lag is the difference
    quotient of a fit and its one-step move (so the derivatives absorb what they can),
    REFINE_STEP_S apart; steps halved while the weighted residuals grow, bounded to
    DELAY_RANGE_S and LAG_RANGE_S; at most REFINE_ITERATIONS, done when every change is
    below REFINE_TOLERANCE std or a step gains less than REFINE_COST_GAIN. std: those
    sensitivities' Cramér-Rao bound corrected for coloured residuals (Morelli-Klein), at
    least REFINE_MIN_STD_S, widened to the difference from equation error's value where
    the two disagree by more than REFINE_AGREE combined std. A delay or lag the fits do
    not see (a surface whose axis is not fitted) keeps its equation-error value and std.
    Nothing changes when a fit fails or does not converge, or an estimate ends at its
    range's end."""
    run = _Refinement({s: dict(v) for s, v in doc["applied"].items()}, fit, progress)
    doc["refined"] = run.ref
    applied, keys, lo, hi = run.applied, run.keys, run.lo, run.hi
    x = np.array([applied[s][k] for s, k in keys], dtype=float)
    try:
        base = run(x, None)
        bad = [k for k, r in base.items() if not r.converged]
        if not base:
            return run.done("no output-error fit on this log")
        if bad:
            return run.done(f"output error did not converge with the equation-error values ({', '.join(bad)})")
        it, converged = 0, False
        while True:
            v0, W = _whitened(base)
            cost0 = sum(float(np.sum(v * v)) for v in v0)
            S, Minv, seen, step = _gauss_newton_step(run, x, base, v0, W)
            sd = np.sqrt(np.clip(np.diag(Minv), 0.0, None))
            it += 1
            moved = _along(run, x, step, base, W, cost0)
            if moved is None:  # no better point along the step: at the minimum
                converged = True
                break
            change = np.abs(moved[0] - x)
            x, base, gain = moved
            if np.all(change <= REFINE_TOLERANCE * sd) or gain < REFINE_COST_GAIN:
                converged = True
                break
            if it >= REFINE_ITERATIONS:
                break
    except Exception as exc:  # noqa: BLE001 - a failed refinement keeps equation error's values
        return run.done(f"a fit failed ({type(exc).__name__}: {exc})")
    run.ref["iterations"] = it
    if not converged:
        return run.done(f"not converged in {REFINE_ITERATIONS} Gauss-Newton iterations")
    ends = [
        f"{s} {k[:-2]}"
        for (s, k), val, a, b in zip(keys, x, lo, hi)
        if val >= b - AT_END_S or (k == "delay_s" and val <= a + AT_END_S)
    ]
    if ends:
        return run.done(f"{', '.join(ends)} at the end of its range")
    names = [f"{s} {k[:-2]}" for s, k in keys]
    cov, mk, crb, apart = _refined_covariance(
        S, v0, Minv, seen, x, np.array([applied[s][k] for s, k in keys]), names, doc
    )
    doc["equation_error"] = {"applied": applied, "covariance": doc["covariance"]}
    doc["applied"] = run.dynamics(x)
    doc["covariance"] = {"names": names, "matrix": cov.tolist()}
    sd = np.sqrt(np.diag(cov))
    for j, (s, k) in enumerate(keys):
        if seen[j]:
            doc["surfaces"][s].setdefault("refined", {}).update(
                {
                    k: float(x[j]),
                    k[:-2] + "_std": float(sd[j]),
                    k[:-2] + "_crb_std": float(crb[j]),
                    k[:-2] + "_mk_std": float(mk[j]),
                    k[:-2] + "_widened": bool(apart[j]),
                }
            )
    if not np.all(seen):
        run.ref["not_seen"] = [n for n, ok in zip(names, seen) if not ok]
    run.ref["status"] = "refined"
    return run.done(None)


class _Refinement:
    """One run of :func:`refine_by_output_error`: the delays and lags refined (``keys``:
    (surface, "delay_s" | "lag_s") of ``applied``) with their bounds, the fits run
    (calling it runs ``fit`` with values ``xv`` in the order of ``keys``), and the
    refinement's document ``ref``."""

    def __init__(self, applied: dict[str, dict[str, float]], fit, progress: Any) -> None:
        self.t0 = time.perf_counter()
        self.applied = applied
        self.keys = [(s, k) for s in applied for k in REFINED]
        self.lo = np.array([(DELAY_RANGE_S if k == "delay_s" else LAG_RANGE_S)[0] for _, k in self.keys])
        self.hi = np.array([(DELAY_RANGE_S if k == "delay_s" else LAG_RANGE_S)[1] for _, k in self.keys])
        self.fit, self.progress = fit, progress
        self.count = 0
        self.ref: dict[str, Any] = {
            "method": f"{REFINE_METHOD}: Gauss-Newton on the delays and lags, the derivatives profiled out; Morelli-Klein std",
            "status": "not refined",
        }

    def dynamics(self, xv: np.ndarray) -> dict[str, dict[str, float]]:
        out = {s: dict(v) for s, v in self.applied.items()}
        for (s, k), val in zip(self.keys, xv):
            out[s][k] = float(val)
        return out

    def __call__(self, xv: np.ndarray, starts: Any) -> Mapping[str, Any]:
        self.count += 1
        if self.progress is not None:
            self.progress.tick(str(self.count))
        return self.fit(self.dynamics(xv), starts)

    def done(self, reason: str | None) -> dict[str, Any]:
        self.ref.update(fits=self.count, seconds=time.perf_counter() - self.t0)
        if reason:
            self.ref["reason"] = reason
        return self.ref


def _gauss_newton_step(
    run: _Refinement, x: np.ndarray, base: Mapping[str, Any], v0: list[np.ndarray], W: Mapping[str, np.ndarray]
) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """(whitened sensitivities per segment, the inverse of their normal matrix on the
    values the fits see, which values they see, the Gauss-Newton step) at ``x``, the fits
    ``base`` with whitened residuals ``v0`` (whitening ``W``): each value's sensitivity is
    the difference quotient of ``base`` and its one-step move REFINE_STEP_S away."""
    cols = []
    for j in range(len(run.keys)):
        h = REFINE_STEP_S if x[j] + REFINE_STEP_S <= run.hi[j] else -REFINE_STEP_S
        xj = x.copy()
        xj[j] += h
        vj, _ = _whitened(run(xj, base), W)
        cols.append([(b - a) / h for a, b in zip(vj, v0)])  # d(output)/d(value)
    S = [np.stack([c[i] for c in cols], axis=-1) for i in range(len(v0))]
    M = sum(np.einsum("nap,naq->pq", s, s) for s in S)
    seen = np.diag(M) > 1e-12 * max(float(np.max(np.diag(M))), 1e-300)
    Minv = np.zeros_like(M)
    Minv[np.ix_(seen, seen)] = np.linalg.pinv(M[np.ix_(seen, seen)], hermitian=True)
    step = Minv @ sum(np.einsum("nap,na->p", s, v) for s, v in zip(S, v0))
    return S, Minv, seen, step


def _along(
    run: _Refinement,
    x: np.ndarray,
    step: np.ndarray,
    base: Mapping[str, Any],
    W: Mapping[str, np.ndarray],
    cost0: float,
) -> tuple[np.ndarray, Mapping[str, Any], float] | None:
    """(values, fits, gain) of the first point along ``step`` from ``x`` (halved up to 4
    times, bounded) whose fits converge with weighted residuals below ``cost0``; None
    when there is none."""
    lam = 1.0
    for _ in range(4):
        xn = np.clip(x + lam * step, run.lo, run.hi)
        new = run(xn, {k: dict(r.params) for k, r in base.items()})
        if all(r.converged for r in new.values()):
            vn, _ = _whitened(new, W)
            cn = sum(float(np.sum(v * v)) for v in vn)
            if cn < cost0:
                return xn, new, cost0 - cn
        lam *= 0.5
    return None


def _refined_covariance(
    S: list[np.ndarray],
    v0: list[np.ndarray],
    Minv: np.ndarray,
    seen: np.ndarray,
    x: np.ndarray,
    was: np.ndarray,
    names: list[str],
    doc: Mapping[str, Any],
) -> tuple[np.ndarray, ...]:
    """(covariance, Morelli-Klein std, Cramér-Rao std, apart) of the refined values ``x``
    (equation error's ``was``; named ``names``, "<surface> delay|lag"; ``seen`` by the
    fits) from the last Gauss-Newton iteration of :func:`refine_by_output_error` (its
    whitened sensitivities ``S`` and residuals ``v0`` per segment, ``Minv``), ``doc``
    still equation error's; ``apart``: where the two methods disagree."""
    # the std: output error's Morelli-Klein one, at least REFINE_MIN_STD_S, where equation
    # error agrees (within REFINE_AGREE combined std); where it does not, the data cannot
    # tell them apart (the commands or the gyro logged slowly: a delay and a lag of a few
    # samples trade against each other) and the std is widened to their difference. A
    # value output error does not see keeps equation error's std. Equation error's value
    # at its bound (a lag of 0) has no std of its own: 0 there.
    n_out = [v.shape[1] for v in v0]
    mid, _ = coloured_information(S, v0, [np.eye(n) for n in n_out])
    cov = Minv @ mid @ Minv
    mk = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    crb = np.sqrt(np.clip(np.diag(Minv), 0.0, None))
    old = doc["covariance"]
    pos = {n: i for i, n in enumerate(old["names"])}
    ee = np.asarray(old["matrix"], dtype=float)
    sd_ee = np.array([np.sqrt(max(ee[pos[n], pos[n]], 0.0)) if n in pos else 0.0 for n in names])
    diff = np.abs(x - was)
    apart = seen & (diff > REFINE_AGREE * np.hypot(sd_ee, mk))
    want = np.maximum(np.where(apart, np.maximum(mk, diff), mk), REFINE_MIN_STD_S)
    widen = np.where(mk > 0, want / np.where(mk > 0, mk, 1.0), 1.0)
    cov = cov * np.outer(widen, widen)
    for j in np.flatnonzero(~seen | ~(mk > 0)):
        cov[j, :] = cov[:, j] = 0.0
        cov[j, j] = sd_ee[j] ** 2 if not seen[j] else want[j] ** 2
    return 0.5 * (cov + cov.T), mk, crb, apart
