"""Readers on small files written with the real formats' own libraries/layouts."""

from __future__ import annotations

import numpy as np
import pytest
from _ros2 import stamped

from pipeline.errors import FsidError
from pipeline.ingest.readers import LogReadError, detect_format, read_log
from pipeline.ingest.readers.dataflash import message_arrays, read_dataflash, scaled
from pipeline.ingest.readers.synth import (
    demo_dataflash,
    encode_tlog,
    encode_ulog,
    px4_surface_commands,
    write_json_mcap,
)


@pytest.fixture(scope="module")
def binfile(tmp_path_factory):
    p = tmp_path_factory.mktemp("df") / "demo.bin"
    p.write_bytes(demo_dataflash(n=300, seed=3))
    return p


def test_dataflash_matches_dfreader_exactly(binfile):
    from pymavlink import DFReader

    arrays, formats, damage = message_arrays(binfile)
    by_name = {f.name: f for f in formats.values()}
    r = DFReader.DFReader_binary(str(binfile))
    seen: dict[str, int] = {}
    while True:
        m = r.recv_msg()
        if m is None:
            break
        name = m.get_type()
        if name not in arrays or name in ("FMT", "FMTU", "UNIT", "MULT", "PARM"):
            continue
        k = seen.get(name, 0)
        seen[name] = k + 1
        for col in m.get_fieldnames():
            ours = scaled(arrays[name][k : k + 1], by_name[name], col)[0]
            assert ours == getattr(m, col), (name, k, col)
    assert seen["IMU"] == 600 and seen["ATT"] == 300 and damage is None


def test_dataflash_instances_units_modes_and_pwm(binfile):
    fd = read_log(binfile)
    assert fd.meta["tables"]["IMU[0]"] == 300 and fd.meta["tables"]["IMU[1]"] == 300
    raw = read_dataflash(binfile)
    assert raw.tables["IMU[0]"].units["GyrX"] == "rad/s"  # from FMTU + UNIT
    assert raw.tables["ATT"].units["Roll"] == "deg"
    assert [m for _, m in fd.modes] == ["FBWA", "MANUAL"]
    arr = message_arrays(binfile)[0]["RCOU"]
    # SERVO2 (function 19 = elevator): min 1000, trim 1500, max 2000, not reversed, 30 deg
    n = (arr["C2"].astype(float) - 1500) / 500
    assert np.allclose(fd["de"].values, -n * np.radians(30))
    assert np.allclose(fd["phi"].values, np.radians(arr_att(binfile)["Roll"] * 0.01))


def arr_att(p):
    return message_arrays(p)[0]["ATT"]


def test_user_map_overrides_builtin(binfile, tmp_path):
    m = tmp_path / "m.toml"
    m.write_text(
        '[map]\nname = "mine"\nextends = "ardupilot_bin"\n'
        '[channels.p]\nsource = "IMU[1].GyrX"\nunit = "rad/s"\n'
        '[channels.V]\nsource = "ARSP.Airspeed"\nunit = "kt"\n'
    )
    fd = read_log(binfile, map=m)
    arrays = message_arrays(binfile)[0]
    imu = arrays["IMU"]
    assert np.allclose(fd["p"].values, imu["GyrX"][imu["I"] == 1].astype(float))
    assert np.allclose(fd["V"].values, arrays["ARSP"]["Airspeed"].astype(float) * 0.514444)
    assert "q" in fd.channels  # the rest still comes from the built-in map
    bad = tmp_path / "bad.toml"
    bad.write_text('[channels.p]\nsource = "IMU.GyrX"\nunit = "furlong"\n')
    with pytest.raises(FsidError, match="furlong"):
        read_log(binfile, map=bad)
    # a source that applies when the log has a parameter (SERVO2_TRIM is in this log)
    cond = tmp_path / "cond.toml"
    cond.write_text(
        '[map]\nname = "cond"\nextends = "ardupilot_bin"\n'
        '[channels.p]\nsource = "IMU.GyrX"\nunit = "rad/s"\n'
        'source_if = { SERVO2_TRIM = ["IMU[1].GyrX"], NO_SUCH_PARAM = "IMU[2].GyrX" }\n'
    )
    assert np.allclose(read_log(binfile, map=cond)["p"].values, imu["GyrX"][imu["I"] == 1].astype(float))
    bad.write_text('[channels.p]\nsource = "IMU.GyrX"\nsource_if = ["IMU[1].GyrX"]\n')
    with pytest.raises(FsidError, match="source_if must be a table"):
        read_log(binfile, map=bad)


