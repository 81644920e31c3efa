"""The ragged .npz archive reader: windows as segments kept apart, the pose under its
canonical names, normalised commands through the servo travel, no provider states."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.ingest.rawlog import LogReadError
from pipeline.ingest.readers import detect_format, read_log, read_raw
from pipeline.ingest.readers.npz import WINDOW_GAP_S

SPORTCUB = Path(__file__).resolve().parents[3] / "shared" / "data" / "sportcub"
TRAIN = SPORTCUB / "sportcub_mocap_4_17_26_train.npz"
TRAVEL = {"de": (23.0, "test"), "da": (25.0, "test"), "dr": (30.0, "test")}


def _archive(path: Path, enu: bool = False, **extra) -> Path:
    """Two windows (30 and 20 samples at 100 Hz) of level flight north at 4 m/s, heading 30
    deg, with a step on the aileron command; positions in NED or ENU."""
    n, w = 30, 2
    t = np.tile(np.arange(n) * 0.01, (w, 1))
    valid = np.ones((w, n), bool)
    valid[1, 20:] = False
    psi = np.radians(30.0)
    pos = np.zeros((w, n, 3))
    pos[..., 0] = 4.0 * t
    quat = np.broadcast_to([np.cos(psi / 2), 0.0, 0.0, np.sin(psi / 2)], (w, n, 4))
    u = np.zeros((w, n, 4))
    u[..., 0] = 0.5
    u[:, 10:, 2] = 0.4
    doc = dict(time_s=t, valid_mask=valid, u_cmd=u, input_names=np.array(["throttle", "elevator", "aileron", "rudder"]))
    doc["segment_names"] = np.array(["first", "second"])
    doc["format_version"] = np.array("sysid.timeseries.ragged.v1")
    doc["x_meas"] = np.full((w, n, 13), 99.0)  # the provider's states: never read
    if enu:  # ENU position, quaternion body -> ENU of the same attitude
        enu_pos = np.stack([pos[..., 1], pos[..., 0], -pos[..., 2]], axis=-1)
        ned_to_enu = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
        r = Rotation.from_matrix(ned_to_enu @ Rotation.from_quat(quat[..., [1, 2, 3, 0]].reshape(-1, 4)).as_matrix())
        q_enu = r.as_quat()[:, [3, 0, 1, 2]].reshape(w, n, 4)
        doc["pose_meas"] = np.concatenate([enu_pos, q_enu], axis=-1)
        doc["pose_names"] = np.array(["x_e", "y_n", "z_u", "q_w", "q_x", "q_y", "q_z"])
    else:
        doc["mocap_meas"] = np.concatenate([pos, quat], axis=-1)
        doc["mocap_names"] = np.array(["x_n", "y_e", "z_d", "q_w", "q_x", "q_y", "q_z"])
    doc.update(extra)
    f = path / "flight.npz"
    np.savez(f, **doc)
    return f


def test_windows_become_segments_kept_apart(tmp_path):
    f = _archive(tmp_path)
    assert detect_format(f) == "npz"
    fd = read_log(f, servo_travel=TRAVEL, pose=False)
    assert [s.name for s in fd.segments] == ["first", "second"]
    # named windows are given windows: their axis the input moved (the aileron step)
    assert [(s.kind, s.axis) for s in fd.segments] == [("time", "da"), ("time", "da")]
    a, b = fd.segments
    assert a.t0 == 0.0 and a.t1 == pytest.approx(0.29)
    assert b.t0 == pytest.approx(0.29 + WINDOW_GAP_S) and b.duration == pytest.approx(0.19)
    assert len(fd["x_n"]) == 50  # the padding is not read
    np.testing.assert_allclose(fd["q_z"].values, np.sin(np.radians(15.0)))
    # normalised command x the travel: 0.4 x 25 deg
    assert fd["da"].values.max() == pytest.approx(np.radians(10.0))
    assert fd["throttle"].values[0] == 0.5
    assert "u" not in fd  # x_meas is the provider's derivation, not a measurement


def test_pose_states_derived_from_the_pose(tmp_path):
    fd = read_log(_archive(tmp_path), servo_travel=TRAVEL)
    assert np.nanmax(np.abs(fd["V"].values - 4.0)) < 1e-6
    # flying north with the nose 30 deg right: beta = -30 deg of the air velocity
    assert np.nanmedian(fd["beta"].values) == pytest.approx(np.radians(-30.0), abs=1e-6)
    assert np.nanmedian(fd["psi"].values) == pytest.approx(np.radians(30.0), abs=1e-6)


def test_enu_pose_turned_to_ned(tmp_path):
    raw = read_raw(_archive(tmp_path, enu=True))
    tab = raw.tables["npz"]
    np.testing.assert_allclose(tab["x_n"][:30], 4.0 * np.arange(30) * 0.01, atol=1e-12)
    q = np.stack([tab[k] for k in ("q_w", "q_x", "q_y", "q_z")], axis=-1)
    q *= np.sign(q[:, :1])
    np.testing.assert_allclose(q[0], [np.cos(np.radians(15)), 0, 0, np.sin(np.radians(15))], atol=1e-12)


def test_bad_archives_say_what(tmp_path):
    with pytest.raises(LogReadError, match="format_version"):
        read_log(_archive(tmp_path, format_version=np.array("other.v2")))
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"PK\x03\x04 not a zip at all")
    with pytest.raises(LogReadError, match="not a readable .npz"):
        read_log(bad)


@pytest.mark.skipif(not TRAIN.is_file(), reason="shared Sport Cub data absent")
def test_sportcub_train_archive():
    fd = read_log(TRAIN, servo_travel=TRAVEL)
    data = np.load(TRAIN)
    names = [str(s) for s in data["segment_names"]]
    assert [s.name for s in fd.segments] == names
    n = data["valid_mask"].sum(axis=1)
    assert [round(s.duration * 100) + 1 for s in fd.segments] == list(n)
    gaps = [b.t0 - a.t1 for a, b in zip(fd.segments, fd.segments[1:])]
    assert min(gaps) == pytest.approx(WINDOW_GAP_S)
    k = names.index("aileron3211__ail_001")
    s = fd.segments[k]
    inside = (fd["da"].t >= s.t0) & (fd["da"].t <= s.t1)
    np.testing.assert_allclose(fd["da"].values[inside], data["u_cmd"][k, : n[k], 2] * np.radians(25.0))
    np.testing.assert_allclose(fd["z_d"].values[inside], data["mocap_meas"][k, : n[k], 2])
    assert fd.meta["pose"]["pieces"] and len(fd.meta["pose"]["pieces"]) == len(names)
