"""MAVLink telemetry log (.tlog) reader.

A .tlog is a sequence of ``<8-byte big-endian microseconds since 1970><MAVLink packet>``.
Packets (v1 0xFE or v2 0xFD, CRC-checked) are decoded with pymavlink's ``ardupilotmega``
dialect (a superset of ``common``, so PX4 logs decode too). Only the vehicle's own
messages (the system that sends autopilot HEARTBEATs, default the most frequent sender)
are kept. PARAM_VALUE messages fill ``params`` (PX4 integer parameters are decoded
bytewise), HEARTBEAT ``custom_mode`` gives the flight modes (pymavlink's mode tables).
Time base: the autopilot's own stamps where messages carry them, on the receive clock
(:mod:`pipeline.ingest.readers.tlog_time`); ``time_base="log"`` keeps the receive timestamps.

Damage: bytes that are not a valid timestamped packet are skipped until the next one;
the first such offset is reported in ``RawLog.damage``.
"""

from __future__ import annotations

import os
import struct
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.ingest.rawlog import TIME_BASES, Damage, LogReadError, RawLog, Table
from pipeline.ingest.readers.tlog_time import boot_time_base

MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
_INT_TYPES = {1: "<B", 2: "<b", 3: "<H", 4: "<h", 5: "<I", 6: "<i"}


def _mavlink():
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import ardupilotmega as mav

    return mav


def _packet_len(data: bytes, i: int) -> int:
    """Length of the MAVLink packet starting at i (0 if not a packet start)."""
    magic = data[i]
    if i + 2 > len(data):
        return 0
    plen = data[i + 1]
    if magic == 0xFE:
        return plen + 8
    if magic == 0xFD:
        if i + 3 > len(data):
            return 0
        sig = 13 if data[i + 2] & 0x01 else 0
        return plen + 12 + sig
    return 0


def _flatten(m, fields: list[str]) -> list:
    out = []
    for f in fields:
        v = getattr(m, f, None)
        if isinstance(v, (list, tuple)):
            out.extend(v)
        else:
            out.append(v)
    return out


@dataclass
class _Packets:
    """The decoded packets of a .tlog, per (system id, message name): rows of flattened
    field values, receive times [s] and packet numbers (order in the file); the
    heartbeats (time, system, message, packet number), PARAM_VALUEs per system, packets
    per sender; how many packets were kept, the first undecodable byte (-1: none), bytes
    skipped, and where decoding stopped."""

    rows: dict[tuple[int, str], list] = field(default_factory=lambda: defaultdict(list))
    times: dict[tuple[int, str], list] = field(default_factory=lambda: defaultdict(list))
    seqs: dict[tuple[int, str], list] = field(default_factory=lambda: defaultdict(list))
    fields_of: dict[str, list[str]] = field(default_factory=dict)
    heartbeats: list[tuple[float, int, object, int]] = field(default_factory=list)
    params: dict[int, dict[str, float]] = field(default_factory=lambda: defaultdict(dict))
    senders: Counter = field(default_factory=Counter)
    kept: int = 0
    first_bad: int = -1
    skipped: int = 0
    end: int = 0