def test_tlog_synthetic(tmp_path):
    p = tmp_path / "x.tlog"
    p.write_bytes(encode_tlog(n=100))
    fd = read_log(p)
    assert len(fd["phi"]) == 100
    assert fd["phi"].values[10] == pytest.approx(0.1 * np.sin(1.0), rel=1e-6)
    assert fd["az"].values[0] == pytest.approx(-1000 * 9.80665e-3)
    assert fd["r"].values[0] == pytest.approx(0.1)
    assert [m for _, m in fd.modes] == ["FBWA", "AUTO"]
    assert fd.params["SERVO2_TRIM"] == 1500.0
    # servo2 = 1500 + (i % 20) * 10 -> de = -(pwm - 1500)/500 * 30 deg
    assert fd["de"].values[5] == pytest.approx(-50 / 500 * np.radians(30))
    assert fd.rates()["phi"] == pytest.approx(20.0, rel=1e-6)


def test_mcap_json_header_vs_log_time(tmp_path):
    p = tmp_path / "f.mcap"
    msgs = [{"t": 100.0 + i * 0.01, "p": 0.01 * i, "q": 0.0, "r": -0.5} for i in range(200)]
    write_json_mcap(p, {"/imu": msgs, "/baro": [{"t": 100.0 + i * 0.1, "h": 50.0} for i in range(20)]})
    fd = read_log(p)
    assert fd.meta["format"] == "mcap" and fd.meta["map"] == "fsid_mcap"
    assert np.allclose(fd["p"].values, 0.01 * np.arange(200))
    # seconds from the log's start; the header stamp of the start kept in meta
    assert fd["p"].t[0] == 0.0 and fd.meta["t0_abs"] == pytest.approx(100.0) and fd["h"].values[0] == 50.0
    fd2 = read_log(p, time_base="log")
    assert "log_time" in fd2.meta["time_base"]


ROS_IMU = stamped(
    """geometry_msgs/Quaternion orientation
float64[9] orientation_covariance
geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance
geometry_msgs/Vector3 linear_acceleration
float64[9] linear_acceleration_covariance""",
    "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w",
    "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z",
)


def test_mcap_ros2_imu_flu_to_frd(tmp_path):
    from mcap_ros2.writer import Writer

    p = tmp_path / "ros.mcap"
    yaw_enu = 0.3
    with open(p, "wb") as fh:
        w = Writer(fh)
        s = w.register_msgdef("sensor_msgs/msg/Imu", ROS_IMU)
        for i in range(30):
            w.write_message(
                topic="/imu/data",
                schema=s,
                log_time=i * 10**7,
                publish_time=i * 10**7,
                message={
                    "header": {"stamp": {"sec": 5, "nanosec": i * 10**7}, "frame_id": "b"},
                    "orientation": {"x": 0.0, "y": 0.0, "z": np.sin(yaw_enu / 2), "w": np.cos(yaw_enu / 2)},
                    "orientation_covariance": [0.0] * 9,
                    "angular_velocity": {"x": 0.1, "y": 0.2, "z": 0.3},
                    "angular_velocity_covariance": [0.0] * 9,
                    "linear_acceleration": {"x": 1.0, "y": 2.0, "z": 9.81},
                    "linear_acceleration_covariance": [0.0] * 9,
                },
            )
        w.finish()
    fd = read_log(p)
    assert fd.meta["map"] == "ros2"
    assert fd["p"].values[0] == pytest.approx(0.1) and fd["q"].values[0] == pytest.approx(-0.2)
    assert fd["r"].values[0] == pytest.approx(-0.3) and fd["az"].values[0] == pytest.approx(-9.81)
    assert fd["psi"].values[0] == pytest.approx(np.pi / 2 - yaw_enu)
    assert fd["p"].t[3] + fd.meta["t0_abs"] == pytest.approx(5.03)
    assert "h" in fd.meta["unmapped"]


