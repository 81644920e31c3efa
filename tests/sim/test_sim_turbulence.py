"""Dryden turbulence: a 10-minute run has the scenario's intensity and the Dryden shape,
and the gyros and vanes see it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import coherence, welch

import sim
from tests._simdata import flown, turbulence_10min

COMP = {"u": "gust_n", "v": "gust_e", "w": "gust_d"}  # no mean wind: Dryden axes = north, east, down


def test_dryden_parameters_follow_mil_f_8785c():
    hi = sim.dryden_parameters(1500.0, 7.7, 3)  # above 2000 ft: POE table, L = 1750 ft
    assert hi["L_u"] == hi["L_w"] == pytest.approx(1750 * 0.3048)
    assert hi["sigma_w"] == pytest.approx(np.interp(1500 / 0.3048, [3750, 7500], [7.4, 6.7]) * 0.3048)
    lo = sim.dryden_parameters(100.0, 10.0, 3)  # below 1000 ft: sigma_w = 0.1 W20, L_w = h
    h = 100 / 0.3048
    assert lo["sigma_w"] == pytest.approx(1.0) and lo["L_w"] == pytest.approx(100.0)
    assert lo["sigma_u"] == pytest.approx(1.0 / (0.177 + 0.000823 * h) ** 0.4)
    assert lo["L_u"] == pytest.approx(h / (0.177 + 0.000823 * h) ** 1.2 * 0.3048)


@pytest.mark.slow
def test_gust_variance_matches_the_scenario_intensity():
    """Sample variance over 10 min (about 75 correlation times of the 533 m scale length
    at 67 m/s): pooled over u, v, w (same sigma above 2000 ft) within 20 %; each
    component within 30 % (its own sampling error is about 12 % rms, so this part is a
    2.5-sigma check)."""
    r = turbulence_10min()
    tu = r.meta["turbulence"]
    ratios = {c: np.mean(r.truth[g] ** 2) / tu[f"sigma_{c}"] ** 2 for c, g in COMP.items()}
    assert tu["sigma_u"] == tu["sigma_w"] and tu["sigma_w"] > 1.5
    assert np.mean(list(ratios.values())) == pytest.approx(1.0, abs=0.2), ratios
    for c, k in ratios.items():
        assert k == pytest.approx(1.0, abs=0.3), (c, ratios)


def test_gust_spectra_follow_the_dryden_form():
    """Welch spectra (20 s segments, about 58 half-overlapping averages) integrated over
    octave bands from 0.2 to 6.4 Hz (4 to 64 frequency bins each, sampling error < 8 %
    rms) against the analytic Dryden spectra: each band within 20 %. Below 0.2 Hz a 10
    minute record has too few averages; the variance test covers that part."""
    r = turbulence_10min()
    tu = r.meta["turbulence"]
    V = float(r.truth["V"].mean())
    for c, g in COMP.items():
        f, P = welch(r.truth[g].to_numpy(), fs=r.scenario.rate_hz, nperseg=2048)
        Pd = sim.dryden_psd(f, V, tu[f"sigma_{c}"], tu[f"L_{c}"], c)
        for lo in (0.2, 0.4, 0.8, 1.6, 3.2):
            band = (f >= lo) & (f < 2 * lo)
            ratio = np.trapezoid(P[band], f[band]) / np.trapezoid(Pd[band], f[band])
            assert ratio == pytest.approx(1.0, abs=0.2), (c, lo, ratio)
        # shape: u is first order (-20 dB/decade), v and w second order with a zero
        hi = (f > 2) & (f < 5)
        slope = np.polyfit(np.log10(f[hi]), np.log10(P[hi]), 1)[0]
        assert slope == pytest.approx(-2.0, abs=0.3), (c, slope)


def test_gyros_and_vanes_contain_the_turbulence():
    r = turbulence_10min()
    T, S = r.truth, r.sensors
    ad, imu = S["airdata"], S["imu"]
    fs = r.scenario.rate_hz
    gw = np.interp(ad["t"], T["t"], T["gust_w"])
    gv = np.interp(ad["t"], T["t"], T["gust_v"])
    f, c_alpha = coherence(ad["alpha"].to_numpy(), gw, fs=fs, nperseg=1024)
    _, c_beta = coherence(ad["beta"].to_numpy(), gv, fs=fs, nperseg=1024)
    band = (f > 0.3) & (f < 3)
    assert c_alpha[band].mean() > 0.7 and c_beta[band].mean() > 0.7
    noise = r.meta["sensors"]["imu"]["noise_std"]
    for ch, turb in (("p", "p_turb"), ("q", "q_turb")):
        x = imu[ch].to_numpy()
        assert x.std() > 10 * noise[ch]
        _, c = coherence(x, np.interp(imu["t"], T["t"], T[turb]), fs=fs, nperseg=1024)
        assert c[band].mean() > 0.5, ch


def test_calm_scenarios_have_no_gusts_and_turbulent_ones_do():
    calm = flown("longitudinal_3211_calm").truth
    assert not np.any(calm[["gust_n", "gust_e", "gust_d", "p_turb", "q_turb", "r_turb"]].to_numpy())
    turb = flown("longitudinal_3211_turbulence")
    tu = turb.meta["turbulence"]
    assert tu["model"] == "milspec" and tu["jsbsim_turb_type"] == 3
    assert tu["sigma_w"] == pytest.approx(0.5)  # 0.1 * W20 below 1000 ft
    assert 0.3 < turb.truth["gust_d"].std() < 0.8
