"""What a newcomer tripped over (issue 45, section 6), each fixed where it arose: one rule
for every sample rate fsid states, the channels identification needs listed when a log
lacks them, a configuration file given as the log named as such, the .npz archive in the
help, and no reference to a design document users do not have."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _ros2 import stamped

from pipeline.cli import build_parser, main
from pipeline.conditioning.checks import run_checks
from pipeline.ingest.readers import read_log
from pipeline.ingest.sampling import sample_rate
from pipeline.jobs.fields import list_fields

TEMPLATE = "pipeline/ingest/aircraft_template.toml"


def _bursty_csv(path):
    """A CSV whose samples arrive in bursts (3 within 4 ms, then a pause): its median
    interval (2 ms) says 500 Hz, its samples 10 a second."""
    t = np.concatenate([k * 0.3 + np.array([0.0, 0.002, 0.004]) for k in range(60)])
    rows = "\n".join(f"{x:.4f},{0.01 * i:.4f},0.0" for i, x in enumerate(t))
    path.write_text("t,q,p\n" + rows + "\n")
    return t


def test_one_rate_rule_in_fields_and_checks(tmp_path):
    log = tmp_path / "bursty.csv"
    t = _bursty_csv(log)
    lf = list_fields(log)
    (table,) = lf.tables
    rate = round(sample_rate(t), 3)
    # samples per second over the record, not the median interval's 500 Hz
    assert table.rate_hz == rate and rate == pytest.approx((t.size - 1) / (t[-1] - t[0]), rel=1e-3)
    fd = read_log(log, segments=[])
    checked = [f.value for f in run_checks(fd) if f.check == "rate" and f.channel == "q"]
    assert checked == [pytest.approx(rate, rel=1e-3)]


def test_mapped_only_lists_the_missing_control_surfaces(tmp_path, capsys):
    log = tmp_path / "rates.csv"
    _bursty_csv(log)
    assert main(["fields", str(log), "--mapped-only"]) == 0
    out = capsys.readouterr().out
    missing = out.split("not filled by the map")[1]
    for ch in ("de", "da", "dr", "alpha", "V"):
        assert f"\n  {ch} " in missing, (ch, missing)
    assert "\n  q " not in missing


@pytest.mark.parametrize(
    ("name", "said"), [("plane.toml", "TOML file"), ("truth.json", "JSON file"), ("model.py", "--model FILE.py:NAME")]
)
def test_a_configuration_file_given_as_the_log(tmp_path, capsys, name, said):
    path = tmp_path / name
    path.write_text("[aircraft]\nname = 'x'\n")
    assert main(["check", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert said in err and "not a flight log" in err and "no numeric data lines" not in err, err
    assert len(err.strip().splitlines()) == 1


def test_npz_in_the_help_and_the_readme():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for cmd in ("check", "estimate", "fields"):
        assert ".npz" in sub.choices[cmd].format_help(), cmd
    assert ".npz" in open("README.md").read()


def test_no_design_md_where_users_read(tmp_path, capsys):
    text = open(TEMPLATE).read()
    assert "DESIGN.md" not in text
    path = tmp_path / "a.toml"
    assert main(["aircraft", "init", str(path)]) == 0
    assert main(["aircraft", "check", str(path)]) == 0
    printed = capsys.readouterr()
    assert "DESIGN.md" not in printed.out + printed.err and "docs/aircraft.md" in printed.out
    bad = tmp_path / "b.toml"
    bad.write_text(text.replace("[apriori]", "[apriori]\nCfoo = { value = 1.0, std = 1.0 }", 1))
    assert main(["aircraft", "check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "DESIGN.md" not in err and "docs/aircraft.md" in err, err


def test_the_compatibility_stage_splits_its_windows_at_gaps():
    """A window with a 3-s hole in the IMU record: the flight-path fit takes the two sides
    as two segments (named <window>.0, .1) instead of asking the user to split them."""
    from pipeline.conditioning.compatibility import _segment_frames
    from pipeline.ingest.flightdata import Channel, FlightData, SegmentSpec

    t = np.arange(0.0, 20.0, 0.02)
    t = t[(t < 8.0) | (t >= 11.0)]
    chans = {c: Channel(t, np.full(t.size, 0.1), "") for c in ("ax", "ay", "az", "p", "q", "r", "phi", "theta")}
    fd = FlightData(chans, {}, [])
    frames = _segment_frames(fd, [SegmentSpec("w", 0.0, 20.0)], 50.0, ["phi", "theta"], np.zeros(3))
    assert [s.name for s, _ in frames] == ["w.0", "w.1"]
    (a, da), (b, db) = frames
    assert da["t"].iloc[-1] < 9.0 < 10.0 < db["t"].iloc[0] and a.t1 < 9.0 < 10.0 < b.t0


def test_messages_in_command_line_terms():
    """The estimators' Python-API advice reaches the command line in its own terms, and an
    unset limit is not printed as 'airspeed >= inf m/s'."""
    from estimators.errors import DIVERGE_HINT, SimulationDivergedError
    from pipeline.conditioning.flow_angles import reconstruct_flow_angles
    from pipeline.errors import FsidError, describe
    from pipeline.ingest.flightdata import Channel, FlightData

    line = describe(SimulationDivergedError(f"the simulation ran away at t=3 s. {DIVERGE_HINT}"))
    assert "StabilizedOutputError" not in line and "stabilisation matrix" not in line
    assert "--method fem, ekf or ukf" in line and line.startswith("the simulation ran away at t=3 s.")
    t = np.arange(0.0, 30.0, 0.1)
    chans = {c: Channel(t, np.zeros(t.size), "") for c in ("vn", "ve", "vd", "phi", "theta", "psi")}
    chans["V"] = Channel(t, np.full(t.size, np.nan), "m/s")  # no airspeed logged in flight
    with pytest.raises(FsidError) as err:
        reconstruct_flow_angles(FlightData(chans, {}, []))
    assert "inf" not in str(err.value) and "fewer than 20 velocity samples" in str(err.value), err.value


def test_a_tlog_with_only_the_local_position_gives_h_and_the_velocity(tmp_path):
    """A .tlog without GPS (LOCAL_POSITION_NED, no GLOBAL_POSITION_INT): h is the local
    frame's height (-z, m) and vn/ve/vd its velocity in m/s (not read as cm/s)."""
    import os
    import struct

    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import ardupilotmega as mav

    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    out = bytearray()
    for i in range(50):
        t = 1.7e9 + 0.1 * i
        for msg in (
            m.attitude_encode(100 * i, 0.0, 0.05, 1.0, 0.0, 0.0, 0.0),
            m.local_position_ned_encode(100 * i, 1.0 * i, 0.0, -30.0 - 0.1 * i, 12.0, -3.0, -1.0),
        ):
            out += struct.pack(">Q", int(t * 1e6)) + msg.pack(m)
    log = tmp_path / "indoor.tlog"
    log.write_bytes(bytes(out))
    fd = read_log(log, segments=[])
    np.testing.assert_allclose(fd["h"].values, 30.0 + 0.1 * np.arange(50), rtol=1e-6)
    np.testing.assert_allclose(fd["vn"].values, 12.0, rtol=1e-6)
    np.testing.assert_allclose(fd["vd"].values, -1.0, rtol=1e-6)
    assert fd["h"].source.startswith("-LOCAL_POSITION_NED.z")


