"""Air-data angles from the flight path (pipeline.conditioning.flow_angles) and flying in wind.

Unit part: the wind fit on kinematics built by hand (known wind, known sideslip), the
errors. Closed loop: longitudinal_3211_calm flown in a 6.4 m/s steady wind ([wind],
JSBSim), its MCAP read through a channel map without the vanes, ``estimate_log`` rebuilds
alpha and beta from the 10 Hz GPS velocity, the compatibility stage estimates the wind
instead of booking it on the sensors, and output error recovers every derivative.

Measured (seed 11, wind (-4, 5) m/s): flow-angle wind (-3.993, 4.996) +- 0.04 m/s; rebuilt
alpha/beta against the vanes: mean 0.007 deg, std 0.31/0.29 deg (vane 0.2 deg and GPS
0.1 m/s noise); every derivative within 1.82 std (with the vanes 1.89), proof of match
passes. Before the compatibility model had the wind, this flight had bias_az, scale_az,
bias_V, bias_beta, scale_beta and delay_air "significant" and applied, and Cmalpha 44,
CLalpha 40 std off.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.conditioning.flow_angles import (
    SCALE_STD_MAX,
    _body_axes,
    correlation_time,
    fit_wind,
    reconstruct_flow_angles,
)
from pipeline.conditioning.wind_uncertainty import markov_mean_std, wind_uncertainty
from pipeline.errors import FsidError
from pipeline.ingest.flightdata import Channel, FlightData

ROOT = Path(__file__).resolve().parents[2]


def _kinematics(
    seed: int, turn_rate: float, n: int = 3000, V: float = 25.0, wind=(3.0, -6.0), beta_std=np.deg2rad(1.0)
):
    """A flight at 10 Hz with a known wind: heading turning at turn_rate (rad/s), bank
    for it, alpha 4 deg, a random sideslip; returns t, vg (n, 3), V (n,), axes, truth."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.1
    psi = turn_rate * t
    phi = np.full(n, np.arctan(V * turn_rate / 9.81))
    theta = np.full(n, np.deg2rad(4.0)) + 0.02 * np.sin(0.3 * t)
    alpha = np.deg2rad(4.0) + 0.02 * np.sin(0.3 * t)
    beta = beta_std * np.sin(0.7 * t + rng.uniform(0, 6)) + 0.3 * beta_std * rng.standard_normal(n)
    vb = V * np.column_stack([np.cos(alpha) * np.cos(beta), np.sin(beta), np.sin(alpha) * np.cos(beta)])
    axes = _body_axes(phi, theta, psi)
    va = np.einsum("nji,nj->ni", axes, vb)  # body -> NED: transpose of T_bn
    vg = va + np.array([wind[0], wind[1], 0.0]) + 0.1 * rng.standard_normal((n, 3))
    Vm = V + 0.3 * rng.standard_normal(n)
    return t, vg, Vm, axes, {"phi": phi, "theta": theta, "psi": psi, "alpha": alpha, "beta": beta}


@pytest.mark.parametrize("turn_rate", [0.0, 0.05])
def test_wind_fit_recovers_a_known_wind(turn_rate):
    """Straight (the zero-sideslip condition fixes the cross wind) and turning flight."""
    t, vg, V, axes, _ = _kinematics(3, turn_rate)
    w = fit_wind(t, vg, V, axes, window_s=1e9)
    assert w.knots.size == 1
    en, ee = (w.north[0] - 3.0) / w.std_north[0], (w.east[0] + 6.0) / w.std_east[0]
    assert abs(en) < 3.0 and abs(ee) < 3.0, (w.north, w.east, w.std_north, w.std_east)
    assert max(w.std_north[0], w.std_east[0]) < 0.3
    assert 0.2 < w.airspeed_rms < 0.5  # the 0.3 m/s pitot noise


