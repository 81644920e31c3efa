"""Log readers: any supported log file -> :class:`pipeline.ingest.flightdata.FlightData`.

``read_log(path, map=None, **opts)`` detects the format from the file's first bytes (the
extension only breaks ties), reads it into raw tables with the format reader, converts
them to canonical SI channels through a channel map (:mod:`pipeline.ingest.maps`) and attaches
metadata (params, modes, time base, damage) and segments.

Formats: MCAP (.mcap: JSON, ROS 2 CDR, protobuf), ArduPilot DataFlash (.bin), MAVLink
telemetry (.tlog), PX4 ULog (.ulg), CSV/ASCII columns (.csv, .txt), ragged time-series
archives (.npz, :mod:`pipeline.ingest.readers.npz`).

The only exception a reader raises for a bad file is :class:`LogReadError` (a
:class:`pipeline.errors.FsidError`) with ``.offset``/``.where``. Damage after some valid
data is not an error: the data before it is kept and ``FlightData.meta['damage']`` says
where reading stopped (pass ``strict=True`` to raise instead).
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline.errors import FsidError
from pipeline.ingest.flightdata import FlightData, SegmentSpec
from pipeline.ingest.maps import apply_map, builtin_names, load_map
from pipeline.ingest.maps.rules import finite_number
from pipeline.ingest.pose import derive_pose_states, map_pose_options, needs_pose_states
from pipeline.ingest.rawlog import TIME_BASES, Damage, LogReadError, RawLog, Table
from pipeline.ingest.readers.csvlog import read_csv
from pipeline.ingest.readers.dataflash import read_dataflash
from pipeline.ingest.readers.mcap import read_mcap
from pipeline.ingest.readers.npz import read_npz
from pipeline.ingest.readers.tlog import read_tlog
from pipeline.ingest.readers.ulog import read_ulog

__all__ = ["read_log", "read_raw", "detect_format", "LogReadError", "RawLog", "Table", "Damage"]

EXTENSIONS = {
    ".mcap": "mcap",
    ".bin": "dataflash",
    ".tlog": "tlog",
    ".ulg": "ulog",
    ".csv": "csv",
    ".txt": "csv",
    ".dat": "csv",
    ".npz": "npz",
}
#: format -> its reader (path, **opts) -> RawLog
READERS = {
    "dataflash": read_dataflash,
    "tlog": read_tlog,
    "ulog": read_ulog,
    "mcap": read_mcap,
    "csv": read_csv,
    "npz": read_npz,
}


#: files fsid reads that are not logs: given as the log, they are refused by name
NOT_LOGS = {
    ".toml": "TOML file (an aircraft, scenario or channel-map file?)",
    ".json": "JSON file (a truth.json or a report?)",
    ".py": "Python file (a model file? give it with --model FILE.py:NAME)",
    ".md": "Markdown file",
    ".html": "HTML file",
    ".rrd": "rerun recording (open it with fsid view)",
}


def detect_format(path: str | os.PathLike) -> str:
    """ "mcap" | "dataflash" | "tlog" | "ulog" | "csv" from the content (then the extension)."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError as exc:
        raise LogReadError(
            f"cannot open {path}: {exc.strerror}; check the path", path=str(path), offset=None, where="open"
        ) from None
    if not head:
        raise LogReadError(
            f"{path} is empty (0 bytes); nothing to read — check the copy/download",
            path=str(path),
            offset=0,
            where="byte 0",
        )
    if head.startswith(b"\x89MCAP"):
        return "mcap"
    if head.startswith(b"ULog"):
        return "ulog"
    if head.startswith(b"PK\x03\x04") and path.suffix.lower() == ".npz":
        return "npz"
    if head[:3] == b"\xa3\x95\x80":
        return "dataflash"
    if len(head) > 8 and head[8] in (0xFE, 0xFD):
        return "tlog"
    if path.suffix.lower() in NOT_LOGS:
        raise LogReadError(
            f"{path} is a {NOT_LOGS[path.suffix.lower()]}, not a flight log: give the log "
            "(.mcap, .bin, .tlog, .ulg, .csv or .npz) as the first argument",
            path=str(path),
            offset=0,
            where="file name",
        )
    ext = EXTENSIONS.get(path.suffix.lower())
    if ext == "csv" or (ext is None and _looks_text(head)):
        return "csv"
    if ext is not None:
        return ext
    raise LogReadError(
        f"{path}: unknown log format (first bytes {head[:8].hex()}); supported: .mcap .bin .tlog .ulg .csv",
        path=str(path),
        offset=0,
        where="byte 0",
    )


