"""Pose-only (motion-capture) data: flight states derived from position and quaternion
(pipeline.ingest.pose), the kinematic-consistency checks that find a mirrored roll
(pipeline.conditioning.kinematics), and a ROS 2 pose MCAP read end to end.

The pose is built from a simulated flight's truth (lateral_doublets_calm: aileron and
cross-controlled rudder manoeuvres, banks of 10-25 deg): NED position integrated from the
truth's velocity, the quaternion from its Euler angles, with motion-capture noise of 1 mm
and 0.1 deg per axis, sampled at the truth's 100 Hz."""

from __future__ import annotations

import functools

import numpy as np
import pandas as pd
import pytest
from _ros2 import stamped
from _simdata import flown
from scipy.integrate import cumulative_trapezoid

from pipeline.conditioning.checks import FAIL, PASS, run_checks
from pipeline.conditioning.kinematics import check_kinematics
from pipeline.errors import FsidError
from pipeline.ingest.flightdata import Channel, FlightData
from pipeline.ingest.pose import POSE, derive_pose_states, euler_to_quat, pose_part, quat_to_euler
from pipeline.ingest.readers import read_log

NOISE_M, NOISE_DEG = 1e-3, 0.1
COMPARED = ("vn", "ve", "vd", "phi", "theta", "psi", "p", "q", "r", "ax", "ay", "az", "V", "alpha", "beta")


@functools.cache
def _truth(scenario: str = "lateral_doublets_calm"):
    return flown(scenario).truth


def _pose(
    roll_sign: float = 1.0, seed: int = 0, scenario: str = "lateral_doublets_calm", pitch_sign: float = 1.0, **channels
) -> FlightData:
    """A scenario's truth as a noisy pose; ``roll_sign`` / ``pitch_sign`` -1 mirror the roll /
    the pitch; extra logged channels by name."""
    tr = _truth(scenario)
    t = tr["t"].to_numpy()
    rng = np.random.default_rng(seed)
    pos = np.column_stack([cumulative_trapezoid(tr[c].to_numpy(), t, initial=0.0) for c in ("vn", "ve", "vd")])
    pos += NOISE_M * rng.standard_normal(pos.shape)
    ang = [tr[c].to_numpy() + np.radians(NOISE_DEG) * rng.standard_normal(t.size) for c in ("phi", "theta", "psi")]
    quat = euler_to_quat(roll_sign * ang[0], pitch_sign * ang[1], ang[2])
    chans = {n: Channel(t, v, "") for n, v in zip(POSE, [*pos.T, *quat.T])}
    chans |= {k: Channel(t, v, "") for k, v in channels.items()}
    return FlightData(chans, {}, [])


def _errors(fd: FlightData, name: str, scenario: str = "lateral_doublets_calm") -> np.ndarray:
    tr = _truth(scenario)
    ch = fd[name]
    e = ch.values - np.interp(ch.t, tr["t"].to_numpy(), tr[name].to_numpy())
    return np.angle(np.exp(1j * e)) if name == "psi" else e


def test_derived_states_match_truth_within_stated_noise():
    fd = derive_pose_states(_pose())
    pose = fd.meta["pose"]
    assert pose["window_samples"] == 21 and pose["polyorder"] == 3
    # the smoother's residual measures the camera noise that was put in
    assert np.allclose(pose["noise_position_m"], NOISE_M, rtol=0.1)
    assert 2 * pose["noise_quaternion"] == pytest.approx(np.radians(NOISE_DEG), rel=0.1)
    for name in COMPARED:
        ch = fd[name]
        e = _errors(fd, name)
        rms = float(np.sqrt(np.mean(e**2)))
        assert pose_part(ch) is not None and "Savitzky-Golay, 21 samples = 0.2 s" in ch.derived
        assert rms <= 1.3 * ch.noise, (name, rms, ch.noise)  # stated noise is honest ...
        assert rms >= 0.7 * ch.noise, (name, rms, ch.noise)  # ... and not inflated
        assert abs(float(np.mean(e))) <= 0.25 * ch.noise, name
        assert fd.noise_std(name) == ch.noise
    # logged channels win over derived ones
    tr = _truth()
    logged = derive_pose_states(_pose(p=tr["p"].to_numpy()))
    assert logged["p"].noise is None and np.array_equal(logged["p"].values, tr["p"].to_numpy())


