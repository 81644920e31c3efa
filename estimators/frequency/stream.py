"""The finite Fourier transform of samples at their own, irregular times, whole or sample by
sample.

A telemetry stream arrives with jitter and gaps: its samples are not on a grid, and the
cubic-interpolant transform of :func:`~estimators.frequency.transform.fourier_transform`
does not apply. Here X(w) = integral x(t) e^{-jwt} dt is evaluated exactly for the samples'
piecewise-linear interpolant: each interval [t_a, t_b] (h = t_b - t_a, theta = w h) adds

    h e^{-jw t_a} (x_a A(theta) + x_b B(theta)),
    A = integral_0^1 (1 - s) e^{-j theta s} ds,  B = integral_0^1 s e^{-j theta s} ds,

so the recursive form (:class:`StreamingFourierTransform`, one interval per new sample) and
the whole-record form (:func:`linear_fourier_transform`) are the same sum. Its derivative's
transform follows by parts, exactly for the same interpolant:
integral x' e^{-jwt} dt = jw X(w) + x(t_N) e^{-jw t_N} - x(t_0) e^{-jw t_0} (Morelli's
real-time method regresses it instead of a differentiated signal).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from estimators.errors import ModelDefinitionError

#: below this |theta| the weights come from their Taylor series (the closed forms divide by
#: theta^2 and lose about eps / theta^2 relative accuracy)
SERIES_BELOW = 0.1
_TERMS = 12


def interval_weights(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the module docstring at theta = w h (any shape)."""
    th = np.asarray(theta, dtype=float)
    small = np.abs(th) < SERIES_BELOW
    A = np.empty(th.shape, dtype=complex)
    B = np.empty(th.shape, dtype=complex)
    if np.any(small):
        z = -1j * th[small]
        # integral_0^1 s^m e^{z s} ds = sum_n z^n / (n! (n + m + 1))
        term = np.ones_like(z)
        i0 = np.zeros_like(z)
        i1 = np.zeros_like(z)
        for n in range(_TERMS):
            i0 += term / (n + 1)
            i1 += term / (n + 2)
            term = term * z / (n + 1)
        A[small], B[small] = i0 - i1, i1
    big = ~small
    if np.any(big):
        t = th[big]
        e = np.exp(-1j * t)
        jt = 1j * t
        i0 = (1.0 - e) / jt
        i1 = -e / jt + (1.0 - e) / jt**2
        A[big], B[big] = i0 - i1, i1
    return A, B


def _checked(t: np.ndarray, x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    t = np.asarray(t, dtype=float).ravel()
    x = np.asarray(x, dtype=float)
    one = x.ndim == 1
    X2 = x[:, None] if one else x
    if X2.ndim != 2 or X2.shape[0] != t.size or t.size < 2:
        raise ModelDefinitionError(f"linear_fourier_transform: x has shape {x.shape}, t has {t.size} samples (>= 2)")
    if not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)):
        raise ModelDefinitionError("linear_fourier_transform: the times must be finite and strictly increasing")
    if not np.all(np.isfinite(X2)):
        raise ModelDefinitionError("linear_fourier_transform: x holds NaN or inf; cut them out first")
    return t, X2, np.atleast_1d(np.asarray(w, dtype=float)), one


def linear_fourier_transform(t: np.ndarray, x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """X(w) of samples ``x`` (N,) or (N, n) at strictly increasing, possibly irregular times
    ``t`` (N,) s, exact for their piecewise-linear interpolant (module docstring), at
    frequencies ``w`` (n_f,) rad/s; (n_f,) or (n_f, n) complex, x's units times seconds."""
    t, X2, w, one = _checked(t, x, w)
    h = np.diff(t)
    A, B = interval_weights(np.outer(w, h))  # (n_f, N-1)
    E = np.exp(-1j * np.outer(w, t[:-1])) * h[None, :]
    X = (E * A) @ X2[:-1] + (E * B) @ X2[1:]
    return X[:, 0] if one else X


def derivative_transform(t: np.ndarray, x: np.ndarray, w: np.ndarray, X: np.ndarray | None = None) -> np.ndarray:
    """The transform of x's time derivative, jw X(w) + x(t_N) e^{-jw t_N} - x(t_0) e^{-jw t_0}
    (exact for any interpolant through the samples); ``X`` the transform of x when known."""
    t, X2, w, one = _checked(t, x, w)
    if X is None:
        X = linear_fourier_transform(t, X2, w)
    X = X[:, None] if X.ndim == 1 else X
    D = 1j * w[:, None] * X + np.outer(np.exp(-1j * w * t[-1]), X2[-1]) - np.outer(np.exp(-1j * w * t[0]), X2[0])
    return D[:, 0] if one else D


class StreamingFourierTransform:
    """:func:`linear_fourier_transform` of ``n_channels`` channels built sample by sample:
    ``update(t, x)`` adds the interval from the previous sample (the first sample only
    starts the record). ``X`` (n_f, n_channels) is the transform so far; ``derivative()``
    the transform of the channels' time derivative. ``w`` in rad/s."""

    def __init__(self, w: Sequence[float], n_channels: int) -> None:
        self.w = np.atleast_1d(np.asarray(w, dtype=float))
        self.X = np.zeros((self.w.size, int(n_channels)), dtype=complex)
        self.t0: float | None = None
        self.x0: np.ndarray | None = None
        self.t_last: float | None = None
        self.x_last: np.ndarray | None = None
        self.count = 0

    def update(self, t: float, x: Sequence[float]) -> np.ndarray:
        """Add the sample ``x`` (n_channels,) at time ``t`` (s, after the previous one)."""
        x = np.asarray(x, dtype=float).ravel()
        if self.t_last is None:
            self.t0, self.x0 = float(t), x.copy()
        else:
            h = float(t) - self.t_last
            if not h > 0:
                raise ModelDefinitionError(
                    f"StreamingFourierTransform: t={t} is not after the last sample {self.t_last}"
                )
            A, B = interval_weights(self.w * h)
            self.X += (np.exp(-1j * self.w * self.t_last) * h)[:, None] * (np.outer(A, self.x_last) + np.outer(B, x))
        self.t_last, self.x_last = float(t), x
        self.count += 1
        return self.X

    def update_many(self, t: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Add the samples ``x`` (N, n_channels) at times ``t`` (N,) at once: the same sum as
        N calls of :meth:`update`, vectorised over the new intervals."""
        t = np.asarray(t, dtype=float).ravel()
        x = np.asarray(x, dtype=float).reshape(t.size, -1)
        if t.size == 0:
            return self.X
        if self.t_last is None:
            self.update(t[0], x[0])
            t, x = t[1:], x[1:]
            if t.size == 0:
                return self.X
        tt = np.r_[self.t_last, t]
        if not np.all(np.diff(tt) > 0):
            raise ModelDefinitionError("StreamingFourierTransform: the new samples' times must increase after the last")
        xx = np.vstack([self.x_last[None, :], x])
        self.X += linear_fourier_transform(tt, xx, self.w) if tt.size > 1 else 0.0
        self.t_last, self.x_last = float(tt[-1]), xx[-1].copy()
        self.count += t.size
        return self.X

    def derivative(self) -> np.ndarray:
        """The transform of the channels' time derivative over the samples so far."""
        if self.t_last is None:
            return np.zeros_like(self.X)
        return (
            1j * self.w[:, None] * self.X
            + np.outer(np.exp(-1j * self.w * self.t_last), self.x_last)
            - np.outer(np.exp(-1j * self.w * self.t0), self.x0)
        )