def _decode(data: bytes, mav, strict: bool) -> _Packets:
    """Every timestamped MAVLink packet of ``data`` decoded; bytes that start none are
    skipped one at a time (``strict``: decoding stops at the first)."""
    parser = mav.MAVLink(None)
    parser.robust_parsing = True
    pk = _Packets()
    n = len(data)
    i = 0
    prev_ts = None
    while i + 8 < n:
        ln = _packet_len(data, i + 8)
        ok = False
        if ln and i + 8 + ln <= n:
            ts = struct.unpack_from(">Q", data, i)[0] * 1e-6
            if prev_ts is None or abs(ts - prev_ts) < 86400 * 7:
                try:
                    m = parser.decode(bytearray(data[i + 8 : i + 8 + ln]))
                    ok = m is not None
                except Exception:
                    ok = False
        if not ok:
            if pk.first_bad < 0:
                pk.first_bad = i
                if strict:
                    break
            pk.skipped += 1
            i += 1
            continue
        prev_ts = ts
        pk.kept += 1
        i += 8 + ln
        name = m.get_type()
        if name == "BAD_DATA":
            continue
        sysid = m.get_srcSystem()
        pk.senders[sysid] += 1
        if name == "HEARTBEAT":
            pk.heartbeats.append((ts, sysid, m, pk.kept))
        elif name == "PARAM_VALUE":
            pid = m.param_id if isinstance(m.param_id, str) else m.param_id.decode("ascii", "replace")
            pk.params[sysid][pid.rstrip("\0")] = (m.param_value, m.param_type)
        fl = pk.fields_of.get(name)
        if fl is None:
            fl = pk.fields_of[name] = list(m.get_fieldnames())
        pk.rows[(sysid, name)].append(_flatten(m, fl))
        pk.times[(sysid, name)].append(ts)
        pk.seqs[(sysid, name)].append(pk.kept)
    pk.end = i
    return pk


def _tables(pk: _Packets, sysid: int, mav) -> tuple[dict[str, Table], dict[str, np.ndarray]]:
    """One table per message type of system ``sysid`` (rows of the first row's layout) and
    each table's packet numbers."""
    tables: dict[str, Table] = {}
    seq_of: dict[str, np.ndarray] = {}
    for (s, name), r in pk.rows.items():
        if s != sysid or name in ("PARAM_VALUE", "STATUSTEXT"):
            continue
        proto = pk.fields_of[name]
        width = len(r[0])
        cols: dict[str, np.ndarray] = {}
        expanded = proto if len(proto) == width else _expand_names(mav, name, proto, width)
        same = np.array([len(row) == width for row in r])  # rows of the first's layout
        arr_rows = [row for row, ok in zip(r, same) if ok]
        for c, col in enumerate(expanded):
            vals = [row[c] for row in arr_rows]
            try:
                cols[col] = np.asarray(vals, dtype=np.float64)
            except (TypeError, ValueError):
                cols[col] = np.asarray([str(v) for v in vals], dtype=object)
        tables[name] = Table(name, np.asarray(pk.times[(s, name)])[same], cols)
        seq_of[name] = np.asarray(pk.seqs[(s, name)])[same]
    return tables, seq_of


def _modes(hbs: list[tuple[float, object, int]]) -> tuple[list[tuple[float, str]], list[int]]:
    """The flight modes (start time, name) of the vehicle's heartbeats and the packet
    number of each change (pymavlink's mode tables)."""
    modes: list[tuple[float, str]] = []
    mode_seq: list[int] = []
    try:
        from pymavlink import mavutil

        for t, hb, k in hbs:
            name = mavutil.mode_string_v10(hb)
            if not modes or modes[-1][1] != name:
                modes.append((float(t), name))
                mode_seq.append(k)
    except Exception:  # pragma: no cover
        pass
    return modes, mode_seq


