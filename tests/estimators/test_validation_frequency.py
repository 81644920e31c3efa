"""Frequency response of known transfer functions, spectral estimates from noisy data with
coherence, and the mismatch against bounds."""

import numpy as np
import pytest
from scipy import signal

from estimators.validation import bode, freq_response, mismatch, spectral_estimate

WN, ZETA = 3.0, 0.3
A2 = np.array([[0.0, 1.0], [-(WN**2), -2 * ZETA * WN]])
B2 = np.array([[0.0], [WN**2]])
C2 = np.array([[1.0, 0.0]])


def test_first_order_hand_computed():
    # G(s) = 1 / (s + 2)
    w = np.array([0.0, 2.0, 20.0])
    H = freq_response([[-2.0]], [[1.0]], [[1.0]], None, w)
    assert H.shape == (3, 1, 1)
    np.testing.assert_allclose(H[:, 0, 0], 1.0 / (1j * w + 2.0), rtol=1e-12)
    np.testing.assert_allclose(H[1, 0, 0], 0.25 - 0.25j, rtol=1e-12)
    mag, ph = bode(H)
    np.testing.assert_allclose(mag[:, 0, 0], [-6.0206, -9.0309, -26.0638], atol=1e-4)
    np.testing.assert_allclose(ph[:, 0, 0], [0.0, -45.0, -np.degrees(np.arctan(10.0))], atol=1e-9)
    # feedthrough D adds to every frequency
    Hd = freq_response([[-2.0]], [[1.0]], [[1.0]], [[1.0]], w)
    np.testing.assert_allclose(Hd - H, 1.0)


def test_second_order_hand_computed():
    # G(s) = wn^2 / (s^2 + 2 zeta wn s + wn^2): at wn, G = 1 / (2 j zeta), |G| = 1/(2 zeta), -90 deg
    w = np.array([0.0, WN, 100 * WN])
    H = freq_response(A2, B2, C2, None, w)[:, 0, 0]
    np.testing.assert_allclose(H[0], 1.0, rtol=1e-12)
    np.testing.assert_allclose(H[1], 1.0 / (2j * ZETA), rtol=1e-12)
    mag, ph = bode(H)
    assert mag[1] == pytest.approx(20 * np.log10(1 / 0.6), rel=1e-12)  # 4.437 dB
    assert ph[1] == pytest.approx(-90.0, abs=1e-9)
    assert ph[2] == pytest.approx(-180.0 + np.degrees(np.arctan(0.6 / 99.99)), abs=1e-6)
    assert mag[2] == pytest.approx(-80.0, abs=0.01)  # -40 dB/decade


def test_mimo_shape_and_values():
    A = np.diag([-1.0, -3.0])
    B = np.eye(2)
    C = np.array([[1.0, 1.0], [0.0, 2.0], [1.0, 0.0]])
    w = np.linspace(0.1, 10, 7)
    H = freq_response(A, B, C, np.zeros((3, 2)), w)
    assert H.shape == (7, 3, 2)
    s = 1j * w
    np.testing.assert_allclose(H[:, 0, 0], 1 / (s + 1))
    np.testing.assert_allclose(H[:, 1, 1], 2 / (s + 3))
    np.testing.assert_allclose(H[:, 2, 1], 0.0)


def simulate_noisy(fs=50.0, n=2**15, noise=0.02, seed=5):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=n)
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete((A2, B2, C2, np.zeros((1, 1))), 1 / fs, method="zoh")
    _, y, _ = signal.dlsim((Ad, Bd, Cd, Dd, 1 / fs), u)
    return u, y[:, 0] + noise * rng.normal(size=n)


def test_spectral_estimate_recovers_known_system():
    fs = 50.0
    u, y = simulate_noisy(fs)
    est = spectral_estimate(u, y, fs, nperseg=1024)
    band = (est.f > 0.1) & (est.f < 1.2)  # 0.6 to 7.5 rad/s around wn = 3 rad/s
    assert est.H.shape == (est.f.size, 1, 1) == est.coherence.shape
    assert est.coherence[band].min() > 0.93
    # model response, with the half-sample delay of the zero-order hold
    Hm = freq_response(A2, B2, C2, None, est.w[band])[:, 0, 0] * np.exp(-0.5j * est.w[band] / fs)
    mag_err, ph_err = bode(est.H[band, 0, 0] / Hm, unwrap=False)
    assert np.abs(mag_err).max() < 0.5
    assert np.abs(ph_err).max() < 3.0
    # resonance peak near wn
    k = np.argmax(np.abs(est.H[band, 0, 0]))
    assert est.w[band][k] == pytest.approx(WN * np.sqrt(1 - 2 * ZETA**2), rel=0.05)


def test_spectral_estimate_two_inputs():
    fs, n = 50.0, 2**15
    rng = np.random.default_rng(9)
    u = rng.normal(size=(n, 2))
    y = np.column_stack([2.0 * u[:, 0] - 0.5 * u[:, 1], 0.7 * u[:, 1]])  # static gains
    est = spectral_estimate(u, y, fs, nperseg=512)
    np.testing.assert_allclose(est.H.real.mean(axis=0), [[2.0, -0.5], [0.0, 0.7]], atol=0.02)
    assert est.coherence[:, 1, 1].min() > 0.99


def test_mismatch_pass_fail_and_coherence_mask():
    w = np.linspace(0.5, 10, 20)
    Hd = freq_response(A2, B2, C2, None, w)
    coh = np.full(Hd.shape, 0.95)
    good = Hd * 10 ** (1.0 / 20) * np.exp(1j * np.radians(10.0))  # +1 dB, +10 deg
    r = mismatch(good, Hd, w, coh)
    np.testing.assert_allclose(r.mag_db, 1.0, atol=1e-9)
    np.testing.assert_allclose(r.phase_deg, 10.0, atol=1e-9)
    assert bool(r.table["pass"].iloc[0]) and r.table["n_used"].iloc[0] == 20
    assert not bool(mismatch(good, Hd, w, coh, mag_bound_db=0.5).table["pass"].iloc[0])
    assert not bool(mismatch(good, Hd, w, coh, phase_bound_deg=5.0).table["pass"].iloc[0])
    # a bad point at low coherence is ignored; at high coherence it fails the channel
    bad = good.copy()
    bad[3] *= 10.0
    coh[3] = 0.2
    assert bool(mismatch(bad, Hd, w, coh).table["pass"].iloc[0])
    assert not bool(mismatch(bad, Hd, w, None).table["pass"].iloc[0])
    # envelope bounds per frequency
    env = np.where(w > 5, 0.5, 3.0)
    assert not bool(mismatch(good, Hd, w, coh, mag_bound_db=env).table["pass"].iloc[0])
    assert bool(mismatch(good, Hd, w, coh, mag_bound_db=env, band=(0.0, 5.0)).table["pass"].iloc[0])