def test_wind_fit_follows_a_changing_wind():
    t, vg, V, axes, _ = _kinematics(4, 0.05, n=6000)
    drift = np.column_stack([np.linspace(0.0, 4.0, t.size), np.zeros(t.size), np.zeros(t.size)])
    w = fit_wind(t, vg + drift, V, axes, window_s=120.0)
    assert w.knots.size > 2
    wn, we = w.at(t)
    assert np.max(np.abs(wn - (3.0 + drift[:, 0]))) < 0.5 and np.max(np.abs(we + 6.0)) < 0.5


def test_wind_fit_skips_knots_in_a_gap():
    """Two flights 5 min apart in one log (landed in between): no knot without data."""
    t, vg, V, axes, _ = _kinematics(7, 0.05, n=6000)
    keep = (t < 200.0) | (t > 500.0)
    w = fit_wind(t[keep], vg[keep], V[keep], axes[keep], window_s=60.0)
    # 11 knots over 0-600 s, of which 3 (300, 360, 420 s) carry no sample: dropped
    assert w.knots.size == 8 and not np.any((w.knots > 250.0) & (w.knots < 470.0)), w.knots
    assert np.all(w.std_north > 0) and np.all(w.std_north < 0.5)
    wn, we = w.at(t[keep])
    assert np.max(np.abs(wn - 3.0)) < 0.5 and np.max(np.abs(we + 6.0)) < 0.5


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_wind_fit_estimates_a_pitot_scale_factor_in_a_turn(seed):
    """A 3 % pitot scale factor with the wind, over 860 deg of heading: within 3 std, the
    std under 0.1 %; held at 0 the airspeed error goes into the wind."""
    t, vg, V, axes, _ = _kinematics(seed, 0.05)
    w = fit_wind(t, vg, 1.03 * V, axes, window_s=1e9, scale=None)
    assert w.scale_estimated and w.std_scale < 1e-3
    assert abs(w.scale - 0.03) < 3 * w.std_scale, (w.scale, w.std_scale)
    assert abs(w.north[0] - 3.0) < 3 * w.std_north[0] and abs(w.east[0] + 6.0) < 3 * w.std_east[0]
    held = fit_wind(t, vg, 1.03 * V, axes, window_s=1e9)
    assert not held.scale_estimated and held.scale == 0.0
    assert held.airspeed_rms > 2 * w.airspeed_rms  # 0.75 m/s of scale error in it


def test_wind_fit_leaves_the_scale_factor_alone_in_straight_flight():
    """No turn: the scale factor cannot be told from the wind along the track (its std with
    the prior near 0.16), so it is held at 0 and the wind takes the error."""
    t, vg, V, axes, _ = _kinematics(3, 0.0)
    w = fit_wind(t, vg, 1.03 * V, axes, window_s=1e9, scale=None)
    assert not w.scale_estimated and w.scale == 0.0 and w.std_scale > SCALE_STD_MAX
    assert w.north[0] - 3.0 == pytest.approx(-0.03 * 25.0, abs=0.05)  # the tail wind took it


def test_rebuilt_flight_carries_the_calibrated_airspeed():
    t, vg, V, _, tr = _kinematics(5, 0.05)
    fd = _flight(t, vg, 1.03 * V, tr)
    out, doc = reconstruct_flow_angles(fd)
    cal = doc["airspeed_scale"]
    assert cal["status"] == "estimated" and cal["applied"] and abs(cal["estimate"] - 0.03) < 3 * cal["std"]
    assert np.array_equal(fd["V"].values, 1.03 * V)  # the input is not modified
    assert np.allclose(out["V"].values, 1.03 * V / (1 + cal["estimate"]))
    assert "calibrated" in out["V"].notes and "/ (1 + 0.03" in out["V"].source
    assert wind_uncertainty(doc, [(0.0, 300.0)])["airspeed scale"] == cal["std"]
    # held (a validation flight takes the fitted flight's); the scale part of the offset
    held, hdoc = reconstruct_flow_angles(fd, airspeed_scale=0.03)
    assert hdoc["airspeed_scale"]["status"] == "held" and np.allclose(held["V"].values, V)
    moved, mdoc = reconstruct_flow_angles(fd, wind_offset=(0.0, 0.0, 0.0, 0.01))
    assert np.allclose(moved["V"].values, 1.03 * V / (1 + cal["estimate"] + 0.01))
    assert mdoc["airspeed_scale_offset"] == 0.01
    assert mdoc["wind"]["north_mps"][0] != doc["wind"]["north_mps"][0]  # the wind refitted
    # a straight flight: not identifiable, the airspeed as logged, nothing carried
    t, vg, V, _, tr = _kinematics(5, 0.0)
    out, doc = reconstruct_flow_angles(_flight(t, vg, V, tr))
    assert doc["airspeed_scale"]["status"] == "not identifiable" and out["V"] is not None
    assert np.array_equal(out["V"].values, V) and wind_uncertainty(doc, [(0.0, 300.0)])["airspeed scale"] == 0.0


