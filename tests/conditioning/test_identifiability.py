"""The identifiability bottom line (pipeline.conditioning.identifiability): right on the
shared real logs and on simulated ones, and ``fsid estimate`` refusing with the very
reasons ``fsid check`` ends with."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.conditioning.checks import airborne_speed, run_checks
from pipeline.conditioning.identifiability import AXIS_NEEDS, identifiability, identifiable_axes
from pipeline.errors import FsidError
from pipeline.ingest.flightdata import FlightData
from pipeline.ingest.readers import read_log
from pipeline.problems import LAT_CHANNELS, LAT_OUTPUTS, LONG_CHANNELS, LONG_OUTPUTS

ROOT = Path(__file__).resolve().parents[2]
LOGS = Path(os.environ.get("FSID_LOGS_DIR") or ROOT.parent / "shared" / "data" / "logs")
AIRCRAFT = str(ROOT / "scenarios" / "aircraft" / "uav_small.toml")


def _check_then_estimate(log: Path, tmp: Path, capsys) -> tuple[dict, str, int]:
    """(checks.json's identifiability, estimate's stderr, estimate's exit code) of ``log``."""
    assert main(["check", str(log), "--aircraft", AIRCRAFT, "--no-compat", "--out", str(tmp / "check")]) == 0
    ident = json.loads((tmp / "check" / "checks.json").read_text())["identifiability"]
    capsys.readouterr()
    code = main(["estimate", str(log), "--aircraft", AIRCRAFT, "--out", str(tmp / "est")])
    return ident, capsys.readouterr().err, code


def _same_story(ident: dict, err: str) -> None:
    """Every reason check gives is a line of estimate's refusal, and nothing else is."""
    lines = [ln.strip() for ln in err.split("be identified:\n", 1)[1].splitlines() if ln.startswith("  ")]
    assert lines == [f"{axis}: {why}" for axis, r in ident.items() for why in r["reasons"]]


def test_axis_needs_are_what_the_problems_read():
    assert AXIS_NEEDS["longitudinal"].channels == LONG_CHANNELS
    assert AXIS_NEEDS["lateral"].channels == LAT_CHANNELS
    assert AXIS_NEEDS["longitudinal"].outputs == LONG_OUTPUTS
    assert AXIS_NEEDS["lateral"].outputs == LAT_OUTPUTS


# ------------------------------------------------------------------ shared real logs
def _real(name: str) -> Path:
    p = LOGS / name
    if not p.is_file():
        pytest.skip(f"{p} not present (shared real logs)")
    return p


def test_ardupilot_ground_log_is_on_the_ground_without_airspeed(tmp_path, capsys):
    ident, err, code = _check_then_estimate(_real("ardupilot_plane_ground_truncated.BIN"), tmp_path, capsys)
    assert code != 0
    for r in ident.values():
        assert not r["possible"] and r["missing"] == ["V"]
        assert r["reasons"][0].startswith("on the ground or hovering over the whole log")
        assert any(w.startswith("too short: the log spans 1.0 s") for w in r["reasons"])
    _same_story(ident, err)


def test_px4_ground_log_is_on_the_ground_not_lacking_alpha(tmp_path, capsys):
    ident, err, code = _check_then_estimate(_real("px4_vtol_ground_small.ulg"), tmp_path, capsys)
    assert code != 0
    for r in ident.values():
        assert not r["possible"] and r["missing"] == []
        assert r["reasons"][0].startswith("on the ground or hovering over the whole log (airspeed below 5 m/s")
        assert not any("alpha" in w or "beta" in w for w in r["reasons"])
        assert r["modes"] and r["modes"][0]["mode"] == "MANUAL"
        assert r["maneuvers"] and not any(m["airborne"] for m in r["maneuvers"])
    assert "needs channels" not in err and "alpha" not in err.split("be identified:\n", 1)[1]
    _same_story(ident, err)


@pytest.mark.slow
def test_quadplane_telemetry_is_too_slow_and_lacks_the_rudder(tmp_path, capsys):
    ident, err, code = _check_then_estimate(_real("ardupilot_quadplane_sitl.tlog"), tmp_path, capsys)
    assert code != 0
    lon, lat = ident["longitudinal"], ident["lateral"]
    assert not lon["possible"] and lon["missing"] == []
    assert lon["reasons"][0].startswith("rate too low: q 4") and "short period" in lon["reasons"][0]
    assert not lat["possible"] and lat["missing"] == ["dr"]
    assert lat["reasons"][0].startswith("dr missing: no servo output configured for dr")
    assert not any(w.startswith("on the ground") for r in ident.values() for w in r["reasons"])
    # it flies: maneuvers in forward flight in the fixed-wing modes, hovering ones in the Q modes
    modes = {m["mode"]: m["airborne"] for m in lat["maneuvers"]}
    assert modes["CIRCLE"] and [m["mode"] for m in lon["modes"]] == ["QLOITER", "CIRCLE", "GUIDED", "QLAND"]
    _same_story(ident, err)


# ------------------------------------------------------------------ simulated logs
@pytest.fixture(scope="module")
def default_fd() -> FlightData:
    pytest.importorskip("jsbsim")
    from _simdata import written

    return read_log(written("default") / "flight.bin")


def _write_csv(path: Path, fd: FlightData, drop: tuple[str, ...] = ()) -> Path:
    """``fd`` on a 100 Hz grid as a canonical CSV (the format fsid check writes), without ``drop``."""
    df = fd.resample(100.0, [c for c in fd.names if c not in drop], span="union")
    df.to_csv(path, index=False, float_format="%.9g")
    return path


def test_good_simulated_flight_is_identifiable_on_both_axes(default_fd):
    res = identifiability(default_fd, run_checks(default_fd))
    for axis, r in res.items():
        assert r.possible and not r.reasons and not r.missing, (axis, r.reasons)
        assert len([m for m in r.maneuvers if m.airborne and m.usable]) >= 2
    assert identifiable_axes(res, ("longitudinal", "lateral"), "flight.bin") == ("longitudinal", "lateral")


def test_the_aircraft_stall_speed_is_the_airborne_floor(default_fd):
    """The same ~30 m/s flight is on the ground for an aircraft that stalls at 40 m/s, and
    flying for one that stalls at 3 m/s (an indoor micro aircraft's floor, below the 5 m/s
    default): one floor for the checks, the windows and the bottom line."""
    assert airborne_speed(default_fd) == 5.0
    for stall, flying in ((40.0, False), (3.0, True)):
        fd = dataclasses.replace(default_fd, meta={**default_fd.meta, "stall_speed_mps": stall})
        assert airborne_speed(fd) == stall
        res = identifiability(fd, run_checks(fd))
        for axis, r in res.items():
            assert r.possible is flying, (stall, axis, r.reasons)
            if not flying:
                assert r.reasons[0].startswith(
                    f"on the ground or hovering over the whole log (airspeed below {stall:g} m/s"
                )


def test_one_axis_left_is_fitted_without_the_other(default_fd):
    fd = FlightData({k: c for k, c in default_fd.channels.items() if k != "de"}, default_fd.meta, default_fd.segments)
    res = identifiability(fd, run_checks(fd))
    assert res["longitudinal"].missing == ("de",) and res["lateral"].possible
    assert identifiable_axes(res, ("longitudinal", "lateral"), "x") == ("lateral",)
    with pytest.raises(
        FsidError, match=r"the longitudinal axis of x cannot be identified:\n  longitudinal: de missing"
    ):
        identifiable_axes(res, ("longitudinal",), "x")


def test_log_without_surfaces_is_refused_naming_them(default_fd, tmp_path, capsys):
    log = _write_csv(tmp_path / "no_surfaces.csv", default_fd, drop=("de", "da", "dr"))
    ident, err, code = _check_then_estimate(log, tmp_path, capsys)
    assert code == 2
    assert ident["longitudinal"]["missing"] == ["de"] and ident["lateral"]["missing"] == ["da", "dr"]
    assert "no control-input activity" not in err
    assert "longitudinal: de missing" in err and "lateral: da missing" in err and "lateral: dr missing" in err
    _same_story(ident, err)


def _ground_csv(path: Path) -> Path:
    """30 s of an aircraft standing on the ground at 100 Hz through a control check: every
    surface swept by +-10 deg, gyro and accelerometer noise, airspeed a pitot's 0-1.5 m/s,
    inertial velocity near 0, constant altitude and attitude; no alpha/beta vane."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 30.0, 0.01)
    n = t.size
    sweep = np.radians(10.0) * np.sin(2 * np.pi * 0.5 * t) * ((t % 10.0) < 6.0)
    cols = {
        "t": t,
        **{k: rng.normal(0.0, 0.003, n) for k in ("p", "q", "r")},
        "ax": rng.normal(0.0, 0.05, n),
        "ay": rng.normal(0.0, 0.05, n),
        "az": rng.normal(-9.81, 0.05, n),
        "phi": np.full(n, 0.01),
        "theta": np.full(n, 0.05),
        "psi": np.full(n, 1.2),
        "V": np.abs(rng.normal(0.7, 0.4, n)),
        **{k: rng.normal(0.0, 0.02, n) for k in ("vn", "ve", "vd")},
        "h": 120.0 + rng.normal(0.0, 0.1, n),
        "de": sweep,
        "da": np.roll(sweep, 1000),
        "dr": np.roll(sweep, 2000),
        "throttle": np.zeros(n),
    }
    header = ",".join(cols)
    np.savetxt(path, np.column_stack(list(cols.values())), delimiter=",", header=header, comments="", fmt="%.9g")
    return path


def test_log_on_the_ground_is_refused_as_on_the_ground(tmp_path, capsys):
    ident, err, code = _check_then_estimate(_ground_csv(tmp_path / "ground.csv"), tmp_path, capsys)
    assert code == 2
    for r in ident.values():
        assert not r["possible"] and r["missing"] == []
        assert r["reasons"][0].startswith("on the ground or hovering over the whole log (airspeed below 5 m/s")
        assert r["maneuvers"] and not any(m["airborne"] for m in r["maneuvers"])
    refusal = err.split("be identified:\n", 1)[1]
    assert "alpha" not in refusal and "beta" not in refusal and "needs channels" not in err
    _same_story(ident, err)


def test_pose_only_flight_has_its_states_and_its_windows_named():
    """The Sport Cub motion-capture archive (pose and surface commands only, at 4-5 m/s):
    the states derived from the pose count as present; its named windows are maneuvers of
    the surface they move, or of the axis whose rate answers (the elevator and throttle
    ones make the longitudinal axis), and given as time ranges they are the same
    maneuvers."""
    npz = LOGS.parent / "sportcub" / "sportcub_mocap_4_17_26_train.npz"
    if not npz.is_file():
        pytest.skip(f"{npz} not present (shared real data)")
    fd = read_log(npz)
    res = identifiability(fd, run_checks(fd))
    assert all(not r.missing for r in res.values())
    lon = res["longitudinal"]
    assert lon.possible and [m.name for m in lon.maneuvers] == [
        "elev_3211_1__elev_001",
        "trim_2__elev_001",
        "elev_3211_3__elev_001",
        "throttle_cub1__thr_001",  # no surface moves; the pitch rate answers the throttle
    ], lon.reasons
    picked = FlightData(fd.channels, fd.meta, fd.chosen_segments([(0.0, 2.49), (6.48, 8.97)]))
    lon = identifiability(picked, run_checks(picked))["longitudinal"]
    assert lon.possible and [m.surfaces for m in lon.maneuvers] == ["de", "de"], lon.reasons


def test_a_log_with_nothing_to_fit_says_so_before_asking_for_an_aircraft(tmp_path, capsys):
    log = _real("px4_vtol_ground_small.ulg")
    assert main(["check", str(log), "--no-compat", "--out", str(tmp_path / "check")]) == 0
    ident = json.loads((tmp_path / "check" / "checks.json").read_text())["identifiability"]
    capsys.readouterr()
    assert main(["estimate", str(log), "--out", str(tmp_path / "est")]) == 2
    err = capsys.readouterr().err
    assert "--aircraft" not in err.split("be identified:\n", 1)[1]
    _same_story(ident, err)


def test_excitation_is_judged_by_the_response(default_fd):
    """The elevator moved a tenth as far (a full-scale aircraft's small inputs): its
    maneuvers still excite the axis, because the pitch rate answers far above its floor;
    with the pitch rate flat as well, the axis is not excited and the reason names both."""
    small = {**default_fd.channels, "de": dataclasses.replace(default_fd["de"], values=default_fd["de"].values * 0.1)}
    fd = FlightData(small, default_fd.meta, default_fd.segments)
    lon = identifiability(fd, run_checks(fd))["longitudinal"]
    assert max(m.excitation for m in lon.maneuvers) < np.radians(1.0)  # under the surface rule
    assert lon.possible, lon.reasons
    q = default_fd["q"]
    flat = FlightData(
        {**small, "q": dataclasses.replace(q, values=np.zeros(len(q)))}, default_fd.meta, default_fd.segments
    )
    lon = identifiability(flat, run_checks(flat))["longitudinal"]
    assert not lon.possible and any(w.startswith("no excitation: de moves by at most") for w in lon.reasons), (
        lon.reasons
    )


def test_a_window_given_by_time_is_never_dropped_unsaid(default_fd):
    """A window whose surfaces hardly move but whose pitch rate does (a phugoid after a
    pulse) is an elevator window; one where nothing moves is named in the reason."""
    chans = dict(default_fd.channels)
    for c in ("de", "da", "dr"):
        chans[c] = dataclasses.replace(chans[c], values=np.full(len(chans[c]), 0.01))
    t = chans["q"].t
    lo = float(t[0])
    phugoid = {**chans, "q": dataclasses.replace(chans["q"], values=0.03 * np.sin(2 * np.pi * (t - lo) / 20.0))}
    fd = FlightData(phugoid, default_fd.meta, [])
    segs = fd.chosen_segments([(10.0, 50.0)])
    assert "de" in {s.axis for s in segs} and {s.kind for s in segs} == {"time"}
    still = {**chans, **{c: dataclasses.replace(chans[c], values=np.zeros(len(chans[c]))) for c in ("p", "q", "r")}}
    fd = FlightData(still, default_fd.meta, [])
    fd.segments = fd.chosen_segments([(10.0, 50.0)], per_axis=True)
    lon = identifiability(fd, run_checks(fd))["longitudinal"]
    assert any("the windows given, time_10-50s (10.0-50.0 s)" in w for w in lon.reasons), lon.reasons


def test_the_rate_rule_is_sized_by_the_motion_the_data_show():
    """Ten samples a period of the fastest motion a channel shows (its own spectrum): a
    business jet's 0.5 Hz short period logged at 10 Hz is enough; a small UAV's 2 Hz mode
    logged at 10 Hz is not (folded up to the Nyquist frequency, it asks for the ceiling),
    and at 100 Hz it is."""
    from pipeline.ingest.sampling import response_floor_hz

    rng = np.random.default_rng(0)

    def q(mode_hz: float, rate: float) -> tuple[np.ndarray, np.ndarray]:
        t = np.arange(0.0, 120.0, 1.0 / rate)
        v = np.sin(2 * np.pi * mode_hz * t) * np.exp(-0.02 * (t % 20.0)) + 0.01 * rng.standard_normal(t.size)
        return t, v

    jet = response_floor_hz(*q(0.5, 10.0), 20.0, 4.0)
    assert 4.0 <= jet <= 10.0, jet
    assert response_floor_hz(*q(2.0, 10.0), 20.0, 4.0) == 20.0
    assert response_floor_hz(*q(2.0, 100.0), 20.0, 4.0) == 20.0  # needs 20, has 100
    assert response_floor_hz(np.arange(10.0), np.zeros(10), 20.0, 4.0) == 20.0  # too few samples to tell


def test_a_small_uav_logged_at_10_hz_is_refused_with_the_rate_it_needs(default_fd):
    slow = {k: (dataclasses.replace(c, t=c.t[::10], values=c.values[::10]) if k in ("q", "az") else c)
            for k, c in default_fd.channels.items()}  # fmt: skip
    fd = FlightData(slow, default_fd.meta, default_fd.segments)
    lon = identifiability(fd, run_checks(fd))["longitudinal"]
    assert not lon.possible
    why = [r for r in lon.reasons if r.startswith("rate too low")]
    assert why and "ten samples a period" in why[0], lon.reasons
    need = float(why[0].split("q 10.0 Hz (needs ", 1)[1].split(")", 1)[0])
    assert 10.0 < need <= 20.0, why


def test_accept_low_rate_turns_the_rate_refusal_into_a_stated_risk(default_fd):
    """The user's soft limit (fsid estimate --accept-low-rate): the same 10 Hz q is no longer
    a reason the axis cannot be identified; it stays as a risk, in checks.json's entry."""
    slow = {k: (dataclasses.replace(c, t=c.t[::10], values=c.values[::10]) if k in ("q", "az") else c)
            for k, c in default_fd.channels.items()}  # fmt: skip
    fd = FlightData(slow, default_fd.meta, default_fd.segments)
    lon = identifiability(fd, run_checks(fd), accept_low_rate=True)["longitudinal"]
    assert lon.possible and not any(r.startswith("rate too low") for r in lon.reasons), lon.reasons
    assert lon.risks and lon.risks[0].startswith("rate too low: q 10.0 Hz (needs")
    assert lon.as_dict()["risks"] == list(lon.risks)
