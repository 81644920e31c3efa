"""Scaled sigma points of the unscented Kalman filter (van der Merwe).

lambda = alpha^2 (L + kappa) - L; the 2L + 1 points are s and s +- the columns of a
square root of (L + lambda) P; weights Wm0 = lambda / (L + lambda),
Wc0 = Wm0 + 1 - alpha^2 + beta, Wi = 1 / (2 (L + lambda)).

Two builders give the same points: :func:`sigma_points` is written as element loops for
the compiled segment loop (its source is copied into the model's filter kernel module,
:mod:`estimators.filters.kernels`), :func:`sigma_columns` with numpy for the per-sample
Python loop. They are kept apart because their square roots come from different LAPACK
builds (numba's and numpy's), which can differ in the last bits.
"""

from __future__ import annotations

import numpy as np


def scaled_weights(L: int, alpha: float, beta: float, kappa: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Mean and covariance weights Wm, Wc (2L + 1,) and the factor L + lambda of the
    scaled sigma points for a state of L entries."""
    lam = alpha**2 * (L + kappa) - L
    Wm = np.full(2 * L + 1, 0.5 / (L + lam))
    Wc = Wm.copy()
    Wm[0] = lam / (L + lam)
    Wc[0] = Wm[0] + 1.0 - alpha**2 + beta
    return Wm, Wc, L + lam


def sqrt_psd(A: np.ndarray) -> np.ndarray:
    """A lower factor L with L L^T = A for a symmetric positive semi-definite A."""
    try:
        return np.linalg.cholesky(A)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(0.5 * (A + A.T))
        return V * np.sqrt(np.maximum(w, 0.0))


def sigma_columns(s: np.ndarray, P: np.ndarray, cfac: float) -> np.ndarray:
    """The 2L + 1 sigma points (L, 2L + 1) of mean s (L,) and covariance P (L, L):
    s, s + columns of sqrt(cfac P), s - those columns (numpy)."""
    A = sqrt_psd(cfac * P)
    return np.concatenate([s[:, None], s[:, None] + A, s[:, None] - A], axis=1)


def sigma_points(s, P, cfac):
    """The 2L + 1 sigma points (L, 2L + 1) as :func:`sigma_columns`, as element loops for
    numba (Cholesky, else the symmetric square root of the eigen-decomposition)."""
    L = s.shape[0]
    A = cfac * P
    try:
        F = np.linalg.cholesky(A)
    except Exception:  # noqa: BLE001 - numba raises a plain LinAlgError
        w, V = np.linalg.eigh(0.5 * (A + A.T))
        F = V * np.sqrt(np.maximum(w, 0.0))
    S = np.empty((L, 2 * L + 1))
    for j in range(L):
        S[j, 0] = s[j]
        for b in range(L):
            S[j, 1 + b] = s[j] + F[j, b]
            S[j, 1 + L + b] = s[j] - F[j, b]
    return S