def test_mcap_protobuf(tmp_path):
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from mcap_protobuf.writer import Writer

    fdp = descriptor_pb2.FileDescriptorProto(name="rates.proto", package="demo")
    m = fdp.message_type.add(name="Rates")
    for k, n in enumerate(["t", "p", "q", "r"], 1):
        m.field.add(
            name=n,
            number=k,
            type=descriptor_pb2.FieldDescriptorProto.TYPE_DOUBLE,
            label=descriptor_pb2.FieldDescriptorProto.LABEL_OPTIONAL,
        )
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fdp)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName("demo.Rates"))
    p = tmp_path / "pb.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh)
        for i in range(40):
            w.write_message(
                "/rates", cls(t=1.0 + i * 0.02, p=0.5, q=-0.25, r=float(i)), log_time=i * 10**6, publish_time=i * 10**6
            )
        w.finish()
    fd = read_log(p)
    assert len(fd["r"]) == 40 and fd["r"].values[-1] == 39.0 and fd["q"].values[0] == -0.25
    assert fd["p"].t[1] + fd.meta["t0_abs"] == pytest.approx(1.02)


def test_csv_with_column_map(tmp_path):
    p = tmp_path / "d.csv"
    t = np.arange(50) * 0.02
    p.write_text(
        "time_ms;roll_deg;airspeed_kt\n"
        + "\n".join(f"{ti * 1000:.0f};{10 * np.sin(ti):.6f};{30:.1f}" for ti in t)
        + "\n"
    )
    m = tmp_path / "m.toml"
    m.write_text(
        '[map]\nname = "mine"\n[channels.phi]\nsource = "csv.roll_deg"\nunit = "deg"\n'
        '[channels.V]\nsource = "csv.airspeed_kt"\nunit = "kt"\n'
    )
    fd = read_log(p, map=m, time_column="time_ms", time_scale=1e-3)
    assert np.allclose(fd["phi"].t, t)
    assert np.allclose(fd["phi"].values, np.radians(10 * np.sin(t)), atol=1e-7)
    assert fd["V"].values[0] == pytest.approx(30 * 0.514444)


def test_wrong_extension_and_empty(tmp_path):
    p = tmp_path / "really_a_bin.tlog"
    p.write_bytes(demo_dataflash(n=20))
    assert detect_format(p) == "dataflash"
    assert len(read_log(p)["p"]) == 20
    e = tmp_path / "e.ulg"
    e.write_bytes(b"")
    with pytest.raises(LogReadError) as ei:
        read_log(e)
    assert ei.value.offset == 0
    g = tmp_path / "g.bin"
    g.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(LogReadError):
        read_log(g)


def test_resample_antialias_and_segments(binfile):
    from pipeline.ingest.flightdata import Channel, FlightData

    t = np.arange(0, 60, 0.005)  # 200 Hz
    de = np.where((t > 20) & (t < 26), np.radians(5) * np.sign(np.sin(2 * np.pi * (t - 20) / 3)), 0.0)
    hf = np.sin(2 * np.pi * 41 * t)  # 41 Hz: aliases to 1 Hz at a 10 Hz output without the filter
    fd = FlightData(
        {"de": Channel(t, de, "rad"), "q": Channel(t, hf, "rad/s")}, {"modes": [(0.0, "FBWA"), (30.0, "AUTO")]}
    )
    df = fd.resample(10.0, ["q"])
    assert np.nanstd(df["q"]) < 0.01
    assert np.nanstd(fd.resample(10.0, ["q"], antialias=False)["q"]) > 0.5
    segs = fd.find_segments()
    assert len(segs) == 1 and segs[0].axis == "de"
    assert 18.0 <= segs[0].t0 <= 20.5 and 25.5 <= segs[0].t1 <= 29.5
    ms = fd.mode_segments()
    assert [(s.mode, s.t0, s.t1) for s in ms] == [("FBWA", 0.0, 30.0), ("AUTO", 30.0, t[-1])]


