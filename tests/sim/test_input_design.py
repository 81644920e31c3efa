"""Designed inputs (sim.maneuvers.orthogonal_multisines): harmonics split among the inputs,
mutually orthogonal, zero at both ends, low relative peak factor, more energy than
Schroeder-phased multisines of the same harmonics at the same amplitude."""

import numpy as np
import pytest

from sim.maneuvers import orthogonal_multisines, relative_peak_factor, schroeder_multisine


@pytest.fixture(scope="module")
def three():
    return orthogonal_multisines(["de", "da", "dr"], band=(0.1, 2.0), duration=20.0, dt=0.02, amplitude=1.0)


def test_three_inputs_share_the_band_orthogonally(three):
    U = three
    assert list(U.columns) == ["de", "da", "dr"] and U.index.name == "t"
    assert U.index[0] == 0.0 and U.index[-1] == pytest.approx(20.0) and len(U) == 1001
    f = U.attrs["frequencies"]
    allf = np.sort(np.concatenate(list(f.values())))
    np.testing.assert_allclose(allf, np.arange(2, 41) / 20.0)  # every harmonic of 1/20 s in 0.1-2 Hz, once
    assert all(len(v) >= 10 for v in f.values())
    A = U.to_numpy()[:-1]  # one period
    G = A.T @ A
    assert np.max(np.abs(G - np.diag(np.diag(G)))) < 1e-6 * np.max(np.diag(G))
    np.testing.assert_array_equal(U.iloc[0].to_numpy(), 0.0)
    np.testing.assert_array_equal(U.iloc[-1].to_numpy(), 0.0)
    np.testing.assert_allclose(np.abs(A).max(axis=0), 1.0)


def test_low_peak_factor_and_more_energy_than_schroeder(three):
    """RPF 1.10 is the goal with ten or more harmonics; the phase search has many local
    minima, so each input is held to 1.15 and their mean to 1.10; the energy against
    Schroeder's phases (RPF 1.29-1.31 here) at the same peak, averaged over the inputs,
    at least 1.25x."""
    rpf = three.attrs["rpf"]
    assert max(rpf.values()) <= 1.15 and np.mean(list(rpf.values())) <= 1.10, rpf
    for name, r in rpf.items():
        assert r == pytest.approx(relative_peak_factor(three[name].to_numpy()[:-1]))
    freqs, phases, _ = schroeder_multisine(("de", "da", "dr"), 0.1, 2.0, 20.0)
    t = three.index.to_numpy()
    ratios = []
    for ax in ("de", "da", "dr"):
        s = np.sin(2 * np.pi * np.outer(t, freqs[ax]) + phases[ax]).sum(axis=1)
        s /= np.abs(s).max()
        assert relative_peak_factor(s[:-1]) > 1.25
        ratios.append(np.sum(three[ax].to_numpy() ** 2) / np.sum(s**2))
    assert np.mean(ratios) >= 1.25, ratios


def test_amplitude_per_input_and_refusals():
    U = orthogonal_multisines(["de", "da"], band=(0.2, 1.5), duration=10.0, dt=0.02, amplitude={"de": 0.05, "da": 0.1})
    np.testing.assert_allclose(np.abs(U.to_numpy()).max(axis=0), [0.05, 0.1])
    assert all(r <= 1.15 for r in U.attrs["rpf"].values())  # seven harmonics each
    with pytest.raises(ValueError, match="whole number of steps"):
        orthogonal_multisines(["de"], band=(0.1, 1.0), duration=10.01, dt=0.02)
    with pytest.raises(ValueError, match="harmonics"):
        orthogonal_multisines(["de", "da", "dr"], band=(0.1, 0.2), duration=10.0, dt=0.02)
    with pytest.raises(ValueError, match="Nyquist"):
        orthogonal_multisines(["de"], band=(0.1, 30.0), duration=10.0, dt=0.02)