def _looks_text(head: bytes) -> bool:
    try:
        head.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return b"," in head or b"\t" in head or b" " in head


def read_raw(path: str | os.PathLike, fmt: str | None = None, **opts) -> RawLog:
    """Read a log into raw (unmapped) tables. ``opts`` go to the format reader."""
    fmt = fmt or detect_format(path)
    reader = READERS.get(fmt)
    if reader is None:
        raise LogReadError(f"{path}: no reader for format '{fmt}'", path=str(path), where="dispatch")
    try:
        return reader(path, **opts)
    except LogReadError:
        raise
    except MemoryError:
        raise LogReadError(
            f"{path}: out of memory while reading ({fmt}); the file header probably claims absurd sizes",
            path=str(path),
            where="reading",
        ) from None
    except Exception as exc:  # safety net: a damaged file must end in the documented error
        err = LogReadError(
            f"{path}: the {fmt} reader could not decode this file "
            f"({type(exc).__name__}: {exc}); it is probably damaged — please "
            "report it if it opens elsewhere",
            path=str(path),
            where="decoding",
        )
        err.internal = True
        raise err from exc


def _csv_time(cmap) -> dict:
    """The CSV reader's time options from a user map's ``[map] time_column`` and
    ``time_scale`` (the unit of the time column in seconds, e.g. 0.001 for ms)."""
    head, out = cmap.header, {}
    if "time_column" in head:
        out["time_column"] = str(head["time_column"])
    if "time_scale" in head:
        v = finite_number(head, "time_scale", 1.0, cmap.name, "[map]")
        if not v > 0:
            raise FsidError(
                f"channel map {cmap.name}: [map] time_scale = {v!r}: give the time column's unit in s (> 0)"
            )
        out["time_scale"] = v
    return out


#: the fewest samples a log's fullest channel may have to be read as a flight
MIN_SAMPLES = 3


def _has_records(raw: RawLog, path, fmt: str) -> None:
    """LogReadError unless ``raw`` has a decoded record (tables of bytes no message
    decodes, ``UNKNOWN_*``, do not count)."""
    if not any(len(v) for k, v in raw.tables.items() if not k.startswith("UNKNOWN")):
        raise LogReadError(
            f"{path}: no data records in this {fmt} file (only headers or format definitions, or not "
            f"a {fmt} log at all): give the flight's log",
            path=str(path),
            where="whole file",
        )


def _named_window(fd: FlightData, name: str, t0: float, t1: float) -> SegmentSpec:
    """An archive's named window as a segment given by time, its axis the control input
    moved most in it, else the one whose body rate moves most (None where nothing moves):
    the fits take it as the user's range."""
    moved = fd.moved_inputs(t0, t1) or fd.answered_inputs(t0, t1)
    return SegmentSpec(name, t0, t1, "time", axis=moved[0] if moved else None)


def _timed(chans: dict) -> tuple[dict, dict[str, int]]:
    """The channels without their samples whose time is NaN or infinite (a damaged or
    blank time field: no place on any time line), and channel -> how many were dropped."""
    out, untimed = {}, {}
    for k, c in chans.items():
        ok = np.isfinite(np.asarray(c.t, dtype=float))
        if not ok.all():
            untimed[k] = int((~ok).sum())
            c = replace(c, t=c.t[ok], values=c.values[ok])
        out[k] = c
    return out, untimed


def _has_samples(chans: dict, path) -> None:
    """LogReadError unless the fullest mapped channel has MIN_SAMPLES samples."""
    most = max((len(c) for c in chans.values()), default=0)
    if most < MIN_SAMPLES:
        raise LogReadError(
            f"{path}: {most} sample{'s' if most != 1 else ''} in its fullest channel, too few to check or fit "
            f"(at least {MIN_SAMPLES}): give the flight's whole log",
            path=str(path),
            where="whole file",
        )