def test_the_verdict_legend_does_not_read_as_a_verdict():
    from pipeline.outputs.run_sections import summary_md

    rows = summary_md({"oem": {"verdict": {"level": "PASS"}, "converged": True, "det_R": 1e-9, "fit": {}}})
    assert any(line.startswith("| oem") and "PASS" in line for line in rows)
    assert not any(line.startswith("Verdict FAIL") for line in rows)
    assert rows[-2].startswith("*What the verdicts mean.*")


SPORTCUB = Path(__file__).resolve().parents[3] / "shared" / "data" / "sportcub"


@pytest.mark.skipif(not (SPORTCUB / "sportcub_mocap_4_17_26_train.npz").is_file(), reason="shared data absent")
def test_an_archives_named_windows_are_maneuvers_with_their_times(tmp_path, capsys):
    """The Sport Cub archive's windows (elev_3211_*, aileron3211_*, rudder_3211_*): each a
    maneuver of the axis its surface moves, printed with its times; the elevator ones make
    the longitudinal axis identifiable."""
    log = SPORTCUB / "sportcub_mocap_4_17_26_train.npz"
    assert main(["check", str(log), "--no-compat", "--out", str(tmp_path / "out")]) in (0, 1)
    out = capsys.readouterr().out
    assert "  window elev_3211_1__elev_001: 0.00-2.49 s, de" in out
    assert "  window aileron3211__ail_001:" in out and "s, da" in out
    assert "longitudinal: identifiable (4 of 4 elevator maneuvers usable)" in out  # throttle window: q answers
    assert "carry no control axis" not in out


