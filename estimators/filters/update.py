"""Kalman measurement-update pieces shared by the parameter-estimating filters."""

from __future__ import annotations

import numpy as np


def joseph_update(P: np.ndarray, H: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kalman measurement update of the covariance P (..., L, L) with output Jacobian H
    (..., k, L) and noise R (k, k), stacked over leading axes: (P in Joseph form
    (I - K H) P (I - K H)^T + K R K^T, made symmetric; gain K = P H^T S^-1 (..., L, k);
    innovation covariance S = H P H^T + R)."""
    T = lambda A: np.swapaxes(A, -1, -2)  # noqa: E731
    S = H @ P @ T(H) + R
    K = T(np.linalg.solve(S, H @ P))  # S symmetric
    IKH = np.eye(P.shape[-1]) - K @ H
    P = IKH @ P @ T(IKH) + K @ R @ T(K)
    return 0.5 * (P + T(P)), K, S


def innovation_nll(nu: np.ndarray, S: np.ndarray) -> float:
    """0.5 (nu^T S^-1 nu + ln det S) of one update's innovations nu (m,), covariance S."""
    sign, logdet = np.linalg.slogdet(S)
    if sign <= 0:
        return np.inf
    return 0.5 * (nu @ np.linalg.solve(S, nu) + logdet)
