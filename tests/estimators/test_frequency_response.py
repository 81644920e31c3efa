"""Frequency responses with coherence (estimators.frequency_response): against the true
responses of known linear systems, with one input and with two correlated inputs, and the
stated random error against the scatter over noise draws."""

import numpy as np
import pytest
import scipy.signal as ss

from estimators import ModelDefinitionError, frequency_response

DT = 0.02


def _inputs(rng, n):
    """Two inputs correlated 0.8: the second follows the first (a pilot's rudder with
    aileron), plus its own part."""
    b, a = ss.butter(2, 0.2)
    u1 = ss.lfilter(b, a, rng.standard_normal(n))
    u2 = 0.7 * u1 + 0.5 * ss.lfilter(b, a, rng.standard_normal(n))
    return u1, u2


H1 = ([4.0], [1.0, 1.2, 4.0])  # 2nd order, 2 rad/s
H2 = ([2.0, 0.0], [1.0, 3.0, 9.0])


def _true(tf, w):
    s = 1j * w
    return np.polyval(tf[0], s) / np.polyval(tf[1], s)


def _outputs(t, u1, u2, rng, noise=0.02):
    y1 = ss.lsim(ss.TransferFunction(*H1), u1, t)[1]
    y2 = ss.lsim(ss.TransferFunction(*H2), u2, t)[1]
    return y1 + y2 + noise * rng.standard_normal(t.size)


def test_conditioned_responses_recover_both_inputs_where_the_single_input_estimate_misses():
    rng = np.random.default_rng(1)
    t = np.arange(30000) * DT
    u1, u2 = _inputs(rng, t.size)
    y = _outputs(t, u1, u2, rng)
    assert np.corrcoef(u1, u2)[0, 1] > 0.5
    f = np.geomspace(0.05, 2.0, 30)
    fr = frequency_response(t, np.column_stack([u1, u2]), y, f=f, inputs=["da", "dr"], outputs=["p"])
    assert fr.H.shape == (30, 1, 2) and fr.coherence.shape == (30, 1, 2) and fr.multiple_coherence.shape == (30, 1)
    for i, tf in enumerate((H1, H2)):
        T = _true(tf, fr.w)
        ok = fr.coherence[:, 0, i] >= 0.6
        assert ok.sum() > 15
        # within 1 dB and 5 deg, or where the coherence leaves more random error, within
        # its spread: every point within 4 random errors, nine in ten within 2 (eps of |H|
        # in dB: 20 log10(1 + eps); of the phase: eps rad)
        eps = fr.random_error[ok, 0, i]
        dmag = np.abs(20 * np.log10(np.abs(fr.H[ok, 0, i]) / np.abs(T[ok])))
        dph = np.abs(np.degrees(np.angle(fr.H[ok, 0, i] / T[ok])))
        for k, ok_mag, ok_ph in ((4, 1.0, 5.0), (2, 1.0, 5.0)):
            within = (dmag < np.maximum(ok_mag, 20 * np.log10(1 + k * eps))) & (
                dph < np.maximum(ok_ph, np.degrees(k * eps))
            )
            assert np.mean(within) >= (1.0 if k == 4 else 0.9), (i, k, dmag, dph, eps)
    assert np.all(fr.multiple_coherence[:, 0] > 0.95)
    # the single-input estimate books the second input's share on the first
    single = frequency_response(t, u1, y, f=f)
    miss = 20 * np.log10(np.abs(single.H[:, 0, 0]) / np.abs(_true(H1, fr.w)))
    assert np.max(np.abs(miss)) > 3.0
    p = fr.pair("p", "dr")
    assert list(p.columns) == ["magnitude_db", "phase_deg", "coherence", "random_error", "H"]
    assert fr.select("p", "dr").H.shape == (30, 1, 1)


@pytest.mark.slow  # 40 simulated flights: the edit loop's tier goes without it
def test_random_error_matches_the_scatter_over_repeated_flights():
    """One input, noise of 30 % of the output: the stated normalised random error of |H|
    against the scatter of |H| over 40 repeated experiments (a new random input and noise
    each: what the random error describes), averaged over the band (each frequency's
    ratio has a sampling spread of about 1/sqrt(2 * 40))."""
    t = np.arange(12000) * DT
    b, a = ss.butter(2, 0.2)
    f = np.geomspace(0.1, 1.5, 20)
    mags, errs = [], []
    for seed in range(40):
        r = np.random.default_rng(100 + seed)
        u = ss.lfilter(b, a, r.standard_normal(t.size))
        clean = ss.lsim(ss.TransferFunction(*H1), u, t)[1]
        y = clean + 0.3 * np.std(clean) * r.standard_normal(t.size)
        fr = frequency_response(t, u, y, f=f)
        mags.append(np.abs(fr.H[:, 0, 0]))
        errs.append(fr.random_error[:, 0, 0])
    scatter = np.std(mags, axis=0) / np.mean(mags, axis=0)
    ratio = np.mean(errs, axis=0) / scatter
    assert 0.7 < np.median(ratio) < 1.3, ratio


def test_bad_input_is_refused():
    t = np.arange(100) * DT
    with pytest.raises(ModelDefinitionError, match="u has shape"):
        frequency_response(t, np.zeros((99, 1)), np.zeros(100))
    with pytest.raises(ModelDefinitionError, match="NaN"):
        frequency_response(t, np.r_[np.zeros(99), np.nan], np.zeros(100))