JOY = stamped("float32[] axes\nint32[] buttons")


def test_the_documented_joystick_map_reads_a_ros2_joy_topic(tmp_path):
    """docs/channel-maps.md's joystick map, as written there, on a ROS 2 MCAP with a
    sensor_msgs/Joy topic: the sticks become de, da, dr (times the aircraft's travel, the
    documented signs) and throttle."""
    import re

    from mcap_ros2.writer import Writer

    doc = open("docs/channel-maps.md").read()
    block = doc.split("## ROS 2: the pilot's stick")[1]
    (toml,) = re.findall(r"```toml\n(.*?)```", block.split("## ")[0], re.S)
    (tmp_path / "joystick.toml").write_text(toml)
    path = tmp_path / "joy.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        s = w.register_msgdef("sensor_msgs/msg/Joy", JOY)
        for i in range(50):
            ns = i * 20_000_000
            stamp = {"sec": ns // 10**9, "nanosec": ns % 10**9}
            axes = [0.5, 0.5, 1.0 if i >= 25 else -1.0, -0.25]  # rudder, pitch back, throttle, roll left
            w.write_message(
                "/joy", s, {"header": {"stamp": stamp, "frame_id": ""}, "axes": axes, "buttons": []}, ns, ns
            )
        w.finish()
    travel = {"de": (20.0, "test"), "da": (18.0, "test"), "dr": (25.0, "test")}
    fd = read_log(path, map=tmp_path / "joystick.toml", servo_travel=travel, segments=[])
    np.testing.assert_allclose(fd["de"].values, -np.radians(10.0), rtol=1e-6)  # 0.5 x 20 deg, pulled back: up
    np.testing.assert_allclose(fd["da"].values, -np.radians(4.5), rtol=1e-6)
    np.testing.assert_allclose(fd["dr"].values, -np.radians(12.5), rtol=1e-6)
    assert fd["throttle"].values[0] == pytest.approx(0.0) and fd["throttle"].values[-1] == pytest.approx(1.0)


def test_no_control_surface_shares_a_colour_with_a_method():
    from matplotlib.colors import to_rgb

    from pipeline.outputs.figures.style import MEASURED, method_color
    from pipeline.outputs.figures.time_histories import CONTROL_COLOR, CONTROL_STYLES
    from pipeline.registry import METHODS

    taken = {to_rgb(method_color(m, METHODS)) for m in METHODS} | {to_rgb(MEASURED)}
    near = [c for c in taken if max(abs(a - b) for a, b in zip(c, to_rgb(CONTROL_COLOR))) < 0.08]
    assert not near, near
    assert len({dash for dash, _ in CONTROL_STYLES.values()}) == len(CONTROL_STYLES)