def test_airspeed_calibration_rules():
    """The document's rules on a wind fit's scale factor: too uncertain (the joint std
    above SCALE_STD_MAX, as with 10 deg of weaving heading: 2.5 %) is not identifiable;
    significant and plausible is applied; beyond SCALE_MAX it is taken as 0, like one not
    identifiable (units or a blocked pitot, not a calibration)."""
    from pipeline.conditioning.flow_angles import SCALE_MAX, WindFit, airspeed_calibration

    def fit(k, sd):
        z = np.zeros(1)
        return WindFit(
            knots=z,
            north=z,
            east=z,
            std_north=z,
            std_east=z,
            airspeed_rms=0.3,
            beta_rms=0.01,
            n=100,
            scale=k,
            std_scale=sd,
            scale_estimated=True,
        )

    assert airspeed_calibration(fit(-0.03, 0.025))["status"] == "not identifiable"
    cal = airspeed_calibration(fit(0.05, 0.01))
    assert cal["status"] == "estimated" and cal["applied"] and cal["significance_std"] == pytest.approx(5.0)
    assert not airspeed_calibration(fit(0.02, 0.01))["applied"]  # 2 std
    wild = airspeed_calibration(fit(SCALE_MAX + 0.05, 0.01))
    assert wild["status"] == "implausible" and not wild["applied"] and not wild["carried"]


def test_an_insignificant_scale_factor_is_not_applied_but_carried():
    """A correct pitot in a turn: k within 3 std of 0, the airspeed kept as logged, the
    wind fitted with k = 0, and k's std still carried (the calibration's uncertainty)."""
    t, vg, V, _, tr = _kinematics(6, 0.05)
    out, doc = reconstruct_flow_angles(_flight(t, vg, V, tr))
    cal = doc["airspeed_scale"]
    assert cal["status"] == "estimated" and not cal["applied"] and cal["carried"], cal
    assert np.array_equal(out["V"].values, V) and "not applied" in cal["note"]
    assert wind_uncertainty(doc, [(0.0, 300.0)])["airspeed scale"] == cal["std"] > 0


def _flight(t, vg, V, tr, with_vanes=False) -> FlightData:
    ch = {k: Channel(t=t, values=vg[:, i], unit="m/s") for i, k in enumerate(("vn", "ve", "vd"))}
    ch["V"] = Channel(t=t, values=V, unit="m/s")
    for k in ("phi", "theta", "psi") + (("alpha", "beta") if with_vanes else ()):
        ch[k] = Channel(t=t, values=tr[k], unit="rad")
    return FlightData(channels=ch, meta={"source": "test"})


def test_rebuilt_angles_match_the_true_ones_and_leave_the_input_alone():
    t, vg, V, _, tr = _kinematics(5, 0.05)
    fd = _flight(t, vg, V, tr)
    out, doc = reconstruct_flow_angles(fd)
    assert "alpha" not in fd and "beta" not in fd  # the input is not modified
    assert doc["status"] == "reconstructed" and doc["channels"] == ["alpha", "beta"]
    for k in ("alpha", "beta"):
        e = out[k].values - np.interp(out[k].t, t, tr[k])
        # 0.1 m/s velocity noise / 25 m/s = 0.23 deg per sample
        assert abs(np.rad2deg(e.mean())) < 0.05 and np.rad2deg(e.std()) < 0.4, (k, e.mean(), e.std())
    assert abs(doc["wind"]["north_mps"][0] - 3.0) < 0.2 and abs(doc["wind"]["east_mps"][0] + 6.0) < 0.2
    same, doc2 = reconstruct_flow_angles(_flight(t, vg, V, tr, with_vanes=True))
    assert doc2 == {"status": "not needed"} and "alpha" in same


