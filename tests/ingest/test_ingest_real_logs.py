"""Ingest the real third-party logs in ../shared/data/logs (skipped when absent).

Expected numbers were taken independently from pymavlink (DFReader, mavutil) and pyulog
over the same files, and from scipy's Rotation for the quaternion -> Euler conversion.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from pipeline.conditioning.checks import run_checks
from pipeline.ingest.readers import read_log


def _logs_dir() -> Path:
    env = os.environ.get("FSID_LOGS_DIR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "shared" / "data" / "logs"


LOGS = _logs_dir()
BIN = LOGS / "ardupilot_plane_ground_truncated.BIN"
TLOG = LOGS / "ardupilot_quadplane_sitl.tlog"
ULG = LOGS / "px4_vtol_ground_small.ulg"


def need(p: Path) -> Path:
    if not p.is_file():
        pytest.skip(f"real log {p.name} not available")
    return p


@pytest.fixture(scope="module")
def bin_fd():
    return read_log(need(BIN))


@pytest.fixture(scope="module")
def tlog_fd():
    return read_log(need(TLOG))


@pytest.fixture(scope="module")
def tlog_recv():
    """The .tlog on its receive stamps (``time_base="log"``)."""
    return read_log(need(TLOG), time_base="log")


@pytest.fixture(scope="module")
def ulg_fd():
    return read_log(need(ULG))


# ------------------------------------------------------------------ ArduPilot .BIN
def test_bin_counts_values_and_units(bin_fd):
    fd = bin_fd
    counts = fd.meta["info"]["message_counts"]
    # DFReader over the same file: IMU 45, IMU2 45, ATT 24, PARM 809, FMT 132, AOA 23, BARO 8
    assert counts["IMU"] == 45 and counts["IMU2"] == 45 and counts["ATT"] == 24
    assert counts["PARM"] == 809 and counts["FMT"] == 132 and counts["AOA"] == 23
    assert counts["BARO"] == 8 and counts["RCOU"] == 23
    assert len(fd["p"]) == 45
    # first IMU: TimeUS 81794643, GyrX -0.1165708526968956 rad/s, AccZ -9.780994415283203
    assert fd["p"].t[0] + fd.meta["t0_abs"] == pytest.approx(81.794643, abs=1e-9)  # seconds from the start
    assert fd["p"].values[0] == pytest.approx(-0.1165708526968956, rel=1e-12)
    assert fd["az"].values[0] == pytest.approx(-9.780994415283203, rel=1e-12)
    # last complete IMU: TimeUS 82769489, AccZ -9.931867599487305
    assert fd["az"].t[-1] + fd.meta["t0_abs"] == pytest.approx(82.769489, abs=1e-9)
    assert fd["az"].values[-1] == pytest.approx(-9.931867599487305, rel=1e-12)
    # ATT Roll -7.18 deg, Yaw 337.1 deg (format 'c' / 'C': 0.01 deg) -> rad
    assert fd["phi"].values[0] == pytest.approx(np.radians(-7.18), abs=1e-12)
    assert fd["psi"].values[0] == pytest.approx(np.radians(337.1), abs=1e-9)
    assert fd["phi"].unit == "rad" and fd["az"].unit == "m/s^2"


def test_bin_params_modes_servo_calibration(bin_fd):
    fd = bin_fd
    assert len(fd.params) == 809  # DFReader.params has 809 names
    assert fd.params["SERVO2_FUNCTION"] == 19.0
    assert fd.params["INS_ACCOFFS_Y"] == pytest.approx(2.4852089881896973)
    assert [(t + fd.meta["t0_abs"], m) for t, m in fd.modes] == [(pytest.approx(82.020997), "MANUAL")]
    # de from RCOU C2 (elevator by SERVO2_FUNCTION=19): first pulse 1402, trim 1401,
    # max 2000, reversed -> -(1/599) of full travel (30 deg), ArduPilot sign -> +
    assert "RCOU.C2" in fd["de"].source
    assert fd["de"].values[0] == pytest.approx(np.radians(30.0) / 599.0, rel=1e-9)
    # throttle on SERVO3 (function 70): pulse 1100 at min -> 0
    assert fd["throttle"].values[0] == 0.0
    # a real log does not say how far the surfaces move at full servo travel: 30 deg is
    # assumed, reported, and a data-quality warning names the aircraft TOML key to set
    assert fd.meta["servo_travel"] == {a: {"deg": 30.0, "from": "assumed"} for a in ("de", "da", "dr")}
    warn = [f.message for f in run_checks(fd) if f.channel == "de" and "servo" in f.message]
    assert len(warn) == 1 and "[servos] de_travel_deg" in warn[0]


def test_bin_servo_travel_given_by_the_caller():
    """The aircraft TOML's [servos] (passed by fsid estimate) scales the decoded surface."""
    if not BIN.is_file():
        pytest.skip("shared real logs absent")
    fd = read_log(BIN, servo_travel={"de": (20.0, "aircraft TOML [servos] de_travel_deg")})
    assert fd["de"].values[0] == pytest.approx(np.radians(20.0) / 599.0, rel=1e-9)
    assert fd.meta["servo_travel"]["de"] == {"deg": 20.0, "from": "aircraft TOML [servos] de_travel_deg"}
    assert fd.meta["servo_travel"]["da"]["from"] == "assumed"
    assert not fd["de"].notes and "servo" in fd["da"].notes