def test_continuous_excitation_is_cut_into_pieces():
    """200 s of multisine on aileron and rudder (one span of activity each) give pieces of
    at most 60 s per surface, and the lateral windows (aileron and rudder merged) are cut
    again: 4 to fit and hold out, not one window the pipeline can neither fit nor prove."""
    from pipeline.ingest.flightdata import MAX_AUTO_SEGMENT_S, Channel, FlightData, merge_overlapping

    t = np.arange(0, 220, 0.02)
    on = (t > 10) & (t < 210)
    da = np.where(on, np.radians(2) * np.sin(2 * np.pi * 0.7 * t), 0.0)
    dr = np.where(on, np.radians(2) * np.sin(2 * np.pi * 0.45 * t + 1.0), 0.0)
    fd = FlightData({"da": Channel(t, da, "rad"), "dr": Channel(t, dr, "rad")}, {})
    segs = fd.find_segments()
    for axis in ("da", "dr"):
        mine = [s for s in segs if s.axis == axis]
        assert len(mine) == 4 and [s.name for s in mine] == [f"auto_{axis}_{k}" for k in range(4)]
        assert all(s.t1 - s.t0 <= MAX_AUTO_SEGMENT_S for s in mine)
        assert mine[0].t0 < 10 and mine[-1].t1 > 209  # the whole span covered
        assert all(a.t1 == b.t0 for a, b in zip(mine, mine[1:]))  # without gaps or overlap
    lat = merge_overlapping(segs)
    assert len(lat) == 4 and all(set(s.axis.split("+")) == {"da", "dr"} for s in lat)
    assert all(s.t1 - s.t0 <= MAX_AUTO_SEGMENT_S for s in lat)
    assert all(a.t1 <= b.t0 for a, b in zip(lat, lat[1:]))  # the data once
    assert len({s.name for s in lat}) == 4
    assert len(fd.find_segments(max_duration=None)) == 2  # uncut on request


def test_px4_tlog_dialect(tmp_path):
    from pipeline.ingest.readers.synth import encode_px4_tlog

    p = tmp_path / "px4.tlog"
    p.write_bytes(encode_px4_tlog(n=60))
    fd = read_log(p)
    assert fd.meta["map"] == "px4_tlog" and fd.meta["info"]["autopilot"] == "px4"
    assert fd.params["SYS_AUTOSTART"] == 1234.0  # INT32 decoded bytewise
    assert fd.params["FW_AIRSPD_TRIM"] == 15.0
    assert fd.modes and fd.modes[0][1] == "POSCTL"
    assert fd["az"].values[0] == pytest.approx(-9.81, rel=1e-6)  # HIGHRES_IMU in SI
    assert fd["p"].values[10] == pytest.approx(0.1, rel=1e-6)
    # ACTUATOR_CONTROL_TARGET: pitch -0.2 -> de = +0.2 * 30 deg (nose-up command = TE up)
    assert fd["de"].values[0] == pytest.approx(np.radians(6.0), rel=1e-6)
    assert fd["da"].values[0] == pytest.approx(np.radians(3.0), rel=1e-6)
    assert fd["throttle"].values[0] == pytest.approx(0.6, rel=1e-6)


def test_dataflash_fmtu_unit_conflict_is_reported(binfile, tmp_path):
    from pipeline.conditioning.checks import run_checks

    m = tmp_path / "m.toml"
    m.write_text('[map]\nextends = "ardupilot_bin"\n[channels.phi]\nsource = "ATT.Roll"\nunit = "rad"\n')
    fd = read_log(binfile, map=m)
    assert "FMTU" in fd["phi"].notes and "deg" in fd["phi"].notes
    assert any(f.check == "units" and f.channel == "phi" and "FMTU" in f.message for f in run_checks(fd))
    assert read_log(binfile)["phi"].notes == ""