def read_tlog(
    path: str | os.PathLike, *, strict: bool = False, system: int | None = None, time_base: str = "auto"
) -> RawLog:
    """Read a .tlog into one table per message type (fields flattened: ``controls[0]``).

    ``system``: MAVLink system id to keep (default: the autopilot's).
    ``time_base``: "auto" (default) the autopilot's own ``time_boot_ms``/``time_usec``
    stamps where messages have them, on the receive clock, the others at their receive
    time less the link's latency, reboots and wrapped counters handled, each message type
    in the order of its stamps (:func:`pipeline.ingest.readers.tlog_time.boot_time_base`); the
    receive stamps when no message has a usable stamp. "boot": the same, but a log without
    stamps is an error. "log": the .tlog's receive stamps (UTC s; telemetry arrives in
    bursts, so intervals jitter and packets can arrive out of order).
    """
    if time_base not in TIME_BASES["tlog"]:
        raise LogReadError(
            f"time_base must be 'auto', 'log' or 'boot' (got {time_base!r})", path=str(path), where="options"
        )
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise LogReadError.cannot_open(path, exc) from None
    mav = _mavlink()
    pk = _decode(data, mav, strict)
    n, i = len(data), pk.end
    trailing = n - i if i < n else 0
    if pk.kept == 0:
        raise LogReadError(
            f"{path}: no MAVLink packets found (first bytes {data[:12].hex()}); is this a .tlog?",
            path=str(path),
            offset=0,
            where="byte 0",
        )
    # the vehicle: a system sending autopilot heartbeats, else the busiest sender
    autop = [s for _, s, hb, _ in pk.heartbeats if hb.autopilot != 8]
    sysid = (
        system
        if system is not None
        else (Counter(autop).most_common(1)[0][0] if autop else pk.senders.most_common(1)[0][0])
    )
    hbs = [(t, hb, k) for t, s, hb, k in pk.heartbeats if s == sysid and hb.autopilot != 8]
    autopilot = hbs[0][1].autopilot if hbs else None
    tables, seq_of = _tables(pk, sysid, mav)
    par: dict[str, float] = {}
    for pid, (val, ptype) in pk.params.get(sysid, {}).items():
        if autopilot == MAV_AUTOPILOT_PX4 and ptype in _INT_TYPES:
            val = struct.unpack("<i", struct.pack("<f", val))[0]
        par[pid] = float(val)
    modes, mode_seq = _modes(hbs)
    tb_text = "tlog receive timestamps (UTC, seconds since 1970)"
    if time_base != "log":
        mapped = boot_time_base(tables, seq_of, modes, mode_seq)
        if mapped is not None:
            tb_text, modes = mapped
        elif time_base == "boot":
            raise LogReadError(
                f"{path}: no message carries an autopilot stamp (time_boot_ms "
                "or time_usec since boot); read it with time_base='log'",
                path=str(path),
                where="time base",
            )
        else:
            tb_text += ": no autopilot stamps found"
    damage = None
    if pk.first_bad >= 0 or trailing:
        at = pk.first_bad if pk.first_bad >= 0 else i
        damage = Damage(
            at,
            f"byte {at}",
            f"not a timestamped MAVLink packet from byte {at} ({pk.skipped + trailing} bytes skipped)",
            pk.kept,
            pk.skipped + trailing,
        )
        if strict:
            raise LogReadError(
                f"{path}: {damage.message}", path=str(path), offset=at, where=damage.where, partial=tables
            )
    ap = {MAV_AUTOPILOT_ARDUPILOTMEGA: "ardupilot", MAV_AUTOPILOT_PX4: "px4"}.get(autopilot, "")
    info = {
        "system": int(sysid),
        "autopilot": ap,
        "message_counts": {k: len(v) for k, v in tables.items()},
        "param_value_count": int(sum(len(r) for (s, nm), r in pk.rows.items() if nm == "PARAM_VALUE" and s == sysid)),
        "map_hint": "px4_tlog" if ap == "px4" else "mavlink_tlog",
    }
    return RawLog(tables, "tlog", par, modes, tb_text, damage, info)


def _expand_names(mav, name: str, proto: list[str], width: int) -> list[str]:
    cls = mav.mavlink_map.get(getattr(mav, f"MAVLINK_MSG_ID_{name}", -1))
    lengths = dict(zip(getattr(cls, "fieldnames", []), getattr(cls, "array_lengths", [])))
    if cls is not None and hasattr(cls, "ordered_fieldnames"):
        lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths))
    out = []
    for f in proto:
        k = lengths.get(f, 0)
        if k and k > 1 and not _is_char(cls, f):
            out.extend(f"{f}[{j}]" for j in range(k))
        else:
            out.append(f)
    if len(out) != width:
        out = [f"f{j}" for j in range(width)]
    return out


def _is_char(cls, f: str) -> bool:
    try:
        types = dict(zip(cls.fieldnames, cls.fieldtypes))
        return types.get(f) == "char"
    except Exception:
        return False