def test_a_vertical_wind_shifts_the_rebuilt_alpha_by_w_over_v():
    """The reconstruction assumes no vertical wind: in a 1 m/s down-wind the rebuilt alpha
    sits 1/25 rad too high; rebuilt with the wind offset (0, 0, 1) it is the true one."""
    t, vg, V, _, tr = _kinematics(5, 0.05)
    vg = vg + np.array([0.0, 0.0, 1.0])  # air moving down at 1 m/s
    fd = _flight(t, vg, V, tr)
    for offset, bias in (((0.0, 0.0, 0.0), 1.0 / 25.0), ((0.0, 0.0, 1.0), 0.0)):
        out, doc = reconstruct_flow_angles(fd, wind_offset=offset)
        e = out["alpha"].values - np.interp(out["alpha"].t, t, tr["alpha"])
        assert abs(e.mean() - bias * np.cos(tr["phi"][0])) < 2e-3, (offset, e.mean())
    assert doc["wind_offset_mps"] == [0.0, 0.0, 1.0]


def test_mean_of_a_markov_process_over_spans():
    """markov_mean_std against its limits and a Monte Carlo of the process itself."""
    s, tau = 2.0, 5.0
    assert markov_mean_std(s, tau, [(0.0, 1e4)]) == pytest.approx(s * np.sqrt(2 * tau / 1e4), rel=1e-3)
    assert markov_mean_std(s, tau, [(0.0, 1e-3)]) == pytest.approx(s, rel=1e-3)
    one = markov_mean_std(s, tau, [(0.0, 30.0)])
    # two spans far apart: independent halves; overlapping spans count once
    assert markov_mean_std(s, tau, [(0.0, 30.0), (1e4, 1e4 + 30.0)]) == pytest.approx(one / np.sqrt(2))
    assert markov_mean_std(s, tau, [(0.0, 20.0), (10.0, 30.0)]) == pytest.approx(one)
    assert markov_mean_std(0.0, tau, [(0.0, 30.0)]) == 0.0 and markov_mean_std(s, 0.0, [(0, 30)]) == 0.0
    # Monte Carlo: 8000 AR(1) paths at 50 Hz averaged over two spans of one tau, 0.4 tau
    # apart, whose correlation adds 17 % to the std of independent spans
    rng = np.random.default_rng(1)
    dt, n = 0.02, 600
    a = np.exp(-dt / tau)
    x = np.empty((8000, n))
    x[:, 0] = s * rng.standard_normal(8000)
    w = s * np.sqrt(1 - a * a) * rng.standard_normal((8000, n))
    for k in range(1, n):
        x[:, k] = a * x[:, k - 1] + w[:, k]
    t = np.arange(n) * dt
    m = (t < 5.0) | (t >= 7.0)  # spans [0, 5) and [7, 12)
    mc = x[:, m].mean(axis=1).std()
    assert markov_mean_std(s, tau, [(0.0, 5.0), (7.0, 12.0)]) == pytest.approx(mc, rel=0.04), mc


def test_correlation_time_of_a_gust_under_white_noise():
    """An AR(1) gust (tau 6 s) at 10 Hz under white noise of twice its level: the lag-1
    normalisation keeps the noise from shortening it."""
    rng = np.random.default_rng(2)
    dt, n, tau = 0.1, 60000, 6.0
    a = np.exp(-dt / tau)
    g = np.empty(n)
    g[0] = 0.0
    w = np.sqrt(1 - a * a) * rng.standard_normal(n)
    for k in range(1, n):
        g[k] = a * g[k - 1] + w[k]
    assert correlation_time(g + 2.0 * rng.standard_normal(n), dt) == pytest.approx(tau, rel=0.15)
    assert correlation_time(rng.standard_normal(5000), dt) < 2 * dt