def read_log(path: str | os.PathLike, map=None, **opts):
    """Read any supported log into canonical :class:`~pipeline.ingest.flightdata.FlightData`.

    Parameters
    ----------
    path : the log file (never modified)
    map : channel map — None (built-in map for the detected format), a built-in map name,
        a TOML path, or a :class:`pipeline.ingest.maps.ChannelMap`; user TOML maps with
        ``[map] extends = "<builtin>"`` add to / override a built-in map
    opts : ``strict`` (raise on damage), ``time_base`` (MCAP: "auto" | "header" | "log";
        .tlog: "auto" | "boot" | "log", default the autopilot's own stamps,
        :mod:`pipeline.ingest.readers.tlog_time`; ``TIME_BASES``; None is the default, a choice
        the format does not offer is a LogReadError),
        ``segments`` ("mode" | "auto" | list of (t0, t1) [s from the log's start] or
        segment names, :meth:`FlightData.chosen_segments`; default: mode segments when
        the log has modes, then automatic ones from control activity), ``servo_travel``
        (surface -> (deg, origin): the deflection at full servo travel for surfaces
        decoded from servo PWM, e.g. an aircraft TOML's ``[servos]``; see
        :func:`pipeline.ingest.maps.servo_travel`; what was used is ``meta["servo_travel"]``),
        ``pose`` (keywords for :func:`pipeline.ingest.pose.derive_pose_states`, e.g.
        ``{"window_s": 0.2, "wind_ned": (0, 0, 0)}``, or False: a log with a pose (x_n y_e z_d,
        q_w q_x q_y q_z) but without some flight state gets it derived from the pose; logged
        channels win; they override the channel map's ``[map] pose = {...}``; ``meta["pose"]``
        says how, or why a pose could not be used)

    Returns
    -------
    FlightData whose channels are canonical names in SI units (DESIGN.md section 3), its
    times in seconds from the log's start (``meta["t0_abs"]``, ``meta["t0_kind"]``: where
    that is on the log's clock, :meth:`FlightData.from_log_start`).
    """
    segments = opts.pop("segments", None)
    travel = opts.pop("servo_travel", None)
    pose = opts.pop("pose", None)
    fmt = opts.pop("format", None) or detect_format(path)
    time_base = opts.pop("time_base", None)
    if time_base is not None:
        if time_base not in TIME_BASES.get(fmt, ()):
            choices = "; ".join(f"a .{f} log: {', '.join(c)}" for f, c in TIME_BASES.items())
            raise LogReadError(
                f"{path}: time base {time_base!r} does not apply to a {fmt} log; "
                f"the time base is chosen for {choices} (leave it out for the "
                "default)",
                path=str(path),
                where="options",
            )
        opts["time_base"] = time_base
    if fmt == "csv" and map is not None:
        opts.update(_csv_time(load_map(map, fmt)))
    raw = read_raw(path, fmt, **opts)
    _has_records(raw, path, fmt)
    map_fmt = raw.info.get("map_hint", raw.format)
    cmap = (
        load_map(map, raw.format)
        if map is not None
        else load_map(map_fmt if map_fmt in builtin_names() else None, raw.format)
    )
    chans, why, travels = apply_map(raw, cmap, travel)
    chans, untimed = _timed(chans)
    meta = {
        "source": str(path),
        "format": raw.format,
        "map": cmap.name,
        "time_base": raw.time_base,
        "params": raw.params,
        "modes": raw.modes,
        "damage": raw.damage.as_dict() if raw.damage else None,
        "unmapped": why,
        "servo_travel": travels,
        "info": raw.info,
        "tables": {k: len(v) for k, v in raw.tables.items()},
        "untimed": untimed,
    }
    _has_samples(chans, path)
    fd = FlightData(chans, meta, []).from_log_start()
    if pose is not False and needs_pose_states(fd):
        chosen = map_pose_options(cmap.header.get("pose"), cmap.name) | (pose or {})
        fd = derive_pose_states(fd, **({"strict": False} | chosen))
    if isinstance(segments, (list, tuple)):
        fd.segments = fd.chosen_segments(segments, per_axis=False)
    elif segments is None and raw.info.get("windows"):  # an archive's windows are its segments
        fd.segments.extend(_named_window(fd, w["name"], w["t0"], w["t1"]) for w in raw.info["windows"])
    elif segments in (None, "mode", "auto"):
        if segments in (None, "mode") and fd.modes:
            fd.segments.extend(fd.mode_segments())
        if segments in (None, "auto"):
            fd.segments.extend(fd.find_segments())
    return fd