def test_air_data_with_a_given_wind():
    """pitot_wind_turn flies in a steady wind of (3, -4, 0) m/s (NED): given it, V alpha
    beta match the air-relative truth; in still air V is off by metres per second."""
    fd = _pose(scenario="pitot_wind_turn")
    windy = derive_pose_states(fd, wind_ned=(3.0, -4.0, 0.0))
    assert "the wind (3.0, -4.0, 0.0) m/s (NED) removed" in windy["V"].derived
    for name in ("V", "alpha", "beta", "u", "v", "w"):
        e = _errors(windy, name, "pitot_wind_turn")
        assert np.sqrt(np.mean(e**2)) <= 1.3 * windy[name].noise, name
    still = _errors(derive_pose_states(fd), "V", "pitot_wind_turn")
    assert np.sqrt(np.mean(still**2)) > 2.0


def test_gaps_and_quaternion_sign_flips():
    fd0 = _pose()
    t = fd0["q_w"].t
    keep = (t < 20.0) | (t > 21.0)  # a 1 s gap during quiet flight
    flip = np.where((t > 30.0) & (t < 40.0), -1.0, 1.0)  # q and -q: one attitude
    chans = {
        n: Channel(t[keep], (c.values * (flip if n.startswith("q_") else 1.0))[keep], "")
        for n, c in fd0.channels.items()
    }
    fd = derive_pose_states(FlightData(chans, {}, []))
    assert len(fd.meta["pose"]["pieces"]) == 2
    ts = fd["p"].t
    assert not np.any((ts > 20.0 + 1e-9) & (ts < 21.0 - 1e-9))  # nothing across the gap
    for name in ("p", "q", "r", "phi", "vn", "ay"):
        e = _errors(fd, name)
        assert np.sqrt(np.mean(e**2)) <= 1.3 * fd[name].noise, name
        assert np.max(np.abs(e)) <= 10 * fd[name].noise, name  # no spike at a sign flip or gap edge


def _kinematic(findings, check):
    return [f for f in findings if f.check == check]


def test_consistent_pose_passes_the_kinematic_checks():
    findings = run_checks(derive_pose_states(_pose()))
    turn, lift = _kinematic(findings, "coordinated_turn"), _kinematic(findings, "lift_bank")
    assert [f.status for f in turn + lift] == [PASS, PASS]
    assert turn[0].value > 0.7 and lift[0].value > 0.7
    assert not [f for f in findings if f.status == FAIL]


def test_mirrored_roll_is_flagged_with_its_channel_and_mended():
    findings = run_checks(derive_pose_states(_pose(roll_sign=-1.0)))
    bad = [f for f in findings if f.status == FAIL]
    assert {f.check for f in bad} == {"coordinated_turn", "lift_bank"}
    for f in bad:
        assert f.channel == "phi" and f.value < -0.7
        assert "q_w q_x q_y q_z" in f.message and "roll_sign" in f.message
    assert _kinematic(findings, "heading_course")[0].status == PASS  # the heading is right: roll alone
    mended = check_kinematics(derive_pose_states(_pose(roll_sign=-1.0), roll_sign=-1))
    assert not [f for f in mended if f.status == FAIL]


def test_the_roll_is_mended_in_a_channel_map(tmp_path):
    """The mend the finding names, as a user makes it: a map extending the log's own."""
    fd = _pose(roll_sign=-1.0)
    pd.DataFrame({"t": fd["q_w"].t} | {n: fd[n].values for n in POSE}).to_csv(tmp_path / "mocap.csv", index=False)
    bad = [f.check for f in check_kinematics(read_log(tmp_path / "mocap.csv")) if f.status == FAIL]
    assert bad == ["coordinated_turn", "lift_bank"]
    user = tmp_path / "mended.toml"
    user.write_text('[map]\nextends = "canonical_csv"\npose = { roll_sign = -1 }\n')
    mended = read_log(tmp_path / "mocap.csv", map=user)
    assert mended.meta["pose"]["roll_sign"] == -1
    assert not [f for f in check_kinematics(mended) if f.status == FAIL]
    user.write_text('[map]\nextends = "canonical_csv"\npose = { roll = -1 }\n')
    with pytest.raises(FsidError, match=r"channel map canonical_csv\+mended: \[map\] pose must be a table"):
        read_log(tmp_path / "mocap.csv", map=user)


def test_mirrored_pitch_is_flagged_in_pitching_flight():
    """longitudinal_3211_calm: elevator 3-2-1-1s move theta and the flight-path angle together."""
    ok = check_kinematics(derive_pose_states(_pose(scenario="longitudinal_3211_calm")))
    assert [(f.status, f.value > 0.9) for f in _kinematic(ok, "pitch_path")] == [(PASS, True)]
    bad = check_kinematics(derive_pose_states(_pose(scenario="longitudinal_3211_calm", pitch_sign=-1.0)))
    pitch = _kinematic(bad, "pitch_path")
    assert len(pitch) == 1 and pitch[0].status == FAIL and pitch[0].value < -0.9
    assert pitch[0].channel == "theta,z_d" and "z_d" in pitch[0].message