def test_wind_uncertainty_from_the_airspeed_residual():
    """The vertical wind's std: the airspeed residual above the pitot noise (sqrt(2.5^2 -
    1.5^2) = 2 m/s) as the gust level, its correlation time, over the fitted spans."""
    doc = {
        "status": "reconstructed",
        "airspeed_residual_rms_mps": 2.5,
        "airspeed_noise_mps": 1.5,
        "airspeed_residual_tau_s": 8.0,
        "wind": {"std_north_mps": [0.2, 0.4], "std_east_mps": [0.3, 0.3]},
    }
    u = wind_uncertainty(doc, [(0.0, 60.0), (100.0, 160.0)])
    assert u["wind north"] == pytest.approx(0.3) and u["wind east"] == pytest.approx(0.3)
    assert u["vertical wind"] == pytest.approx(markov_mean_std(2.0, 8.0, [(0.0, 60.0), (100.0, 160.0)]))
    assert 0.2 < u["vertical wind"] < 2.0 * np.sqrt(2 * 8.0 / 120.0)
    # a residual slower than the vertical gust's largest scale (533.4 m at 25 m/s: 21.3 s)
    # is the horizontal wind changing: the time constant stops there
    slow = wind_uncertainty(
        {**doc, "airspeed_residual_tau_s": 300.0, "airspeed_mean_mps": 25.0}, [(0.0, 60.0), (100.0, 160.0)]
    )
    assert slow["vertical wind"] == pytest.approx(markov_mean_std(2.0, 533.4 / 25.0, [(0.0, 60.0), (100.0, 160.0)]))
    assert wind_uncertainty({"status": "not needed"}, [(0.0, 1.0)]) == {}


def test_rebuild_errors_name_what_is_missing():
    t, vg, V, _, tr = _kinematics(6, 0.0, n=200)
    fd = _flight(t, vg, V, tr)
    del fd.channels["vn"]
    with pytest.raises(FsidError, match=r"lacks \['vn'\]"):
        reconstruct_flow_angles(fd)
    ground = _flight(t, vg, V, tr)
    ground.channels["V"] = Channel(t=t[:10], values=np.full(10, 20.0), unit="m/s")
    with pytest.raises(FsidError, match="fewer than 20 velocity samples"):
        reconstruct_flow_angles(ground)


def _fly_in_wind(d: Path, scenario: str):
    """Fly a built-in scenario with a (-4, 5) m/s wind into ``d``; write a channel map of its
    MCAP without the vanes. Returns (run folder, SimResult)."""
    pytest.importorskip("jsbsim")
    from pipeline.ingest.maps import plain_map_toml
    from pipeline.ingest.readers import read_log
    from pipeline.jobs.simulate import simulate

    src = (ROOT / "scenarios" / f"{scenario}.toml").read_text()
    src = src.replace('aircraft = "aircraft/', f'aircraft = "{ROOT}/scenarios/aircraft/')
    (d / "windy.toml").write_text(src + "\n[wind]\nnorth_mps = -4.0\neast_mps = 5.0\n")
    run_dir, result = simulate(d / "windy.toml", d / "run", progress=False)
    fd = read_log(run_dir / "flight.mcap")
    (d / "novane.toml").write_text(plain_map_toml(fd, "fsid_mcap_without_vanes", ["mcap"], drop=("alpha", "beta")))
    return run_dir, result


@pytest.fixture(scope="module")
def windy(tmp_path_factory):
    d = tmp_path_factory.mktemp("windy")
    return (d, *_fly_in_wind(d, "longitudinal_3211_calm"))