def test_bin_truncated_last_record_is_reported_and_data_kept(bin_fd):
    dmg = bin_fd.meta["damage"]
    # 65536-byte file; DFReader stops at offset 65515 = 65512 + 3 header bytes
    assert dmg["offset"] == 65512
    assert dmg["kept_records"] == 1731  # DFReader decodes 1731 messages
    assert "cut short" in dmg["message"]


def test_bin_checks_flag_truncation_ground_and_missing_airspeed(bin_fd):
    fs = run_checks(bin_fd)
    by = {(f.check, f.channel): f for f in fs}
    assert by[("damage", None)].status == "warn"
    assert by[("missing", "V")].status == "warn"
    ground = [f for f in fs if f.check == "ground"]
    assert ground and all(f.status == "warn" for f in ground)
    assert not any(f.status == "fail" for f in fs)


# ------------------------------------------------------------------ MAVLink .tlog
def test_tlog_counts_params_modes(tlog_fd):
    fd = tlog_fd
    info = fd.meta["info"]
    # mavutil over the same file: ATTITUDE 888, VFR_HUD 878, SCALED_IMU2 796, HEARTBEAT 199,
    # PARAM_VALUE 1147 messages for 1053 parameters
    assert info["message_counts"]["ATTITUDE"] == 888
    assert info["message_counts"]["VFR_HUD"] == 878
    assert info["message_counts"]["SCALED_IMU2"] == 796
    assert info["message_counts"]["HEARTBEAT"] == 199
    assert info["param_value_count"] == 1147
    assert len(fd.params) == 1053
    assert fd.params["SR0_RAW_SENS"] == 4.0  # last value sent wins (first was 2.0)
    assert fd.params["ARSPD_TYPE"] == 2.0
    assert [m for _, m in fd.modes] == ["QLOITER", "CIRCLE", "GUIDED", "QLAND"]


def test_tlog_receive_stamps(tlog_recv):
    """time_base="log": the .tlog's own receive stamps (mavutil's ``_timestamp``)."""
    fd = tlog_recv
    assert "receive" in fd.meta["time_base"]
    assert fd.meta["t0_kind"] == "epoch UTC"
    assert fd.modes[0][0] + fd.meta["t0_abs"] == pytest.approx(1533737161.935, abs=1e-3)
    assert fd.modes[3][0] + fd.meta["t0_abs"] == pytest.approx(1533737285.271, abs=1e-3)
    assert fd["phi"].t[0] + fd.meta["t0_abs"] == pytest.approx(1533737161.914, abs=1e-3)
    segs = [s for s in fd.segments if s.kind == "mode"]
    assert segs[1].duration == pytest.approx(1533737246.913 - 1533737201.028, abs=1e-2)


def test_tlog_values_and_units(tlog_fd):
    fd = tlog_fd
    assert fd["phi"].values[0] == pytest.approx(-0.024653663858771324, rel=1e-7)
    # SCALED_IMU2 first: zacc -999 mG, xgyro -8 mrad/s
    assert fd["az"].values[0] == pytest.approx(-999 * 9.80665e-3)
    assert fd["p"].values[0] == pytest.approx(-0.008)
    assert "SCALED_IMU2" in fd["az"].source
    # GLOBAL_POSITION_INT relative_alt 6750 mm, vx -188 cm/s
    assert fd["h"].values[0] == pytest.approx(6.75)
    assert fd["vn"].values[0] == pytest.approx(-1.88)