def test_mirrored_gyro_and_accelerometer_axes_are_named():
    tr = _truth()
    fd = derive_pose_states(_pose(p=-tr["p"].to_numpy(), q=tr["q"].to_numpy(), ay=-tr["ay"].to_numpy()))
    findings = check_kinematics(fd)
    rates = {f.channel: f.status for f in _kinematic(findings, "rates_attitude")}
    assert rates == {"p": FAIL, "q": PASS} or rates == {"p": FAIL}
    accel = {f.channel: f.status for f in _kinematic(findings, "accel_track")}
    assert accel == {"ay": FAIL}
    assert _kinematic(findings, "coordinated_turn")[0].status == PASS


POSE_STAMPED = stamped(
    "geometry_msgs/Pose pose",
    "MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z",
    "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1",
)

RC_IN = stamped("uint8 rssi\nuint16[] channels")


def test_ros2_pose_and_rc_mcap_becomes_flight_states(tmp_path):
    """A motion-capture MCAP with only PoseStamped (REP 103: world ENU, body FLU) and RC
    input: read into the full set of flight states, not one altitude channel."""
    from mcap_ros2.writer import Writer

    fd0 = _pose()
    t = fd0["x_n"].t
    span = (t >= 2.0) & (t < 16.0)  # lead-in and the first aileron doublet's turn
    tr = _truth()
    x_n, y_e, z_d = (fd0[c].values[span] for c in ("x_n", "y_e", "z_d"))
    phi, theta, psi = quat_to_euler(np.column_stack([fd0[c].values[span] for c in ("q_w", "q_x", "q_y", "q_z")]))
    q_flu = euler_to_quat(phi, -theta, np.pi / 2 - psi)  # ROS roll, pitch, yaw (ENU, FLU)
    path = tmp_path / "mocap.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        s_pose = w.register_msgdef("geometry_msgs/msg/PoseStamped", POSE_STAMPED)
        s_rc = w.register_msgdef("mavros_msgs/msg/RCIn", RC_IN)
        for k, tk in enumerate(t[span]):
            ns = int(round(tk * 1e9))
            stamp = {"sec": ns // 10**9, "nanosec": ns % 10**9}
            qw, qx, qy, qz = q_flu[k]
            pose = {
                "position": {"x": y_e[k], "y": x_n[k], "z": -z_d[k]},
                "orientation": {"x": qx, "y": qy, "z": qz, "w": qw},
            }
            w.write_message(
                "/mocap/pose", s_pose, {"header": {"stamp": stamp, "frame_id": "world"}, "pose": pose}, ns, ns
            )
            if k % 2 == 0:
                rc = {"header": {"stamp": stamp, "frame_id": ""}, "rssi": 255, "channels": [1500, 1500, 1100, 1500]}
                w.write_message("/rc/in", s_rc, rc, ns, ns)
        w.finish()
    fd = read_log(path)
    assert fd.meta["map"] == "ros2"
    assert not fd.missing(("x_n", "q_w", "vn", "p", "q", "r", "phi", "theta", "psi", "ax", "az", "V", "alpha", "beta"))
    assert fd["h"].values[0] == pytest.approx(-z_d[0])  # the pose's altitude, as before
    t_abs = fd["phi"].t + fd.meta.get("t0_abs", 0.0)
    for name in ("phi", "theta", "psi", "p", "r"):
        truth = np.interp(t_abs, tr["t"].to_numpy(), tr[name].to_numpy())
        e = np.angle(np.exp(1j * (fd[name].values - truth)))
        assert np.sqrt(np.mean(e**2)) <= 1.3 * fd[name].noise, name
    assert fd["V"].values.mean() == pytest.approx(tr["V"].to_numpy()[span].mean(), abs=0.05)
    turn = _kinematic(run_checks(fd), "coordinated_turn")
    assert turn and turn[0].status == PASS


def test_a_pose_that_cannot_be_differentiated():
    t = np.arange(4) * 0.01
    short = FlightData({n: Channel(t, np.full(4, 1.0 if n == "q_w" else 0.0), "") for n in POSE}, {}, [])
    with pytest.raises(FsidError, match="needs at least 5"):
        derive_pose_states(short)
    kept = derive_pose_states(short, strict=False)  # what the ingest does: the rest of the log stays
    assert kept.names == short.names and "needs at least 5" in kept.meta["unmapped"]["p"]
    t = np.arange(40) * 0.01
    bad_q = FlightData({n: Channel(t, np.full(40, 3.0), "") for n in POSE}, {}, [])
    with pytest.raises(FsidError, match=r"unit quaternion \(median \|q\| 6\)"):
        derive_pose_states(bad_q)