def test_sim_wind_is_steady_and_the_airspeed_air_relative(windy):
    _, run_dir, r = windy
    T = r.truth
    assert abs(r.trim["V"] - 30.0) < 1e-6
    axes = _body_axes(T.phi.to_numpy(), T.theta.to_numpy(), T.psi.to_numpy())
    va = np.column_stack([T.vn + 4.0, T.ve - 5.0, T.vd])
    vb = np.einsum("nij,nj->ni", axes, va)
    assert np.max(np.abs(np.linalg.norm(vb, axis=1) - T.V)) < 1e-6
    assert np.max(np.abs(np.arctan2(vb[:, 2], vb[:, 0]) - T.alpha)) < 1e-8
    doc = json.loads((run_dir / "truth.json").read_text())
    assert doc["wind"] == {"north_mps": -4.0, "east_mps": 5.0, "down_mps": 0.0}


@pytest.mark.slow
def test_estimate_without_vanes_in_wind(windy):
    from pipeline.jobs.estimate import estimate_log

    d, run_dir, _ = windy
    estimate_log(
        run_dir / "flight.mcap",
        d / "est",
        map_path=str(d / "novane.toml"),
        methods=["oem"],
        model="longitudinal",
        quiet=True,
        figures=False,
    )
    rep = json.loads((d / "est" / "report.json").read_text())
    flow = rep["meta"]["flow_angles"]
    assert flow["channels"] == ["alpha", "beta"]
    w = flow["wind"]
    assert abs(w["north_mps"][0] + 4.0) < 3 * w["std_north_mps"][0] + 0.02
    assert abs(w["east_mps"][0] - 5.0) < 3 * w["std_east_mps"][0] + 0.02
    # the compatibility stage sees the wind as wind, not as sensor errors
    comp = rep["compatibility"]
    assert comp["applied"] == {}, comp["applied"]
    # without vanes it holds the rebuilt flight's wind: estimated here its cross-track part
    # came out 5.7 +- 18 m/s on this straight flight and the fit did not converge
    assert comp["status"] == "ok" and comp["wind_note"].startswith("wind held at north -3.99, east 5.00")
    assert comp["scope"].startswith("IMU errors only")
    m = rep["methods"]["oem"]
    errs = {
        k: round(abs(v["error_in_std"]), 2)
        for k, v in m["parameters"].items()
        if v.get("error_in_std") is not None and "[" not in k
    }
    assert len(errs) == 11 and max(errs.values()) < 3.0, errs
    assert m["validation"]["proof_of_match"]["all_pass"]


@pytest.mark.slow
def test_estimate_without_vanes_in_wind_and_turbulence(tmp_path):
    """longitudinal_3211_turbulence in the same wind, no vanes: the steady wind leaves the
    airspeed 2.1 x its noise (0.64 m/s rms), so the compatibility stage applies nothing (it
    had bias_ax and scale_ax "significant", truth 0). Measured: FEM with the gust model (the
    filters fit it whatever the maneuvers; alpha_k measured, the 50 Hz grid of the other
    outputs, CLalphadot and Cmalphadot held: not separable here) every derivative within
    1.2 std; before, with the wings-level model on the rebuilt angles' 10 Hz grid, 3.6
    (CLde; with the vanes on its 50 Hz grid within 2.8); OEM, which has no gusts, up to
    13.6 std."""
    from pipeline.jobs.estimate import estimate_log

    run_dir, _ = _fly_in_wind(tmp_path, "longitudinal_3211_turbulence")
    estimate_log(
        run_dir / "flight.mcap",
        tmp_path / "est",
        map_path=str(tmp_path / "novane.toml"),
        methods=["fem"],
        model="longitudinal",
        quiet=True,
        figures=False,
    )
    rep = json.loads((tmp_path / "est" / "report.json").read_text())
    flow = rep["meta"]["flow_angles"]
    assert flow["airspeed_residual_rms_mps"] > 1.5 * flow["airspeed_noise_mps"]
    comp = rep["compatibility"]
    assert comp["applied"] == {} and comp["data_for_estimation"] == "as logged"
    assert "turbulence" in comp["note"] and comp["scope"].startswith("IMU errors only")
    m = rep["methods"]["fem"]
    errs = {
        k: round(abs(v["error_in_std"]), 2)
        for k, v in m["parameters"].items()
        if v.get("error_in_std") is not None and "[" not in k
    }
    assert m["model"] == "longitudinal-measured"
    assert m["converged"] and len(errs) in (11, 13) and max(errs.values()) < 3.0, errs  # alphadot held or free


