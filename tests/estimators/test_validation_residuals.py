"""Residual statistics, autocorrelation and the whiteness test (white vs AR(1) noise), PSD."""

import numpy as np
import pytest
from scipy import signal, stats

from estimators.validation import autocorrelation, psd, residual_stats, whiteness


def test_autocorrelation_hand_computed():
    # x - mean = [-1.5, -0.5, 0.5, 1.5]; c0 = 1.25, c1 = 0.3125, c2 = -0.375, c3 = -0.5625
    rho = autocorrelation(np.array([1.0, 2.0, 3.0, 4.0]))
    np.testing.assert_allclose(rho[:, 0], [1.0, 0.25, -0.3, -0.45], rtol=1e-12)


def test_whiteness_statistic_hand_computed():
    x = np.tile([1.0, -1.0], 10)  # N = 20, rho_1 = -19/20
    w = whiteness(x, max_lag=1)
    q = 20 * 22 * 0.95**2 / 19
    np.testing.assert_allclose(w.statistic, [q], rtol=1e-12)
    np.testing.assert_allclose(w.threshold, 3.841458820694124, rtol=1e-9)
    assert not w.white[0]


def test_whiteness_accepts_white_rejects_ar1():
    rng = np.random.default_rng(12345)
    n = 3000
    white = rng.normal(size=(n, 2)) * [0.01, 2.0]
    w = whiteness(white, max_lag=20, names=["q", "az"])
    assert w.white.all(), w.to_frame()
    assert np.all(w.statistic < w.threshold)
    assert np.all(w.frac_outside <= 0.2)  # ~5 % of lags expected outside
    # AR(1), phi = 0.5: rho_1 ~ 0.5 >> 1.96/sqrt(N)
    ar = signal.lfilter([1.0], [1.0, -0.5], rng.normal(size=(n, 2)), axis=0)
    c = whiteness(ar, max_lag=20)
    assert not c.white.any()
    assert np.all(c.statistic > 10 * c.threshold)
    np.testing.assert_allclose(c.acf[1], 0.5, atol=0.05)
    np.testing.assert_allclose(c.threshold, stats.chi2.ppf(0.95, 20))
    assert list(w.to_frame().index) == ["q", "az"]


def test_residual_stats_values():
    e = np.array([[1.0, 0.0], [3.0, 0.0], [2.0, 3.0], [2.0, -3.0]])
    df = residual_stats(e, names=["a", "b"])
    np.testing.assert_allclose(df["mean"], [2.0, 0.0])
    np.testing.assert_allclose(df["std"], [np.sqrt(0.5), np.sqrt(4.5)])
    np.testing.assert_allclose(df["rms"], [np.sqrt(4.5), np.sqrt(4.5)])
    np.testing.assert_allclose(df.loc["a", "mean_over_std"], 2.0 / np.sqrt(0.5))


def test_psd_white_level_and_sine_peak():
    rng = np.random.default_rng(7)
    fs, n, sigma = 100.0, 2**15, 0.3
    f, p = psd(rng.normal(scale=sigma, size=n), fs)
    # one-sided PSD of white noise: 2 sigma^2 / fs
    np.testing.assert_allclose(p[1:-1].mean(), 2 * sigma**2 / fs, rtol=0.05)
    t = np.arange(n) / fs
    f, p = psd(np.sin(2 * np.pi * 12.5 * t), fs, nperseg=1024, method="welch")
    assert f[np.argmax(p[:, 0])] == pytest.approx(12.5, abs=fs / 1024)
    f2, p2 = psd(np.sin(2 * np.pi * 12.5 * t), fs, method="periodogram")
    assert f2[np.argmax(p2[:, 0])] == pytest.approx(12.5, abs=fs / n)


def test_whiteness_segments_pool_without_crossing_boundaries():
    rng = np.random.default_rng(8)
    a, b = rng.normal(size=(1500, 1)), rng.normal(size=(1500, 1)) + 5.0  # different means
    pooled = whiteness([a, b], max_lag=10)
    assert pooled.white[0]
    # concatenated, the step in the mean between segments looks like strong colour
    assert not whiteness(np.vstack([a, b]), max_lag=10).white[0]
    # one segment as a list equals the plain call
    np.testing.assert_allclose(whiteness([a], max_lag=10).statistic, whiteness(a, max_lag=10).statistic, rtol=1e-12)
