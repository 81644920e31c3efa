"""Ragged time-series archives (``sysid.timeseries.ragged.v1`` .npz): windows of a pose
(motion capture) and the pilot's commands.

Such an archive holds W windows padded to the longest, ``valid_mask`` (W, N) marking the
real samples, ``time_s`` (W, N) and per window:

- the pose, ``mocap_meas`` (W, N, 7) named by ``mocap_names`` = x_n y_e z_d q_w q_x q_y q_z
  (local NED position [m], attitude quaternion body -> NED); or, without it, ``pose_meas``
  named ``x_e y_n z_u q_w q_x q_y q_z`` (ENU position, quaternion body -> ENU), turned to
  NED here (the body axes taken as x forward, y right, z down in both);
- the commands, ``u_cmd`` (W, N, m) named by ``input_names`` (throttle and normalised
  -1..1 surface commands, e.g. elevator, aileron, rudder);
- ``segment_names`` (W,): what each window is.

The reader returns the raw table ``npz``: the pose under its canonical names and the
commands under their own; the built-in map ``sysid_npz`` turns the commands into throttle
and de, da, dr through the servo travel (``read_log(servo_travel=...)``, an aircraft
file's ``[servos]``). Windows are not one flight: each keeps its own time, laid end to end
with ``WINDOW_GAP_S`` of no data between them so nothing differentiates or interpolates
across two windows, and becomes one segment named by its ``segment_names`` entry
(``RawLog.info["windows"]``: name, t0, t1 [s] on the log's time, and the time the window
had in the archive at its first sample).

Derived states an archive may carry (``x_meas``, ``y_meas``, ``direct_state_meas``,
``euler_meas``) are the provider's own computation from the same pose, not measurements:
the reader leaves them out and the ingest derives its own
(:func:`pipeline.ingest.pose.derive_pose_states`).
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from pipeline.ingest.rawlog import LogReadError, RawLog, Table

#: the archive format this reader knows (its ``format_version``)
FORMAT_VERSION = "sysid.timeseries.ragged.v1"
#: the pose channels, in the order of ``mocap_meas`` (DESIGN.md section 3)
POSE_NAMES = ("x_n", "y_e", "z_d", "q_w", "q_x", "q_y", "q_z")
#: the ENU pose's names (``pose_meas``)
ENU_NAMES = ("x_e", "y_n", "z_u", "q_w", "q_x", "q_y", "q_z")
#: time with no samples laid between two windows [s]: far longer than any sample interval
WINDOW_GAP_S = 1.0
#: quaternion of the ENU -> NED axes change (180 deg about (1, 1, 0) / sqrt 2), w x y z
_ENU_TO_NED = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])


def _fail(path: Path, msg: str, where: str = "archive") -> LogReadError:
    return LogReadError(f"{path}: {msg}", path=str(path), where=where)


def _names(data, key: str, path: Path) -> list[str]:
    if key not in data:
        raise _fail(path, f"has no '{key}' (the names of its columns); is it a {FORMAT_VERSION} archive?", key)
    return [str(s) for s in np.atleast_1d(data[key])]


def _array(data, key: str, path: Path, shape: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(data[key], dtype=float)
    if a.shape[: len(shape)] != shape:
        raise _fail(path, f"'{key}' has shape {a.shape}; the windows need {shape} first", key)
    return a


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a (x) b of quaternions (w, x, y, z) along the last axis."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def _ned_pose(data, path: Path, shape: tuple[int, int]) -> tuple[np.ndarray, str]:
    """(W, N, 7) pose x_n y_e z_d q_w q_x q_y q_z and which array it came from."""
    if "mocap_meas" in data:
        names = _names(data, "mocap_names", path)
        missing = [n for n in POSE_NAMES if n not in names]
        if missing:
            raise _fail(path, f"mocap_names lacks {missing}; expected {list(POSE_NAMES)}", "mocap_names")
        a = _array(data, "mocap_meas", path, shape)
        return a[..., [names.index(n) for n in POSE_NAMES]], "mocap_meas"
    if "pose_meas" in data:
        names = _names(data, "pose_names", path)
        missing = [n for n in ENU_NAMES if n not in names]
        if missing:
            raise _fail(path, f"pose_names lacks {missing}; expected {list(ENU_NAMES)}", "pose_names")
        a = _array(data, "pose_meas", path, shape)[..., [names.index(n) for n in ENU_NAMES]]
        out = np.empty_like(a)
        out[..., 0], out[..., 1], out[..., 2] = a[..., 1], a[..., 0], -a[..., 2]
        out[..., 3:] = _quat_mul(_ENU_TO_NED, a[..., 3:])
        return out, "pose_meas (ENU, turned to NED)"
    raise _fail(path, "has no pose (mocap_meas or pose_meas); this reader needs one", "keys")


def read_npz(path: str | os.PathLike, *, strict: bool = False) -> RawLog:
    """Read a ragged archive into the table ``npz`` (see the module docstring).

    ``strict`` is accepted for the readers' common signature: an archive is read whole or
    not at all.
    """
    path = Path(path)
    try:
        data = np.load(path, allow_pickle=False)
    except OSError as exc:
        raise LogReadError.cannot_open(path, exc) from None
    except (ValueError, zipfile.BadZipFile) as exc:
        raise _fail(path, f"not a readable .npz archive ({exc})", "byte 0") from None
    with data:
        version = str(data["format_version"]) if "format_version" in data else ""
        if version and version != FORMAT_VERSION:
            raise _fail(path, f"format_version is {version!r}; this reader knows {FORMAT_VERSION!r}", "format_version")
        for key in ("time_s", "valid_mask"):
            if key not in data:
                raise _fail(path, f"has no '{key}'; a {FORMAT_VERSION} archive needs time_s and valid_mask", key)
        time = np.asarray(data["time_s"], dtype=float)
        valid = np.asarray(data["valid_mask"], dtype=bool)
        if time.ndim != 2 or valid.shape != time.shape:
            raise _fail(path, f"time_s {time.shape} and valid_mask {valid.shape} must both be (windows, samples)")
        shape = time.shape
        pose, pose_from = _ned_pose(data, path, shape)
        inputs = _names(data, "input_names", path) if "u_cmd" in data else []
        u = _array(data, "u_cmd", path, shape) if inputs else np.zeros(shape + (0,))
        names = [str(s) for s in data["segment_names"]] if "segment_names" in data else []
    if len(names) != shape[0]:
        names = [f"window_{k}" for k in range(shape[0])]
    ts, cols, windows = [], [], []
    start = 0.0
    for k in range(shape[0]):
        ok = valid[k] & np.isfinite(time[k]) & np.all(np.isfinite(pose[k]), axis=-1)
        if ok.sum() < 2:
            continue
        tk = time[k, ok]
        if np.any(np.diff(tk) <= 0):
            raise _fail(path, f"window {k} ({names[k]}): time_s is not increasing", f"time_s[{k}]")
        t = np.round(tk - tk[0], 9) + start
        windows.append({"name": names[k], "t0": float(t[0]), "t1": float(t[-1]), "archive_t0": float(tk[0])})
        ts.append(t)
        cols.append(np.concatenate([pose[k, ok], u[k, ok]], axis=1))
        start = round(float(t[-1]) + WINDOW_GAP_S, 6)  # whole microseconds: no drift over windows
    if not ts:
        raise _fail(path, "no window has two valid samples", "valid_mask")
    t = np.concatenate(ts)
    arr = np.concatenate(cols)
    columns = {n: arr[:, j] for j, n in enumerate(list(POSE_NAMES) + inputs)}
    units = {**{n: "m" for n in POSE_NAMES[:3]}, **{n: "-" for n in POSE_NAMES[3:] + tuple(inputs)}}
    return RawLog(
        {"npz": Table("npz", t, columns, units)},
        "npz",
        {},
        [],
        f"each window's own time_s from its first valid sample, windows laid end to end {WINDOW_GAP_S:g} s apart",
        None,
        {"map_hint": "sysid_npz", "windows": windows, "pose_from": pose_from, "inputs": inputs},
    )
