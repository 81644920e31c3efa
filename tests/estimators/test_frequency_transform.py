"""The finite Fourier transform (estimators.fourier_transform): exact for the samples'
cubic interpolant, at any frequencies, with the detrending conventions of the contract."""

import numpy as np
import pytest
from scipy.integrate import quad

from estimators import ModelDefinitionError, fourier_transform


def _exact(fun, a, b, w):
    """integral_a^b fun(t) e^{-jwt} dt by QUADPACK's oscillatory-weight rule (QAWO)."""
    if w == 0:
        return quad(fun, a, b, epsabs=1e-14, epsrel=1e-13)[0]
    re = quad(fun, a, b, weight="cos", wvar=w, epsabs=1e-14, epsrel=1e-13, limit=200)[0]
    im = -quad(fun, a, b, weight="sin", wvar=w, epsabs=1e-14, epsrel=1e-13, limit=200)[0]
    return re + 1j * im


def test_a_cubic_is_transformed_exactly_at_any_frequency():
    """A cubic is its own cubic interpolant, so the transform is the exact integral, whatever
    w dt (the small values come from the weights' series, the large from closed forms);
    the record starts at 0.3 s: the phase is that of the times given."""
    cubic = lambda x: 0.2 - 1.3 * x + 0.7 * x**2 - 0.11 * x**3  # noqa: E731
    t = np.linspace(0.3, 5.3, 1001)
    w = np.array([0.0, 1e-3, 0.05, 0.7, 3.0, 20.0, 150.0, 600.0])
    X = fourier_transform(t, cubic(t), w, detrend="none")
    for k, wk in enumerate(w):
        ex = _exact(cubic, t[0], t[-1], wk)
        assert abs(X[k] - ex) <= 1e-9 * abs(ex), (wk, X[k], ex)


def test_smooth_signals_converge_at_fourth_order_and_the_plain_sum_does_not():
    fun = lambda x: np.sin(1.3 * x) * np.exp(-0.2 * x) + 0.5  # noqa: E731
    w, T = 2.0, 10.0

    def integral(c):  # integral_0^T e^{c t} dt
        return (np.exp(c * T) - 1) / c

    ex = (integral(-0.2 + 1.3j - 1j * w) - integral(-0.2 - 1.3j - 1j * w)) / 2j + 0.5 * integral(-1j * w)
    errs = []
    for n in (101, 201, 401):
        t = np.linspace(0, 10, n)
        errs.append(abs(fourier_transform(t, fun(t), [w], detrend="none")[0] - ex))
    assert 12 < errs[0] / errs[1] < 20 and 12 < errs[1] / errs[2] < 20, errs  # 2^4 = 16
    t = np.linspace(0, 10, 401)
    plain = np.sum(fun(t) * np.exp(-1j * w * t)) * (t[1] - t[0])
    assert abs(plain - ex) > 1e4 * errs[2]


def test_equally_spaced_frequencies_take_the_chirp_z_path_and_agree_with_the_direct_sum():
    rng = np.random.default_rng(0)
    t = np.arange(3000) * 0.01
    x = rng.standard_normal((3000, 2)).cumsum(axis=0)
    w = np.linspace(0.2, 40.0, 300)  # equally spaced: chirp-z
    jitter = w + 1e-13 * np.arange(300) ** 2  # not equally spaced: direct
    a, b = fourier_transform(t, x, w), fourier_transform(t, x, jitter)
    assert a.shape == (300, 2)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.abs(a).max())


def test_detrending_conventions():
    t = np.linspace(2.0, 12.0, 501)
    x = 3.0 + 0.4 * t + np.sin(2.0 * t)
    w = np.array([0.5, 2.0, 5.0])
    ends = fourier_transform(t, x, w)  # default "ends"
    line = x[0] + (x[-1] - x[0]) * (t - t[0]) / (t[-1] - t[0])
    np.testing.assert_allclose(ends, fourier_transform(t, x - line, w, detrend="none"), rtol=1e-12)
    A = np.column_stack([np.ones_like(t), t])
    ls = x - A @ np.linalg.lstsq(A, x, rcond=None)[0]
    np.testing.assert_allclose(fourier_transform(t, x, w, detrend="linear"), fourier_transform(t, ls, w, "none"))
    # a constant and a ramp are removed whole by either
    np.testing.assert_allclose(fourier_transform(t, 5.0 - 2.0 * t, w), 0.0, atol=1e-12)


def test_bad_input_is_refused_with_a_reason():
    t = np.linspace(0, 1, 50)
    with pytest.raises(ModelDefinitionError, match="uniformly sampled"):
        fourier_transform(np.r_[t[:10], t[11:]], np.zeros(49), [1.0])
    with pytest.raises(ModelDefinitionError, match="NaN"):
        fourier_transform(t, np.r_[np.zeros(49), np.nan], [1.0])
    with pytest.raises(ModelDefinitionError, match="detrend"):
        fourier_transform(t, np.zeros(50), [1.0], detrend="mean")
    with pytest.raises(ModelDefinitionError, match="at least 4 samples"):
        fourier_transform(t[:3], np.zeros(3), [1.0])
