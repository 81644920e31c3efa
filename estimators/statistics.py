"""Gauss-Newton building blocks shared by the likelihood methods: residual covariance,
whitened information matrix and gradient, Cramér-Rao bounds, identifiability."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from estimators.defaults import SINGULAR_RTOL, UNINFORMED_RTOL
from estimators.errors import IdentifiabilityError
from estimators.sensitivity import add_block, as_sensitivity


def residual_covariance(residuals: Sequence[np.ndarray], full: bool = False) -> np.ndarray:
    """R = (1/N) sum e e^T over all segments; residuals (N_k, n_out) with NaN where a sample
    is missing (left out of the sums). Diagonal unless ``full``."""
    E = np.concatenate([np.asarray(e, dtype=float) for e in residuals], axis=0)
    ok = np.isfinite(E)
    E0 = np.where(ok, E, 0.0)
    counts = ok.T.astype(float) @ ok.astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        R = (E0.T @ E0) / counts
    if not full:
        R = np.diag(np.diag(R))
    return R


def whitener(R: np.ndarray) -> np.ndarray:
    """L with L L^T = R^-1, so ||L^T e||^2 = e^T R^-1 e. Zero-variance outputs are given a
    tiny floor so a perfectly matched channel does not make R singular."""
    R = np.array(R, dtype=float)
    d = np.diag(R).copy()
    floor = 1e-12 * max(float(np.max(d)), 1e-300)
    R[np.diag_indices_from(R)] = np.maximum(d, floor)
    return np.linalg.cholesky(np.linalg.inv(R))


def information_and_gradient(
    S_list: Sequence[Any], E_list: Sequence[np.ndarray], L: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """F = sum S^T R^-1 S, G = sum S^T R^-1 e and J = 1/2 sum e^T R^-1 e.

    S_list[k] the sensitivities of segment k (:class:`~estimators.sensitivity.Sensitivity`
    or a dense (N_k, n_out, n_p) array), E_list[k] (N_k, n_out) residuals (NaN = missing),
    L the whitener of R. Each segment adds to the block of the parameters it depends on.
    """
    blocks = [as_sensitivity(S) for S in S_list]
    n_p = blocks[0].n_free
    F = np.zeros((n_p, n_p))
    G = np.zeros(n_p)
    J = 0.0
    for b, E in zip(blocks, E_list):
        ok = np.isfinite(E)
        E0 = np.where(ok, E, 0.0)
        m = b.cols.size
        Sw = np.matmul(L.T, np.where(ok[:, :, None], b.values, 0.0)).reshape(-1, m)
        Ew = (E0 @ L).ravel()
        add_block(F, b.cols, Sw.T @ Sw)
        add_block(G, b.cols, Sw.T @ Ew)
        J += 0.5 * float(Ew @ Ew)
    return F, G, J


def weighted_cost(E_list: Sequence[np.ndarray], L: np.ndarray) -> float:
    """J = 1/2 sum e^T R^-1 e (inf when any residual is non-finite where data exist)."""
    J = 0.0
    for E in E_list:
        if E is None:
            return np.inf
        Ew = (np.where(np.isnan(E), 0.0, E)) @ L
        v = float(np.sum(Ew * Ew))
        if not np.isfinite(v):
            return np.inf
        J += 0.5 * v
    return J


def unidentifiable(F: np.ndarray, names: Sequence[str], rtol: float = SINGULAR_RTOL) -> list[str]:
    """Names of parameters the information matrix F cannot resolve: those with no
    sensitivity at all, and those carrying the null directions of the scaled F.

    F_ii carries the parameter's units, so "no sensitivity" is F_ii at round-off of the
    largest (UNINFORMED_RTOL: sensitivities 1e-15 of the largest), not a fraction of it
    that differing units alone reach (a process-noise parameter of order 1e-4 has an F_ii
    many decades above a well identified derivative's)."""
    d = np.diag(F).copy()
    dmax = float(np.max(d)) if d.size else 0.0
    zero = ~(d > UNINFORMED_RTOL * max(dmax, 1e-300))
    out = [names[i] for i in np.flatnonzero(zero)]
    keep = np.flatnonzero(~zero)
    if keep.size > 1:
        D = np.sqrt(d[keep])
        Fs = F[np.ix_(keep, keep)] / np.outer(D, D)
        w, V = np.linalg.eigh(Fs)
        null = w < rtol * max(float(w[-1]), 1e-300)
        if np.any(null):
            weight = np.max(np.abs(V[:, null]), axis=1)
            out += [names[keep[i]] for i in np.flatnonzero(weight > 0.2)]
    return out


def check_identifiable(F: np.ndarray, names: Sequence[str], where: str = "") -> None:
    bad = unidentifiable(F, names)
    if bad:
        raise IdentifiabilityError(
            f"the information matrix is singular{where}: parameters {', '.join(bad)} cannot be "
            "identified from these data (no effect on the outputs, or an effect that other "
            "parameters reproduce exactly). Fix one of them (Parameter(..., free=False)), give "
            "an a-priori value (priors={name: (value, std)}), or fly a maneuver that excites them.",
            parameters=bad,
        )


def covariance(F: np.ndarray) -> np.ndarray:
    """Cramér-Rao covariance P = F^-1, computed on the scaled matrix for accuracy."""
    d = np.sqrt(np.diag(F))
    Fs = F / np.outer(d, d)
    return np.linalg.inv(Fs) / np.outer(d, d)


def solve_step(F: np.ndarray, G: np.ndarray, lam: float = 0.0) -> np.ndarray:
    """Gauss-Newton (lam = 0) or Levenberg-Marquardt step: (F + lam diag F) d = G, solved on
    the scaled system; a least-squares solve when F is not positive definite."""
    d = np.sqrt(np.maximum(np.diag(F), 1e-300))
    Fs = F / np.outer(d, d) + lam * np.eye(F.shape[0])
    Gs = G / d
    try:
        c = np.linalg.cholesky(Fs)
        y = np.linalg.solve(c, Gs)
        x = np.linalg.solve(c.T, y)
    except np.linalg.LinAlgError:
        x = np.linalg.lstsq(Fs, Gs, rcond=1e-12)[0]
    return x / d


def difference_noise_std(segments: Sequence[np.ndarray], robust: bool = False) -> np.ndarray:
    """White measurement-noise std per column, (n_cols,), from second differences of each
    column's own samples (NaN = not measured, skipped, so a 50 Hz channel on a 100 Hz grid
    is differenced at 50 Hz), pooled over the segments (each (N, n_cols)): the second
    difference of white noise has variance 6 sigma^2, and a signal that is smooth over
    two samples adds little. ``robust``: the spread from the median absolute deviation
    (x 1.4826), which the few large second differences at control steps (a rate's kink
    when a surface steps) do not inflate. NaN for a column with fewer than 4 samples in
    every segment."""
    cols = np.atleast_2d(segments[0]).shape[1]
    out = np.full(cols, np.nan)
    for c in range(cols):
        d2 = [np.diff(v[np.isfinite(v)], 2) for v in (np.asarray(s, dtype=float)[:, c] for s in segments)]
        d2 = np.concatenate([d for d in d2 if d.size > 1] or [np.zeros(0)])
        if d2.size:
            spread = 1.4826 * np.median(np.abs(d2 - np.median(d2))) if robust else np.std(d2)
            out[c] = float(spread / np.sqrt(6.0))
    return out
