"""Turbulence axes (sim.scenario.Turbulence.axes): JSBSim builds its rotary gusts from the
gusts' time histories along the flight path (q_g from w_g, r_g from v_g) but turns them,
with the gusts, by the mean-wind azimuth - an aircraft heading east then gets its pitch
gust as roll turbulence. axes = "aircraft" keeps them in the aircraft's axes."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

import sim

ROOT = Path(__file__).resolve().parents[2]


def _gradient_gust(gust: np.ndarray, V: float, tau: float, dt: float) -> np.ndarray:
    """(s / V) / (1 + tau s) applied to a gust velocity (m/s): the rotary gust Dryden
    (and JSBSim) derives from it, rad/s."""
    a = np.exp(-dt / tau)
    return lfilter([1 - a], [1, -a], np.diff(gust, prepend=gust[0]) / dt / V)


@pytest.fixture(scope="module")
def flights():
    """The small UAV in turbulence, started heading east; with no lateral control it
    wanders through every heading over the flight."""
    s = sim.load_scenario(ROOT / "scenarios" / "longitudinal_3211_turbulence.toml")
    s = replace(s, heading=np.pi / 2)
    return {axes: sim.fly(replace(s, turbulence=replace(s.turbulence, axes=axes))) for axes in ("wind", "aircraft")}


def test_aircraft_axes_pair_the_rotary_gusts_with_the_body_gusts(flights):
    """Pitch gust against the one Dryden derives from the body w_g, yaw gust against the
    one from the body v_g (measured: JSBSim's axes 0.33, 0.39; the aircraft's 0.90, 0.87;
    roll gust against the pitch-gust model 0.08)."""
    corr = {}
    for axes, r in flights.items():
        T = r.truth
        assert r.meta["turbulence"]["axes"] == axes
        psi = np.unwrap(T["psi"].to_numpy())
        assert np.ptp(psi) > np.pi / 2  # the premise: the heading moves
        V, b, dt = float(T["V"].mean()), r.aircraft.b, float(T["t"].iloc[1] - T["t"].iloc[0])
        q_model = _gradient_gust(T["gust_w"].to_numpy(), V, 4 * b / (np.pi * V), dt)
        r_model = _gradient_gust(T["gust_v"].to_numpy(), V, 3 * b / (np.pi * V), dt)
        corr[axes] = {
            k: float(np.corrcoef(T[f"{k}_turb"], m)[0, 1]) for k, m in (("p", q_model), ("q", q_model), ("r", r_model))
        }
    assert corr["aircraft"]["q"] > 0.8 and corr["aircraft"]["r"] > 0.8, corr
    assert abs(corr["aircraft"]["p"]) < 0.2, corr
    # JSBSim's own axes: the pairs come apart as the heading leaves north
    assert corr["wind"]["q"] < 0.6 and corr["wind"]["r"] < 0.6, corr
    # same turbulence level either way
    for k in ("p_turb", "q_turb", "gust_w"):
        ratio = flights["aircraft"].truth[k].std() / flights["wind"].truth[k].std()
        assert 0.7 < ratio < 1.4, (k, ratio)


def test_scenario_key(tmp_path):
    text = (ROOT / "scenarios" / "longitudinal_3211_turbulence.toml").read_text()
    text = text.replace('aircraft = "aircraft/', f'aircraft = "{ROOT}/scenarios/aircraft/')
    good, bad = tmp_path / "good.toml", tmp_path / "bad.toml"
    good.write_text(text.replace("[turbulence]\n", '[turbulence]\naxes = "aircraft"\n'))
    bad.write_text(text.replace("[turbulence]\n", '[turbulence]\naxes = "body"\n'))
    assert sim.load_scenario(good).turbulence.axes == "aircraft"
    assert sim.load_scenario(ROOT / "scenarios" / "default.toml").turbulence.axes == "wind"
    with pytest.raises(sim.ScenarioError, match="axes"):
        sim.load_scenario(bad)