def test_tlog_surfaces_follow_servo_functions(tlog_fd):
    """A tilt-rotor quadplane: outputs 1/2 are aileron and elevator (SERVOn_FUNCTION 4, 19),
    output 4 tilts a motor (76) and no output is a rudder (21) or a V-tail (79/80): no dr,
    rather than the map's default output 4 (it had been read as the rudder)."""
    fd = tlog_fd
    assert fd.params["SERVO4_FUNCTION"] == 76.0
    assert "servo1_raw" in fd["da"].source and "servo2_raw" in fd["de"].source
    assert "dr" not in fd
    assert fd.meta["unmapped"]["dr"] == "no servo output configured for dr (no SERVOn_FUNCTION = 21 or 79/80)"


def test_tlog_checks_flag_low_rate_and_hover_segments(tlog_fd):
    fs = run_checks(tlog_fd)
    slow = [f for f in fs if f.check == "rate" and f.status == "warn"]
    assert {"p", "q", "r", "phi", "V"} <= {f.channel for f in slow}
    for f in slow:
        assert 3.0 < f.value < 5.0  # ~4 Hz telemetry
    assert any(f.check == "ground" and "QLOITER" in f.message for f in fs)
    assert not any(f.status == "fail" for f in fs)


def test_tlog_mode_segments(tlog_fd):
    segs = [s for s in tlog_fd.segments if s.kind == "mode"]
    assert [s.mode for s in segs] == ["QLOITER", "CIRCLE", "GUIDED", "QLAND"]
    # on the autopilot's clock: the latest stamp sent before each mode's first HEARTBEAT
    # (mavutil, in file order): GUIDED 694.456375 s, CIRCLE 648.399359 s since boot
    assert segs[1].duration == pytest.approx(694.456375 - 648.399359, abs=1e-6)


# ------------------------------------------------------------------ PX4 .ulg
def test_ulg_vtol_surfaces_are_the_fixed_wing_controls(ulg_fd):
    """A standard VTOL (VT_TYPE 2): its surfaces and pusher are PX4's actuator group 1; group
    0 is the multicopter's attitude control (it had been read as the surfaces)."""
    fd = ulg_fd
    assert fd.params["VT_TYPE"] == 2.0
    for ch, k in (("da", 0), ("de", 1), ("dr", 2), ("throttle", 3)):
        assert fd[ch].source == f"actuator_controls_1.control[{k}]", (ch, fd[ch].source)


def test_ulg_values_quaternion_params(ulg_fd):
    fd = ulg_fd
    assert len(fd["p"]) == 1298
    assert fd["p"].t[0] + fd.meta["t0_abs"] == pytest.approx(20.326716)
    assert fd["p"].values[0] == pytest.approx(0.0029683835, rel=1e-6)
    assert fd["az"].values[0] == pytest.approx(-9.634243, rel=1e-6)
    # vehicle_attitude sample 100 (t = 20.971931 s): scipy ZYX euler = (yaw, pitch, roll)
    i = int(np.argmin(np.abs(fd["psi"].t + fd.meta["t0_abs"] - 20.971931)))
    assert fd["psi"].values[i] == pytest.approx(0.19692472, abs=1e-6)
    assert fd["theta"].values[i] == pytest.approx(-0.00189195, abs=1e-6)
    assert fd["phi"].values[i] == pytest.approx(0.01894606, abs=1e-6)
    assert len(fd.params) == 980
    assert fd.params["ASPD_BETA_NOISE"] == pytest.approx(0.3)
    assert [m for _, m in fd.modes] == ["MANUAL"]
    assert set(fd.missing(["alpha", "beta", "V"])) == {"alpha", "beta"}


def test_ulg_resample_common_base(ulg_fd):
    df = ulg_fd.resample(50.0, ["p", "q", "phi", "de"])
    assert list(df.columns) == ["t", "p", "q", "phi", "de"]
    assert np.allclose(np.diff(df["t"]), 0.02)
    # the 0.16 s without gyro and attitude samples after the first one stays NaN
    assert np.isfinite(df[["p", "q", "phi", "de"]].to_numpy()).mean() > 0.98
    # anti-aliased, so the resampled gyro has smaller spread than the raw 200 Hz one
    assert df["p"].std() < np.std(ulg_fd["p"].values)


