"""The finite Fourier transform of sampled data at any frequencies.

X(w) = integral over the record of x(t) e^{-jwt} dt, evaluated exactly for the samples'
piecewise-cubic (Lagrange) interpolant: the discrete sum sum_j x_j e^{-jw t_j} times a
weight W(w dt), plus corrections from the first and last four samples (Press et al.,
Numerical Recipes, 2nd ed., section 13.9; Morelli, "High accuracy evaluation of the finite
Fourier transform using sampled data", NASA TM-110340, 1997). The plain sum dt sum x_j
e^{-jw t_j} (a rectangle rule) is only first-order accurate near the ends and wrong by a
factor that grows with w dt; the corrected one is fourth order. The sum runs as a chirp-z
transform (scipy.signal.czt) when the frequencies are equally spaced, else directly.

Every frequency-domain method of the package transforms its data with this one function.
"""

from __future__ import annotations

from fractions import Fraction
from math import factorial

import numpy as np

from estimators.errors import ModelDefinitionError

#: detrending before the transform: "ends" removes the line through the first and last
#: samples (SIDPAC's convention; the record then starts and ends at zero, which keeps the
#: ends from leaking into every frequency), "linear" a least-squares line, "none" nothing
DETRENDS = ("ends", "linear", "none")
#: largest relative spread of the sample intervals taken as uniform sampling
UNIFORM_RTOL = 1e-6
#: below this w dt the weights come from their Taylor series (the closed forms divide by
#: (w dt)^4 and lose about eps / (w dt)^4 relative accuracy)
SERIES_BELOW = 0.25
#: the direct sum works in blocks of this many frequency x sample products
_BLOCK = 2_000_000


