"""Measurement noise for the filters from the log's native samples (pipeline.ingest.flightdata:
FlightData.noise_std, resample_noise_gain; pipeline.methods.noise.attach_logged_noise)."""

import numpy as np
import pytest
from scipy.signal import lfilter

from pipeline.ingest.flightdata import Channel, FlightData, SegmentSpec, resample_noise_gain


def _roll_like(rng, n, rate):
    """A rate signal driven by a first-order gust through a fast roll mode (13 rad/s),
    as a gyro sees it in turbulence: its curvature is large at 50 Hz."""
    h = 1.0 / rate
    w = rng.standard_normal(n)
    g = lfilter([np.sqrt(2 * h / 0.44) * 0.05], [1, -np.exp(-h / 0.44)], w)  # p_g, 0.05 rad/s
    a = np.exp(-13.0 * h)
    return lfilter([1 - a], [1, -a], g)


def test_noise_gain_of_the_resampling_matches_resampled_white_noise():
    rng = np.random.default_rng(3)
    t = np.arange(200_000) / 100.0
    fd = FlightData(
        channels={
            "p": Channel(t, rng.standard_normal(t.size), "rad/s"),
            "phi": Channel(t[::2], rng.standard_normal(t.size // 2), "rad"),
        }
    )
    grid = fd.resample(50.0, ["p", "phi"])
    assert resample_noise_gain(100.0, 50.0) == pytest.approx(0.604, abs=0.002)
    assert np.std(grid["p"]) == pytest.approx(resample_noise_gain(100.0, 50.0), rel=0.02)
    # no filter when the native rate is not above 1.25 x the grid rate
    assert resample_noise_gain(50.0, 50.0) == 1.0 and resample_noise_gain(60.0, 50.0) == 1.0
    assert np.std(grid["phi"]) == pytest.approx(1.0, rel=0.02)
    assert resample_noise_gain(400.0, 50.0) == pytest.approx(0.30, abs=0.01)


def test_native_noise_estimate_beats_the_grid_estimate_on_a_fast_signal():
    """A 100 Hz gyro with 0.0017 rad/s of noise on a turbulence-driven roll rate (0.045
    rad/s rms): on its native samples the second differences give 0.00179 (5 % high);
    mapped to the 50 Hz grid 0.00107, for the 0.00103 the resampling leaves. On the grid
    itself they give 0.00133 (the signal's curvature, and filtered noise that is no longer
    white) - the R the filters used before."""
    from estimators.statistics import difference_noise_std

    rng = np.random.default_rng(5)
    n, sigma = 60_000, 0.0017
    t = np.arange(n) / 100.0
    z = _roll_like(rng, n, 100.0) + sigma * rng.standard_normal(n)
    fd = FlightData(channels={"p": Channel(t, z, "rad/s")})
    assert fd.noise_std("p") == pytest.approx(sigma, rel=0.08)
    windows = [(10.0, 200.0), (300.0, 500.0)]
    on_grid = fd.noise_std("p", windows, rate_hz=50.0)
    grid = fd.resample(50.0, ["p"])
    true_grid = sigma * resample_noise_gain(100.0, 50.0)
    assert on_grid == pytest.approx(true_grid, rel=0.08)
    naive = difference_noise_std([grid["p"].to_numpy()[:, None]])[0]
    assert naive > 1.2 * true_grid
    assert np.isnan(fd.noise_std("p", [(1e6, 1e6 + 1)]))


def test_attach_logged_noise_sets_the_outputs_that_are_channels():
    from types import SimpleNamespace

    from pipeline.methods.noise import attach_logged_noise, measurement_noise_std

    rng = np.random.default_rng(7)
    t = np.arange(20_000) / 100.0
    fd = FlightData(channels={"p": Channel(t, 0.002 * rng.standard_normal(t.size), "rad/s")})
    seg = SimpleNamespace(z=np.column_stack([0.002 * rng.standard_normal(500), 0.5 * rng.standard_normal(500)]))
    pb = SimpleNamespace(
        model=SimpleNamespace(outputs=["p", "ay"]),
        rate_hz=50.0,
        specs=[SegmentSpec("a", 10.0, 60.0, "time")],
        fit=[seg],
        noise_std={},
    )
    attach_logged_noise(fd, pb)
    assert set(pb.noise_std) == {"p"}
    assert pb.noise_std["p"] == pytest.approx(0.002 * 0.604, rel=0.06)
    sd = measurement_noise_std(pb)
    assert sd[0] == pb.noise_std["p"]  # from the log
    assert sd[1] == pytest.approx(0.5, rel=0.1)  # from the grid
    assert measurement_noise_std(pb, logged=False)[0] == pytest.approx(0.002, rel=0.1)
