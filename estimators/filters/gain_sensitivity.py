"""Ljung's modification of the parameter-in-the-state filters: the gain's dependence on
the parameters (Ljung 1979, IEEE TAC 24(1))."""

from __future__ import annotations

import numpy as np

from estimators.filters.augmented import AugmentedModel
from estimators.filters.update import joseph_update


class GainSensitivity:
    """The state-only Kalman filters of one segment at the current parameter estimate
    theta and at theta + d_j e_j (j = 1..m), for Ljung's modification of the
    parameter-in-the-state filters (Ljung 1979, IEEE TAC 24(1)).

    The filters' state correction K_x(theta) nu depends on the parameters through the gain;
    the plain EKF/UKF neglect that dependence, so their x-theta cross-covariance misses the
    term (dK_x/dtheta) nu and the parameter estimates are biased wherever the gain is large
    (an unmeasured gust state corrected through a derivative). Here the gain K_j of the
    state-only filter (P_j (n, n), linearised at the filter's state) is carried along at
    each parameter perturbation, and after each update the augmented covariance is mapped
    by J = [[I, M], [0, I]], M[:, j] = (K_j - K_0) nu / d_j (n, m): the Jacobian of the
    update x+ = x- + K(theta) nu with respect to theta."""

    def __init__(self, n: int, s: np.ndarray, Px: np.ndarray, step: float, fd_step: float) -> None:
        m = s.size - n
        self.n, self.m = n, m
        self.P = np.repeat(Px[None], m + 1, axis=0)  # (m + 1, n, n)
        self.d = step * np.maximum(np.abs(s[n:]), 1.0)  # (m,)
        self.fd = fd_step

    def _columns(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Augmented columns (L, (m + 1)(n + 1)): per parameter set j (nominal first) the
        state and its n forward-difference steps; the state steps h (n,)."""
        n, m = self.n, self.m
        h = self.fd * np.maximum(np.abs(s[:n]), 1.0)
        base = np.repeat(s[:, None], m + 1, axis=1)
        base[n + np.arange(m), 1 + np.arange(m)] += self.d
        S = np.repeat(base[:, :, None], n + 1, axis=2)  # (L, m + 1, n + 1)
        S[np.arange(n), :, 1 + np.arange(n)] += h[:, None]
        return S.reshape(s.size, -1), h

    def _jacobian(self, Y: np.ndarray, h: np.ndarray) -> np.ndarray:
        """(m + 1, rows, n) forward-difference Jacobians from evaluations Y (rows, cols)."""
        Y = Y.reshape(Y.shape[0], self.m + 1, self.n + 1)
        return np.transpose((Y[:, :, 1:] - Y[:, :, :1]) / h, (1, 0, 2))

    def predict(self, aug: AugmentedModel, s: np.ndarray, Qx: np.ndarray, i: int) -> None:
        """Each P_j over the step from sample i, linearised about the posterior s."""
        S, h = self._columns(s)
        Phi = self._jacobian(aug.step(S, i), h)
        self.P = Phi @ self.P @ np.transpose(Phi, (0, 2, 1)) + Qx

    def update(
        self, aug: AugmentedModel, s: np.ndarray, ok: np.ndarray, R: np.ndarray, nu: np.ndarray, i: int
    ) -> np.ndarray:
        """Each P_j updated on the outputs ``ok`` about the predicted s; returns M (n, m)
        for the innovations nu (on ``ok``)."""
        S, h = self._columns(s)
        H = self._jacobian(aug.outputs(S, i), h)[:, ok]  # (m + 1, k, n)
        self.P, K, _ = joseph_update(self.P, H, R[np.ix_(ok, ok)])
        return ((K[1:] - K[:1]) @ nu).T / self.d  # (n, m)

    @staticmethod
    def apply(P: np.ndarray, M: np.ndarray, n: int) -> np.ndarray:
        """J P J^T with J = [[I, M], [0, I]] (P (L, L) the posterior covariance)."""
        P = P.copy()
        P[:n] += M @ P[n:]
        P[:, :n] += P[:, n:] @ M.T
        return 0.5 * (P + P.T)