def _taylor(kind: str, n: int) -> list[Fraction]:
    """Coefficients of theta^0..theta^(n-1) of cos(theta) ("cos"), sin(theta) ("sin"),
    cos(2 theta) ("cos2") or sin(2 theta) ("sin2")."""
    out = [Fraction(0)] * n
    scale = 2 if kind.endswith("2") else 1
    for k in range(n):
        if kind.startswith("cos") and k % 2 == 0:
            out[k] = Fraction((-1) ** (k // 2) * scale**k, factorial(k))
        if kind.startswith("sin") and k % 2 == 1:
            out[k] = Fraction((-1) ** (k // 2) * scale**k, factorial(k))
    return out


def _series_coefficients(n_terms: int = 14) -> np.ndarray:
    """(9, n_terms) Taylor coefficients (ascending powers of theta) of W, Re alpha_0..3,
    Im alpha_0..3: each is a numerator of known series divided by theta^4, exactly."""
    n = n_terms + 4
    c, s, c2, s2 = (_taylor(k, n) for k in ("cos", "sin", "cos2", "sin2"))

    def poly(*terms: tuple[Fraction, int, list[Fraction] | None]) -> list[Fraction]:
        """sum of coef * theta^power * (series or 1)."""
        out = [Fraction(0)] * n
        for coef, power, ser in terms:
            for k in range(n - power):
                v = (ser[k] if ser is not None else (1 if k == 0 else 0)) * coef
                out[k + power] += v
        return out

    def mul6(ser: list[Fraction], scale: Fraction) -> list[Fraction]:
        """(6 + theta^2) * ser * scale."""
        return poly((6 * scale, 0, ser), (scale, 2, ser))

    def add(*ps: list[Fraction]) -> list[Fraction]:
        return [sum(x) for x in zip(*ps)]

    one = Fraction(1)
    W = mul6(add(poly((Fraction(3), 0, None)), poly((Fraction(-4), 0, c)), c2), one / 3)
    re = [
        add(
            poly((Fraction(-42, 6), 0, None), (Fraction(5, 6), 2, None)),
            mul6(add(poly((8, 0, c)), poly((-1, 0, c2))), one / 6),
        ),
        add(poly((Fraction(14 * 3, 6), 0, None), (Fraction(-14, 6), 2, None)), mul6(c, Fraction(-7, 6))),
        add(poly((Fraction(-12, 3), 0, None), (Fraction(4, 3), 2, None)), mul6(c, Fraction(2, 3))),
        add(poly((Fraction(6, 6), 0, None), (Fraction(-2, 6), 2, None)), mul6(c, Fraction(-1, 6))),
    ]
    im = [
        add(poly((Fraction(-12, 6), 1, None), (Fraction(6, 6), 3, None)), mul6(s2, one / 6)),
        add(poly((Fraction(30, 6), 1, None)), mul6(s, Fraction(-5, 6))),
        add(poly((Fraction(-12, 3), 1, None)), mul6(s, Fraction(2, 3))),
        add(poly((Fraction(6, 6), 1, None)), mul6(s, Fraction(-1, 6))),
    ]
    rows = []
    for p in [W, *re, *im]:
        assert all(x == 0 for x in p[:4]), "the numerator must vanish to theta^3"
        rows.append([float(x) for x in p[4 : 4 + n_terms]])
    return np.array(rows)


_SERIES = _series_coefficients()


def cubic_weights(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """W(theta) (n_f,) and the end corrections alpha_0..3(theta) (4, n_f) complex of the
    cubic finite Fourier integral in the e^{+j w t} convention (Numerical Recipes eq.
    13.9.13); the e^{-j w t} transform uses alpha(-theta) = conj(alpha(theta))."""
    th = np.asarray(theta, dtype=float)
    small = np.abs(th) < SERIES_BELOW
    big = ~small
    W = np.empty(th.shape)
    a = np.empty((4, *th.shape), dtype=complex)
    if np.any(small):
        ts = th[small]
        vals = np.array([np.polynomial.polynomial.polyval(ts, row) for row in _SERIES])
        W[small] = vals[0]
        a[:, small] = vals[1:5] + 1j * vals[5:9]
    if np.any(big):
        t = th[big]
        c, s, c2, s2 = np.cos(t), np.sin(t), np.cos(2 * t), np.sin(2 * t)
        t2, t4 = t * t, t**4
        W[big] = (6 + t2) / (3 * t4) * (3 - 4 * c + c2)
        a[0, big] = (-42 + 5 * t2) / (6 * t4) + (6 + t2) * (8 * c - c2) / (6 * t4)
        a[0, big] += 1j * ((-12 * t + 6 * t**3) / (6 * t4) + (6 + t2) * s2 / (6 * t4))
        a[1, big] = (14 * (3 - t2) - 7 * (6 + t2) * c) / (6 * t4) + 1j * (30 * t - 5 * (6 + t2) * s) / (6 * t4)
        a[2, big] = (-4 * (3 - t2) + 2 * (6 + t2) * c) / (3 * t4) + 1j * (-12 * t + 2 * (6 + t2) * s) / (3 * t4)
        a[3, big] = (2 * (3 - t2) - (6 + t2) * c) / (6 * t4) + 1j * (6 * t - (6 + t2) * s) / (6 * t4)
    return W, a


def uniform_step(t: np.ndarray, what: str = "fourier_transform") -> float:
    """The sample interval dt (s) of uniformly sampled times ``t`` (N,); ModelDefinitionError
    when they are not uniform (resample first) or too few."""
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size < 4:
        raise ModelDefinitionError(f"{what} needs a time vector of at least 4 samples, got shape {t.shape}")
    d = np.diff(t)
    dt = float(np.mean(d))
    if not np.all(np.isfinite(d)) or dt <= 0 or np.max(np.abs(d - dt)) > UNIFORM_RTOL * dt:
        raise ModelDefinitionError(
            f"{what} needs uniformly sampled data: the intervals run from {np.min(d):.6g} to {np.max(d):.6g} s; "
            "resample onto a uniform grid first"
        )
    return dt


def detrended(t: np.ndarray, x: np.ndarray, detrend: str = "ends") -> np.ndarray:
    """``x`` (N,) or (N, n) with the trend of ``detrend`` removed (see DETRENDS)."""
    if detrend not in DETRENDS:
        raise ModelDefinitionError(f"detrend={detrend!r}: use one of {', '.join(DETRENDS)}")
    x = np.asarray(x, dtype=float)
    if detrend == "none":
        return x
    t = np.asarray(t, dtype=float)
    s = (t - t[0]) / (t[-1] - t[0])
    if detrend == "ends":
        trend = x[0] + np.multiply.outer(s, x[-1] - x[0])
        return x - trend
    A = np.column_stack([np.ones_like(s), s])
    coef, *_ = np.linalg.lstsq(A, x, rcond=None)
    return x - A @ coef


def _discrete_sum(x: np.ndarray, w: np.ndarray, dt: float) -> np.ndarray:
    """sum_j x_j e^{-j w dt j} (n_f, n) for x (N, n): a chirp-z transform when w is equally
    spaced (and long), else the direct sum in blocks."""
    N = x.shape[0]
    if w.size > 16:
        dw = np.diff(w)
        if np.all(np.abs(dw - dw[0]) <= 1e-9 * max(abs(dw[0]), 1e-300)) and dw[0] != 0:
            from scipy.signal import czt

            a = np.exp(1j * w[0] * dt)
            step = np.exp(-1j * dw[0] * dt)
            return czt(x, m=w.size, w=step, a=a, axis=0)
    out = np.empty((w.size, x.shape[1]), dtype=complex)
    n = np.arange(N) * dt
    rows = max(1, _BLOCK // max(N, 1))
    for i in range(0, w.size, rows):
        E = np.exp(-1j * np.outer(w[i : i + rows], n))
        out[i : i + rows] = E @ x
    return out


def fourier_transform(t: np.ndarray, x: np.ndarray, w: np.ndarray, detrend: str = "ends") -> np.ndarray:
    """The finite Fourier transform X(w) = integral x(t) e^{-jwt} dt over the record, exact
    for the samples' cubic interpolant (module docstring), at any frequencies.

    t : (N,) uniformly sampled times (s), N >= 4 (the phase is that of these times, not of
        the time from the record's start).
    x : (N,) or (N, n) samples.
    w : (n_f,) frequencies (rad/s).
    detrend : "ends" (default: the line through the first and last samples removed),
        "linear" (a least-squares line), "none".
    Returns (n_f,) or (n_f, n) complex, in x's units times seconds.
    """
    t = np.asarray(t, dtype=float)
    dt = uniform_step(t)
    x = np.asarray(x, dtype=float)
    one = x.ndim == 1
    X2 = x[:, None] if one else x
    if X2.ndim != 2 or X2.shape[0] != t.size:
        raise ModelDefinitionError(f"fourier_transform: x has shape {x.shape}, t has {t.size} samples")
    if not np.all(np.isfinite(X2)):
        raise ModelDefinitionError("fourier_transform: x holds NaN or inf; fill or cut them out first")
    w = np.atleast_1d(np.asarray(w, dtype=float))
    h = detrended(t, X2, detrend)
    W, a = cubic_weights(w * dt)
    S = _discrete_sum(h, w, dt)
    head = np.einsum("kf,kn->fn", np.conj(a), h[:4])
    tail = np.einsum("kf,kn->fn", a, h[::-1][:4])
    X = dt * (np.exp(-1j * w * t[0])[:, None] * (W[:, None] * S + head) + np.exp(-1j * w * t[-1])[:, None] * tail)
    return X[:, 0] if one else X
