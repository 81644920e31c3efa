"""Unscented Kalman filter with the parameters in the state: scaled sigma points
(:mod:`estimators.filters.sigma_points`), redrawn after the prediction so that Qd reaches
the output statistics; ``augmented=True`` puts the process and measurement noise into the
sigma points (noise-augmented state [s; w; v]) instead of adding Qd and R to the
covariances. The passes, noise settings and result are
:class:`~estimators.filters.parameter_filter.ParameterFilter`'s.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.filters.filter_pass import SegmentRun, SegmentStart, run_compiled
from estimators.filters.parameter_filter import ParameterFilter
from estimators.filters.sigma_points import scaled_weights, sigma_columns
from estimators.model import Model


class UKF(ParameterFilter):
    """Unscented Kalman filter with the parameters in the state.

    Scaled sigma points (van der Merwe): lambda = alpha^2 (L + kappa) - L, points
    s +- columns of sqrt((L + lambda) P), weights Wm0 = lambda / (L + lambda),
    Wc0 = Wm0 + 1 - alpha^2 + beta, Wi = 1 / (2 (L + lambda)). Defaults alpha = 1,
    beta = 2, kappa = 0 (Wm0 = 0: no negative weights, so P stays positive).

    augmented : False (default) adds Qd and R to the predicted covariances; True draws the
        sigma points from the noise-augmented state [s; w; v] (process noise w ~ N(0, Qd)
        added after the step, measurement noise v ~ N(0, R) added to g).
    Other keywords as :class:`~estimators.filters.ekf.EKF` (process_noise, measurement_noise, param_std, ...).
    """

    method = "ukf"

    def __init__(
        self, model: Model, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0, augmented: bool = False, **kw
    ) -> None:
        super().__init__(model, **kw)
        self.alpha, self.beta, self.kappa = float(alpha), float(beta), float(kappa)
        self.augmented = augmented
        if augmented:
            self.method = "ukf-aug"

    def _weights(self, L: int) -> tuple[np.ndarray, np.ndarray, float]:
        return scaled_weights(L, self.alpha, self.beta, self.kappa)

    def _compiled_segment(self, start: SegmentStart) -> SegmentRun | None:
        if self.augmented:  # noise-augmented sigma points: Python
            return None
        Wm, Wc, cfac = self._weights(start.s.size)
        return run_compiled("ukf", start, Wm, Wc, float(cfac))

    def _sigmas(self, s: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        Wm, Wc, c = self._weights(s.size)
        return sigma_columns(s, P, c), Wm, Wc

    def _predict(self, aug, s, P, Q, i):
        n, L = aug.n, s.size
        if self.augmented:
            Pa = np.zeros((2 * L, 2 * L))
            Pa[:L, :L] = P
            Pa[L:, L:] = Q
            Sa, Wm, Wc = self._sigmas(np.concatenate([s, np.zeros(L)]), Pa)
            S = Sa[:L].copy()
            S[:n] = aug.step(S, i)
            S = S + Sa[L:]
            mean = S @ Wm
            D = S - mean[:, None]
            P = (D * Wc) @ D.T
        else:
            S, Wm, Wc = self._sigmas(s, P)
            S = S.copy()
            S[:n] = aug.step(S, i)
            mean = S @ Wm
            D = S - mean[:, None]
            P = (D * Wc) @ D.T + Q
        return mean, 0.5 * (P + P.T)

    def _update(self, aug, s, P, z, ok, R, i):
        L = s.size
        if self.augmented:
            r = R.shape[0]
            Pa = np.zeros((L + r, L + r))
            Pa[:L, :L] = P
            Pa[L:, L:] = R
            Sa, Wm, Wc = self._sigmas(np.concatenate([s, np.zeros(r)]), Pa)
            S = Sa[:L]
            Y = aug.outputs(S, i) + Sa[L:]
            Rk = 0.0
        else:
            S, Wm, Wc = self._sigmas(s, P)
            Y = aug.outputs(S, i)
            Rk = R
        y = Y @ Wm
        if not np.any(ok):
            return s, P, y, None, None
        Dy = Y - y[:, None]
        Ds = S - s[:, None]
        Syy = (Dy * Wc) @ Dy.T + Rk
        Ssy = (Ds * Wc) @ Dy.T
        Syy, Ssy = Syy[np.ix_(ok, ok)], Ssy[:, ok]
        K = np.linalg.solve(Syy, Ssy.T).T
        s = s + K @ (z[ok] - y[ok])
        P = P - K @ Syy @ K.T
        return s, 0.5 * (P + P.T), y, K, Syy

    def _settings(self) -> dict[str, Any]:
        return {
            **super()._settings(),
            "alpha": self.alpha,
            "beta": self.beta,
            "kappa": self.kappa,
            "augmented": self.augmented,
        }
