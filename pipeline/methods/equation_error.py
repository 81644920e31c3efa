"""Equation error (``ls``) on a problem's coefficient regressions, returned as an
estimation result on the problem's dynamic model, and the regressions' unclamped
estimates as start values for the other methods."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from estimators import EstimationResult, LeastSquares, OutputError
from estimators.defaults import CLUSTER_MIN_SEGMENTS as MIN_SEGMENTS
from estimators.errors import ModelDefinitionError
from estimators.validation import ClusterResult, cluster_covariance
from pipeline.problems import Problem
from pipeline.problems.regressions import Regression


def ordinary_least_squares(reg: Regression) -> tuple[EstimationResult, ClusterResult | None]:
    """One coefficient regression by OLS (the intercept, a trim term or the unnamed bias,
    estimated with it) and its maneuver scatter."""
    coef, names, X, y = reg.coef, reg.names, reg.X, reg.y
    cols = [n if n is not None else "bias" for n in names]
    try:
        res = LeastSquares(cols if names[0] is not None else cols[1:], intercept=names[0] is None, response=coef).fit(
            X if names[0] is not None else X[:, 1:], y
        )
    except ModelDefinitionError as exc:  # too few rows: say which regression
        raise ModelDefinitionError(f"equation error on {coef} of the fitted maneuvers: {exc}") from None
    return res, _regression_clusters(X, y, reg.window, cols, res)


def equation_error(
    problem: Problem,
    regress: Callable[[Regression], tuple[EstimationResult, ClusterResult | None]] = ordinary_least_squares,
) -> EstimationResult:
    """``ls``: the problem's coefficient regressions (by ``regress``: OLS, or the
    frequency-domain regression of ``fdls``), returned on the problem's dynamic model so
    that validation, report and recording treat it as any other method: the derivatives
    (free, with the regressions' covariance) are the regression estimates; per-segment
    initial states and output biases are then fitted by output error with every derivative
    held (they are not part of the regression), and the predictions and residuals are that
    simulation's."""
    model = problem.model
    est, var, regs, clusters = {}, {}, [], []
    for reg in problem.regressions:
        res, cluster = regress(reg)
        regs.append(res)
        for n in reg.names:
            if n is not None and n in res.names:
                est[n] = float(res.params[n])
                var[n] = float(res.std[n]) ** 2
        clusters.append(cluster)
    free = [p.name for p in model.parameters if p.free and not p.per_segment and p.name in est]
    held = model.with_values({n: est[n] for n in free}).fixed(free)
    sim = OutputError(held, inputs=problem.inputs, fallback="never").fit(problem.fit, estimate_x0=problem.estimate_x0)
    names = list(sim.names)
    is_free = np.array([n in free for n in names])
    n_samples = sum(len(r.residuals[0]) for r in regs)
    return EstimationResult(
        method="ls",
        model=model,
        names=names,
        values=np.asarray(sim.values, dtype=float),
        free=is_free,
        cov=_regression_covariance(regs, [n for n in names if n in free], var),
        R=sim.R,
        converged=True,
        iterations=1,
        history=sim.history,
        predicted=sim.predicted,
        residuals=sim.residuals,
        segments=list(problem.fit),
        message=(
            f"equation error (OLS) on {', '.join(r.outputs[0] for r in regs)} from "
            f"{n_samples // max(len(regs), 1)} samples; predictions: the model with these "
            "derivatives, initial states and biases fitted"
        ),
        settings={"integrator": sim.settings.get("integrator", "rk4"), "optimizer": "ols", "inputs": problem.inputs},
        extra={
            "regressions": regs,
            "x0_and_biases": sim,
            **(
                {"cluster": _joined_clusters(clusters, [n for n in names if n in free])}
                if clusters and all(c is not None for c in clusters)
                else {}
            ),
        },
    )


def _regression_covariance(regs: list, free: list[str], var: dict[str, float]) -> np.ndarray:
    """Covariance of the ``free`` derivatives (in that order): each regression's covariance
    block (CL0~CLalpha ...), not its diagonal only; ``var`` the OLS variances."""
    cov = np.diag([var[n] for n in free])
    idx = {n: i for i, n in enumerate(free)}
    for res in regs:
        rn = [n for n in res.free_names if n in idx]
        sub = res.cov[np.ix_([res.free_names.index(n) for n in rn], [res.free_names.index(n) for n in rn])]
        for a, na in enumerate(rn):
            for b, nb in enumerate(rn):
                cov[idx[na], idx[nb]] = sub[a, b]
    return cov


def _regression_clusters(X: np.ndarray, y: np.ndarray, window: np.ndarray, cols: list[str], res):
    """The maneuver scatter of one regression (estimators.covariance.cluster): each
    window's X_j^T X_j / s^2 and X_j^T e_j / s^2 at the OLS estimate; None with fewer than
    MIN_SEGMENTS windows or a singular X."""
    wins = np.unique(window)
    if wins.size < MIN_SEGMENTS:
        return None
    beta = np.array([float(res.params[c]) for c in cols])
    e = y - X @ beta
    s2 = float(e @ e) / max(len(y) - len(cols), 1)
    parts = [(X[window == k].T @ X[window == k] / s2, X[window == k].T @ e[window == k] / s2) for k in wins]
    try:
        return cluster_covariance([p[0] for p in parts], [p[1] for p in parts], names=cols)
    except (ValueError, np.linalg.LinAlgError):
        return None


def _joined_clusters(clusters: list, names: list[str]) -> ClusterResult:
    """One ClusterResult over ``names`` from the regressions' (independent fits: block
    diagonal)."""
    p = len(names)
    cov = np.zeros((p, p))
    crb = np.full(p, np.nan)
    share = np.zeros((max(c.n_segments for c in clusters), p))
    for c in clusters:
        mine = [(names.index(n), k) for k, n in enumerate(c.names) if n in names]
        rows, cols = [a for a, _ in mine], [k for _, k in mine]
        cov[np.ix_(rows, rows)] = c.cov[np.ix_(cols, cols)]
        crb[rows] = c.crb_std[cols]
        share[: c.n_segments, rows] = c.share[:, cols]
    bad = ~np.isfinite(np.diag(cov))
    cov[bad, :] = np.nan
    cov[:, bad] = np.nan
    return ClusterResult(names=list(names), cov=cov, crb_std=crb, share=share, limit=clusters[0].limit)


def raw_starts(problem: Problem) -> dict[str, float]:
    """The equation-error estimates of the free parameters without the "flyable" sign clamps
    of the problem's start values (stable Cmalpha, Cmq; positive lift slope). The clamps
    protect plain output error, whose simulation must not diverge; the stabilised methods
    and the filters keep their predictions bounded and need the unstable sign where the data
    show it."""
    out = {}
    free = {p.name for p in problem.model.parameters if p.free}
    for reg in problem.regressions:
        names, X, y = reg.names, reg.X, reg.y
        sol = np.linalg.lstsq(X, y, rcond=None)[0]
        out.update({n: float(v) for n, v in zip(names, sol) if n is not None and n in free})
    return out