F64_ARRAY = """std_msgs/MultiArrayLayout layout
float64[] data
================================================================================
MSG: std_msgs/MultiArrayLayout
std_msgs/MultiArrayDimension[] dim
uint32 data_offset
================================================================================
MSG: std_msgs/MultiArrayDimension
string label
uint32 size
uint32 stride
"""


def test_mcap_ros2_std_msgs_array_with_user_map(tmp_path):
    from mcap_ros2.writer import Writer

    p = tmp_path / "arr.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh)
        s = w.register_msgdef("std_msgs/msg/Float64MultiArray", F64_ARRAY)
        for i in range(25):
            w.write_message(
                topic="/surfaces",
                schema=s,
                log_time=10**9 + i * 2 * 10**7,
                publish_time=0,
                message={"layout": {"dim": [], "data_offset": 0}, "data": [0.5 * i, -1.0, 2.0]},
            )
        w.finish()
    m = tmp_path / "m.toml"
    m.write_text(
        '[map]\nname = "surfaces"\nextends = "ros2"\n'
        '[channels.de]\nsource = "/surfaces.data[0]"\nunit = "deg"\n'
        '[channels.da]\nsource = "/surfaces.data[1]"\nunit = "deg"\nsign = -1\n'
    )
    fd = read_log(p, map=m)
    assert fd.meta["time_base"].startswith("MCAP log_time")  # no header: log time, stated
    assert fd["de"].t[1] + fd.meta["t0_abs"] == pytest.approx(1.02)
    assert np.allclose(fd["de"].values, np.radians(0.5 * np.arange(25)))
    assert np.allclose(fd["da"].values, np.radians(1.0))
    assert set(fd.missing(["p", "phi"])) == {"p", "phi"}
    assert "no @sensor_msgs/msg/Imu" in fd.explain_missing(["p"])["p"]


@pytest.mark.parametrize("allocation", ["conventional", "elevons"])
def test_px4_control_allocation_surfaces(tmp_path, allocation):
    """PX4 1.14+ logs the allocated surface commands (actuator_servos) instead of
    actuator_controls_0: each of da, de, dr is the surfaces' commands weighted by their
    CA_SV_CS*_TRQ_R/P/Y over the coefficients' magnitudes, i.e. the roll, pitch and yaw
    commands the allocation served (here 0.1, -0.2 sin(i/5), 0.3 cos(i/7)) times the
    travel (30 deg assumed). A flying wing's elevons have no yaw torque: no dr, and why."""
    p = tmp_path / f"{allocation}.ulg"
    p.write_bytes(encode_ulog(n=60, allocation=allocation))
    fd = read_log(p)
    cmd = np.array([px4_surface_commands(i) for i in range(60)])
    travel = np.radians(30.0)
    np.testing.assert_allclose(fd["da"].values, cmd[:, 0] * travel, atol=1e-6)
    np.testing.assert_allclose(fd["de"].values, -cmd[:, 1] * travel, atol=1e-6)
    assert fd["da"].source == "actuator_servos by CA_SV_CS*_TRQ_R: -0.5 x control[0] +0.5 x control[1]"
    if allocation == "conventional":
        np.testing.assert_allclose(fd["dr"].values, -cmd[:, 2] * travel, atol=1e-6)
        assert fd["de"].source.endswith("+1 x control[2]")
    else:
        assert "dr" not in fd
        assert "CA_SV_CS*_TRQ_Y all 0" in fd.meta["unmapped"]["dr"]
        assert fd["de"].source.endswith("+0.5 x control[0] +0.5 x control[1]")
    assert fd.meta["servo_travel"]["de"] == {"deg": 30.0, "from": "assumed"}
    np.testing.assert_allclose(fd["throttle"].values, 0.5)  # actuator_motors
    assert fd["throttle"].source == "actuator_motors.control[0]"