def test_tlog_autopilot_time_base(tlog_fd, tlog_recv):
    """The default time base of a .tlog: the autopilot's stamps (pipeline.ingest.readers.tlog_time).
    Expected numbers from mavutil over the file, in file order."""
    fd = tlog_fd
    assert fd.meta["time_base"].startswith("autopilot stamps")
    with pytest.raises(Exception, match="time base .gps. does not apply to a tlog log"):
        read_log(TLOG, time_base="gps")
    # ATTITUDE.time_boot_ms 608582, 608821, 609063, 609301, 609543, then 611021 ... 611941
    # received before 610541 and 610781: put back in order
    t = fd["phi"].t - fd["phi"].t[0]
    assert np.allclose(t[:8], [0, 0.239, 0.481, 0.719, 0.961, 1.959, 2.199, 2.439], atol=1e-6)
    assert np.all(np.diff(fd["phi"].t) > 0) and len(fd["phi"]) == 888
    i = np.flatnonzero(np.isclose(t, 1.959, atol=1e-6))[0]
    assert fd["phi"].values[i] == pytest.approx(-0.0266, abs=1e-4)  # roll sent at 610541 ms
    assert np.any(np.diff(tlog_recv["phi"].t) < 0.01)
    # the modes and VFR_HUD (no stamp) at the latest stamp sent before them: QLOITER's first
    # HEARTBEAT after 609.301766 s, CIRCLE 648.399359, GUIDED 694.456375, QLAND 732.449763
    rel = [m - fd["phi"].t[0] for m, _ in fd.modes]
    assert np.allclose(rel, np.array([609.301766, 648.399359, 694.456375, 732.449763]) - 608.582, atol=1e-6)
    assert fd["V"].t[0] - fd["phi"].t[0] == pytest.approx(0.000234, abs=1e-6)
    jit = {c.channel: c.value for c in run_checks(fd) if c.check == "jitter"}
    jit_log = {c.channel: c.value for c in run_checks(tlog_recv) if c.check == "jitter"}
    # autopilot stamps are steadier than bursty arrivals, also for VFR_HUD's airspeed
    assert jit["phi"] < 0.5 * jit_log["phi"] and jit["V"] < 0.5 * jit_log["V"], (jit, jit_log)
    assert not any(c.check in ("time_order", "duplicate_times") and c.status != "pass" for c in run_checks(fd))


@pytest.mark.parametrize("name", [BIN.name, TLOG.name, ULG.name])
def test_fsid_check_on_real_logs_does_not_fail_the_run(name, tmp_path):
    import json

    from pipeline.cli import main

    log = need(LOGS / name)
    assert main(["check", str(log), "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "checks.json").read_text())
    # none of them can be identified: that (and only that) fails, one finding per axis
    fails = [f for f in doc["findings"] if f["status"] == "fail"]
    assert [f["check"] for f in fails] == ["identifiability"] * 2 and doc["summary"]["warn"] > 0
    assert not any(r["possible"] for r in doc["identifiability"].values())
    # compatibility is attempted and says why it cannot run on these logs
    assert doc["compatibility"]["status"] == "skipped" and doc["compatibility"]["reason"]
    assert (tmp_path / "canonical.csv").stat().st_size > 0
    if name == BIN.name:
        assert doc["source"]["damage"]["offset"] == 65512


def test_tlog_circles_calibrate_the_airspeed_with_the_wind(tlog_fd):
    """The quadplane's CIRCLE and loiter flight turns through 700 deg: the wind fit can tell
    a pitot scale factor from the wind (std 0.42 %), and SITL's simulated pitot has none
    (estimate -0.01 %, not applied, its std carried) in its near-calm air (0.1 m/s)."""
    from pipeline.conditioning.flow_angles import reconstruct_flow_angles

    out, doc = reconstruct_flow_angles(tlog_fd)
    cal = doc["airspeed_scale"]
    assert doc["heading_span_deg"] > 600.0
    assert cal["status"] == "estimated" and cal["std"] < 0.01 and cal["carried"], cal
    assert abs(cal["estimate"]) < 3 * cal["std"] and not cal["applied"], cal
    assert np.array_equal(out["V"].values, tlog_fd["V"].values)
    assert np.hypot(doc["wind"]["north_mps"][0], doc["wind"]["east_mps"][0]) < 1.0
