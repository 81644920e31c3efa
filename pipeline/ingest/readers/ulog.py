"""PX4 ULog (.ulg) reader (pyulog).

Each topic instance becomes a table named ``topic`` (instance 0) and ``topic[k]``;
fields keep pyulog's names (``gyro_rad[0]``, nested ``previous.x``). Time base: the
ULog ``timestamp`` field (microseconds since PX4 boot), in s. Parameters: initial values
updated by later changes. Flight modes: ``vehicle_status.nav_state`` names.
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
from pathlib import Path

import numpy as np

from pipeline.ingest.rawlog import Damage, LogReadError, RawLog, Table

NAV_STATES = {
    0: "MANUAL",
    1: "ALTCTL",
    2: "POSCTL",
    3: "AUTO_MISSION",
    4: "AUTO_LOITER",
    5: "AUTO_RTL",
    10: "ACRO",
    12: "DESCEND",
    13: "TERMINATION",
    14: "OFFBOARD",
    15: "STAB",
    17: "AUTO_TAKEOFF",
    18: "AUTO_LAND",
    19: "AUTO_FOLLOW_TARGET",
    20: "AUTO_PRECLAND",
    21: "ORBIT",
    22: "AUTO_VTOL_TAKEOFF",
}


def _truncated_at(path: Path) -> int | None:
    """The byte offset of the ULog message the file ends inside (a file cut short), or
    None when it ends on a message boundary. Every message after the 16-byte file header
    starts with its size (uint16) and type (uint8)."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    pos = 16
    n = len(data)
    while pos + 3 <= n:
        (msg_size,) = struct.unpack_from("<H", data, pos)
        nxt = pos + 3 + msg_size
        if nxt > n:
            return pos
        pos = nxt
    return pos if pos < n else None


def _damage(path: Path, size: int, ulog, log_text: str, tables: dict, strict: bool) -> Damage | None:
    """Where the file stops being readable: a file cut inside a message
    (:func:`_truncated_at`), or corrupted data pyulog skipped; None when whole. With
    ``strict`` a LogReadError instead."""
    cut = _truncated_at(path)
    if cut is not None:
        damage = Damage(
            cut,
            f"byte {cut} of {size}",
            f"the file ends inside a ULog message at byte {cut} of {size}: it was cut short (copied or "
            "written before the log was closed); the data before that byte are kept",
            sum(len(t) for t in tables.values()),
        )
    elif getattr(ulog, "file_corruption", False) or "corrupt" in log_text.lower():
        damage = Damage(
            -1,
            "ULog data section",
            "corrupted data in the ULog data section; pyulog skipped to the next valid message",
            sum(len(t) for t in tables.values()),
        )
    else:
        return None
    if strict:
        raise LogReadError(f"{path}: {damage.message}", path=str(path), where=damage.where, partial=tables)
    return damage


def read_ulog(path: str | os.PathLike, *, strict: bool = False) -> RawLog:
    """Read a PX4 .ulg into raw tables (see module docstring)."""
    path = Path(path)
    try:
        from pyulog import ULog
    except ImportError as exc:  # pragma: no cover
        raise LogReadError(
            f"reading .ulg needs pyulog ({exc}); pip install pyulog", path=str(path), where="import"
        ) from None
    size = path.stat().st_size if path.exists() else 0
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError as exc:
        raise LogReadError.cannot_open(path, exc) from None
    if not head.startswith(b"ULog"):
        raise LogReadError(
            f"{path}: not a ULog file (no 'ULog' magic at byte 0); is the extension right?",
            path=str(path),
            offset=0,
            where="byte 0",
        )
    try:
        with contextlib.redirect_stdout(io.StringIO()) as out:
            ulog = ULog(str(path))
        log_text = out.getvalue()
    except Exception as exc:  # pyulog raises many kinds on damaged input
        raise LogReadError(
            f"{path}: ULog could not be parsed ({type(exc).__name__}: {exc}); the file is damaged before any data",
            path=str(path),
            offset=None,
            where="ULog header/definitions",
        ) from None
    tables: dict[str, Table] = {}
    for d in ulog.data_list:
        if "timestamp" not in d.data:
            continue
        name = d.name if d.multi_id == 0 else f"{d.name}[{d.multi_id}]"
        t = np.asarray(d.data["timestamp"], dtype=np.float64) * 1e-6
        cols = {}
        for k, v in d.data.items():
            a = np.asarray(v)
            if a.dtype.kind in "biuf":
                with np.errstate(invalid="ignore", over="ignore"):
                    cols[k] = a.astype(np.float64)
        tables[name] = Table(name, t, cols)
    params: dict[str, float] = {}
    changes = [(k, v) for _t, k, v in getattr(ulog, "changed_parameters", [])]
    for k, v in list(ulog.initial_parameters.items()) + changes:
        try:
            params[str(k)] = float(v)
        except (TypeError, ValueError):
            continue  # damaged parameter record
    modes: list[tuple[float, str]] = []
    vs = tables.get("vehicle_status")
    if vs is not None and "nav_state" in vs:
        for ti, ns in zip(vs.t, vs["nav_state"]):
            nm = NAV_STATES.get(int(ns), f"NAV_STATE_{int(ns)}")
            if not modes or modes[-1][1] != nm:
                modes.append((float(ti), nm))
    damage = _damage(path, size, ulog, log_text, tables, strict)
    if not tables:
        raise LogReadError(f"{path}: ULog holds no data messages", path=str(path), where="ULog data section")
    info = {
        "sys_name": ulog.msg_info_dict.get("sys_name", ""),
        "ver_sw": ulog.msg_info_dict.get("ver_sw", ""),
        "size": size,
        "message_counts": {k: len(v) for k, v in tables.items()},
    }
    return RawLog(
        tables, "ulog", params, modes, "ULog timestamp field (microseconds since PX4 boot), in s", damage, info
    )