def test_autopilot_angle_estimates_are_rebuilt(windy):
    """ArduPilot's AOA/SSA are its AHRS's estimate from the EKF velocity and wind (the map
    marks them ``derived``): fsid estimate rebuilds them like missing vanes, and the
    sensor-compatibility stage does not see them as air data."""
    from pipeline.ingest.readers import read_log
    from pipeline.jobs.progress import Progress
    from pipeline.jobs.stages import flow_angle_stage

    _, run_dir, _ = windy
    fd = read_log(run_dir / "flight.bin")
    assert "AHRS estimate" in fd["alpha"].derived and "AHRS estimate" in fd["beta"].derived
    out, _, base, doc = flow_angle_stage(fd, None, Progress(1, quiet=True))
    assert set(doc["replaced"]) == {"alpha", "beta"} and doc["channels"] == ["alpha", "beta"]
    assert "alpha" not in base and "alpha" in fd and out["alpha"].derived.startswith("rebuilt")


def test_autopilot_angles_kept_when_they_cannot_be_rebuilt():
    """A real ArduPilot log on the ground (no forward flight): its AOA stays, and says so."""
    from pipeline.ingest.readers import read_log
    from pipeline.jobs.progress import Progress
    from pipeline.jobs.stages import flow_angle_stage

    log = ROOT.parent / "shared" / "data" / "logs" / "ardupilot_plane_ground_truncated.BIN"
    if not log.is_file():
        pytest.skip("real logs not available")
    fd = read_log(log)
    assert fd["alpha"].derived
    out, _, base, doc = flow_angle_stage(fd, None, Progress(1, quiet=True))
    # estimation keeps them; the sensor-compatibility stage gets the log without them
    assert out is fd and "alpha" not in base and doc["status"] == "not possible"
    assert "kept" in doc["reason"] and "AOA.AOA" in doc["reason"]


@pytest.mark.parametrize("axis", ["longitudinal", "lateral"])
def test_gust_models_measure_a_rebuilt_angle_as_the_rigid_bodys(axis):
    """With ``kin_angles`` = 1 the gust models' alpha (beta) output is the rigid body's
    alpha_k (beta_k), which is what an angle rebuilt from the flight path sees; with 0
    (a vane, at the CG here) the air-relative state. The other outputs do not change."""
    from estimators.model import Namespace
    from estimators.models.lateral import lateral_measured_longitudinal
    from estimators.models.longitudinal import longitudinal_measured_lateral

    base = {
        "m": 1000.0,
        "Ixx": 1300.0,
        "Iyy": 1800.0,
        "Izz": 2600.0,
        "Ixz": 0.0,
        "S": 16.0,
        "cbar": 1.5,
        "b": 11.0,
        "rho": 1.1,
    }
    if axis == "longitudinal":
        build, k, ik = longitudinal_measured_lateral, 1, 4
        x = np.array([60.0, 0.08, 0.05, 0.02, 0.06, 0.01, 0.003])
        u = np.array([-0.02, 900.0, 0.01, 0.05, 0.02, 0.1, 0.3, 1.1])
    else:
        build, k, ik = lateral_measured_longitudinal, 0, 5
        x = np.array([0.04, 0.05, 0.02, 0.1, 0.01, 0.025, 0.005])
        u = np.array([0.02, -0.01, 60.0, 0.06, 0.05, 0.02])
    ys = []
    for kin in (0.0, 1.0):
        m = build({**base, "kin_angles": kin}, rotary_gust=True)
        p = Namespace({q.name: q.value for q in m.parameters})
        ys.append(np.array(m.g(x, u, p, Namespace(m.constants)), dtype=float))
    assert ys[0][k] == pytest.approx(x[k], abs=1e-9)
    assert ys[1][k] == pytest.approx(x[ik], abs=1e-12)
    np.testing.assert_array_equal(np.delete(ys[0], k), np.delete(ys[1], k))
    assert build(base, rotary_gust=True).constants["kin_angles"] == 0.0
