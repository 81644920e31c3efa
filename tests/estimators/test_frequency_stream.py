"""The Fourier transform at the samples' own times (estimators.frequency.stream) and the
Fourier regression on it: exact for the piecewise-linear interpolant, the same sample by
sample as whole, the derivative's transform by parts; a regression of a rate's derivative on
jittered stamps recovers the truth, and its real-time form ends where the whole-record fit is."""

import numpy as np
import pandas as pd
import pytest

from estimators import FourierRegression
from estimators.errors import ModelDefinitionError
from estimators.frequency.stream import (
    StreamingFourierTransform,
    derivative_transform,
    interval_weights,
    linear_fourier_transform,
)
from estimators.frequency.transform import fourier_transform


def _stamps(n=1500, seed=0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(0.01 * (1 + 0.3 * rng.uniform(-1, 1, n)))
    return t - t[0] + 3.0, rng


def test_exact_for_the_linear_interpolant_and_the_same_streamed():
    t, _ = _stamps()
    x = np.column_stack([np.sin(2 * np.pi * 0.7 * t), 0.3 * np.cos(2 * np.pi * 1.9 * t) + 0.2])
    w = 2 * np.pi * np.linspace(0.05, 3.0, 25)
    X = linear_fourier_transform(t, x, w)
    # a line's transform in closed form, interval by interval: the same sum another way
    E = np.zeros((w.size, 2), dtype=complex)
    for a in range(t.size - 1):
        ta, tb = t[a], t[a + 1]
        k = (x[a + 1] - x[a]) / (tb - ta)
        ea, eb = np.exp(-1j * w * ta), np.exp(-1j * w * tb)
        jw = 1j * w
        # integral (x_a + k (t - t_a)) e^{-jwt} dt
        E += np.outer((ea - eb) / jw, x[a]) + np.outer((-(tb - ta) * eb) / jw + (ea - eb) / jw**2, k)
    np.testing.assert_allclose(X, E, rtol=1e-9, atol=1e-12 * np.abs(E).max())
    S = StreamingFourierTransform(w, 2)
    for ti, xi in zip(t, x):
        S.update(ti, xi)
    np.testing.assert_allclose(S.X, X, rtol=1e-12, atol=1e-13 * np.abs(X).max())
    np.testing.assert_allclose(S.derivative(), derivative_transform(t, x, w, X), rtol=1e-12, atol=1e-12)
    # the derivative of a signal known in closed form: its transform against the samples'
    y = np.sin(2 * np.pi * 0.4 * t)
    D = derivative_transform(t, y, w)
    Dd = linear_fourier_transform(t, 2 * np.pi * 0.4 * np.cos(2 * np.pi * 0.4 * t), w)
    assert np.max(np.abs(D - Dd)) < 2e-3 * np.max(np.abs(Dd))  # the interpolant's error, O(h^2)


def test_on_a_grid_it_is_close_to_the_cubic_transform_and_the_series_joins():
    t = np.arange(2000) * 0.01
    x = np.sin(2 * np.pi * 0.7 * t)
    w = 2 * np.pi * np.linspace(0.1, 3.0, 20)
    lin, cub = linear_fourier_transform(t, x, w), fourier_transform(t, x, w, "none")
    assert np.max(np.abs(lin - cub)) < 1e-3 * np.max(np.abs(cub))  # second against fourth order
    A1, B1 = interval_weights(np.array([0.0999999999, 0.1000000001]))
    np.testing.assert_allclose(A1[0], A1[1], rtol=1e-8)
    np.testing.assert_allclose(B1[0], B1[1], rtol=1e-8)
    with pytest.raises(ModelDefinitionError, match="increasing"):
        linear_fourier_transform(t[::-1], x, w)


def test_a_rate_derivative_regressed_on_jittered_stamps():
    t, rng = _stamps(3000, seed=1)
    a = 0.05 * np.sin(2 * np.pi * 0.5 * t) + 0.01 * rng.standard_normal(t.size)
    de = 0.03 * np.sign(np.sin(2 * np.pi * 0.3 * t))
    qdot = 0.4 - 2.0 * a - 4.0 * de
    q = np.r_[0.0, np.cumsum(np.diff(t) * 0.5 * (qdot[1:] + qdot[:-1]))]  # the trapezoid's integral
    X = pd.DataFrame({"one": np.ones_like(t), "a": a, "de": de}, index=pd.Index(t, name="t"))
    f = np.linspace(0.1, 2.0, 30)
    off = FourierRegression(frequencies=f, detrend="none", response_derivative=True).fit(X, q)
    # noise-free: only the trapezoid's q against the interpolants' (their derivative is the
    # interval's mean of qdot, not qdot's line through the interval) is left, O(h^2)
    np.testing.assert_allclose(off.params[["one", "a", "de"]], [0.4, -2.0, -4.0], rtol=1e-3)
    rt = FourierRegression(frequencies=f, detrend="none", response_derivative=True)
    rt.start(None, 3)
    for ti, xi, yi in zip(t, X.to_numpy(), q):
        rt.update(xi, yi, ti)
    theta, cov = rt.estimate()
    np.testing.assert_allclose(theta, off.values, rtol=1e-9)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), off.std.to_numpy(), rtol=1e-9)
    with pytest.raises(ModelDefinitionError, match="detrend='none'"):
        FourierRegression(frequencies=f).start(None, 3)
