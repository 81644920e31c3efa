"""ArduPilot DataFlash (.bin) reader: numpy structured arrays over the raw bytes.

A record is ``0xA3 0x95 <id>`` followed by the fields of message ``id`` as declared by an
``FMT`` record (id 128, 89 bytes, always first). Record boundaries are found by one
compiled walk over the bytes (:mod:`pipeline.ingest.readers._scan`); each message type is then
copied into an ``(n, length)`` byte block and viewed through a numpy structured dtype, so
no Python object is created per message. Values equal pymavlink's ``DFReader``: format
characters ``c C e E`` are scaled by 0.01 and ``L`` by 1e-7. ``FMTU``/``UNIT``/``MULT``
records give each field's unit and multiplier (``Table.units``) and the instance field
('#' unit), by which multi-instance messages split into ``IMU[0]``, ``IMU[1]`` ...

Damage: bytes that do not start a known record are skipped (resynchronising on the next
header, like DFReader); the first such offset and an incomplete last record are reported
in ``RawLog.damage``. Everything decoded is kept.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.ingest.rawlog import Damage, LogReadError, RawLog, Table
from pipeline.ingest.readers import _scan

#: DataFlash format char -> (numpy dtype, multiplier applied by DFReader)
FORMAT_CHARS: dict[str, tuple[object, float | None]] = {
    "a": (("<i2", (32,)), None),
    "b": ("i1", None),
    "B": ("u1", None),
    "g": ("<f2", None),
    "h": ("<i2", None),
    "H": ("<u2", None),
    "i": ("<i4", None),
    "I": ("<u4", None),
    "f": ("<f4", None),
    "d": ("<f8", None),
    "n": ("S4", None),
    "N": ("S16", None),
    "Z": ("S64", None),
    "c": ("<i2", 0.01),
    "C": ("<u2", 0.01),
    "e": ("<i4", 0.01),
    "E": ("<u4", 0.01),
    "L": ("<i4", 1e-7),
    "M": ("i1", None),
    "q": ("<i8", None),
    "Q": ("<u8", None),
}
SCALED_CHARS = set("cCeEL")
FMT_DTYPE = np.dtype(
    [("h", "S3"), ("Type", "u1"), ("Length", "u1"), ("Name", "S4"), ("Format", "S16"), ("Columns", "S64")]
)

#: ArduPilot UNIT labels -> our unit keys (pipeline.ingest.maps.UNIT_FACTORS)
UNIT_LABELS = {
    "m/s/s": "m/s^2",
    "deg/s": "deg/s",
    "rad/s": "rad/s",
    "deg": "deg",
    "degheading": "deg",
    "rad": "rad",
    "m/s": "m/s",
    "m": "m",
    "Pa": "Pa",
    "%": "%",
    "s": "s",
    "cm": "cm",
    "cm/s": "cm/s",
    "mG": "mG",
    "N": "N",
    "kg/m^3": "kg/m^3",
    "cdeg": "cdeg",
    "us": "us",
    "ms": "ms",
}


@dataclass
class MsgFormat:
    """One FMT record: message id, name, record length [bytes], format chars, columns."""

    id: int
    name: str
    length: int
    fmt: str
    columns: list[str]
    dtype: np.dtype | None = None
    units: dict[str, str] = field(default_factory=dict)
    mults: dict[str, float] = field(default_factory=dict)
    instance_field: str | None = None

    def build_dtype(self) -> np.dtype | None:
        if len(self.fmt) != len(self.columns):
            return None
        names: list[tuple] = [("_hdr", "S3")]
        seen: set[str] = set()
        for c, col in zip(self.fmt, self.columns):
            if c not in FORMAT_CHARS:
                return None
            base = FORMAT_CHARS[c][0]
            name = col
            k = 1
            while name in seen or name == "_hdr":
                k += 1
                name = f"{col}_{k}"
            seen.add(name)
            names.append((name, *base) if isinstance(base, tuple) else (name, base))
        try:
            dt = np.dtype(names)
        except (TypeError, ValueError):
            return None
        return dt if dt.itemsize == self.length else None


def _cstr(b: bytes) -> str:
    return b.split(b"\0", 1)[0].decode("ascii", "replace")


def _load_bytes(path: Path) -> np.ndarray:
    size = os.path.getsize(path)
    if size == 0:
        return np.zeros(0, dtype=np.uint8)
    return np.memmap(path, dtype=np.uint8, mode="r")


def scan_file(
    path: str | os.PathLike,
) -> tuple[np.ndarray, dict[int, MsgFormat], np.ndarray, np.ndarray, Damage | None]:
    """Scan a DataFlash file: (bytes, formats by id, record offsets, record ids, damage)."""
    path = Path(path)
    try:
        buf = _load_bytes(path)
    except OSError as exc:
        raise LogReadError.cannot_open(path, exc) from None
    lengths = np.zeros(256, dtype=np.int64)
    lengths[_scan.FMT_ID] = 89
    offs, ids, first_bad, skipped, truncated = _scan.walk(buf, lengths)
    formats: dict[int, MsgFormat] = {}
    fmt_offs = offs[ids == _scan.FMT_ID]
    if fmt_offs.size:
        recs = _scan.gather(buf, fmt_offs, 89).view(FMT_DTYPE).ravel()
        for r in recs:
            mf = MsgFormat(
                int(r["Type"]),
                _cstr(r["Name"]),
                int(r["Length"]),
                _cstr(r["Format"]),
                [c for c in _cstr(r["Columns"]).split(",")],
            )
            mf.dtype = mf.build_dtype()
            formats[mf.id] = mf
    damage = None
    if first_bad >= 0 or truncated >= 0:
        # the first damaged byte: whichever comes first
        cands = [x for x in (first_bad, truncated) if x >= 0]
        at = int(min(cands))
        if truncated >= 0 and at == truncated:
            what = (
                f"incomplete last record at byte {at} ({buf.shape[0] - at} of its bytes present); the log was cut short"
            )
        else:
            what = f"unreadable bytes from byte {at}; skipped {skipped} bytes in total"
        kept = int(np.searchsorted(offs, at))
        damage = Damage(
            at, f"byte {at}", what, kept, int(skipped + (buf.shape[0] - truncated if truncated >= 0 else 0))
        )
    return buf, formats, offs, ids, damage


def message_arrays(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[int, MsgFormat], Damage | None]:
    """Every message type as one structured array (raw field values, no scaling).

    Returns (name -> structured array of shape (n,), formats by id, damage). Field values
    are the stored integers/floats; multiply format chars ``c C e E`` by 0.01 and ``L`` by
    1e-7 (see :func:`scaled`) to get DFReader's values.
    """
    buf, formats, offs, ids, damage = scan_file(path)
    out: dict[str, np.ndarray] = {}
    if offs.size == 0:
        return out, formats, damage
    order = np.argsort(ids, kind="stable")
    sorted_ids = ids[order]
    present = np.unique(sorted_ids)
    bounds = np.searchsorted(sorted_ids, present)
    bounds = np.r_[bounds, sorted_ids.size]
    for k, mid in enumerate(present):
        mf = formats.get(int(mid))
        if mf is None or mf.dtype is None:
            continue
        o = offs[order[bounds[k] : bounds[k + 1]]]
        block = _scan.gather(buf, o, mf.length)
        out[mf.name] = block.view(mf.dtype).reshape(-1)
    del order, sorted_ids
    return out, formats, damage


def scaled(arr: np.ndarray, mf: MsgFormat, name: str) -> np.ndarray:
    """Field ``name`` of a structured array as float64 with DFReader's scaling."""
    col = arr[name]
    i = list(mf.dtype.names).index(name) - 1
    c = mf.fmt[i]
    if c in "nNZ":
        return col
    mul = FORMAT_CHARS[c][1]
    v = col.astype(np.float64)
    if mul is None:
        return v
    # divide (as DFReader does) rather than multiply: 0.01 and 1e-7 are inexact in binary
    return v / (1.0 / mul) if 0.0 < mul < 1.0 else v * mul


def _apply_fmtu(arrays: dict[str, np.ndarray], formats: dict[int, MsgFormat]) -> None:
    units = arrays.get("UNIT")
    mults = arrays.get("MULT")
    fmtu = arrays.get("FMTU")
    if fmtu is None:
        return
    unit_of = {}
    if units is not None and "Id" in units.dtype.names and "Label" in units.dtype.names:
        unit_of = {chr(int(i) & 0xFF): _cstr(l) for i, l in zip(units["Id"], units["Label"])}
    mult_of = {}
    if mults is not None and "Id" in mults.dtype.names and "Mult" in mults.dtype.names:
        mult_of = {chr(int(i) & 0xFF): float(m) for i, m in zip(mults["Id"], mults["Mult"])}
    names = fmtu.dtype.names
    if not {"FmtType", "UnitIds", "MultIds"} <= set(names):
        return
    for ft, uids, mids in zip(fmtu["FmtType"], fmtu["UnitIds"], fmtu["MultIds"]):
        mf = formats.get(int(ft))
        if mf is None:
            continue
        u = _cstr(uids)
        m = _cstr(mids)
        for j, col in enumerate(mf.columns):
            if j < len(u):
                if u[j] == "#":
                    mf.instance_field = col
                lab = unit_of.get(u[j])
                if lab:
                    mf.units[col] = lab
            if j < len(m) and m[j] in mult_of and m[j] not in "-?":
                mf.mults[col] = mult_of[m[j]]


PLANE_MODES = {
    0: "MANUAL",
    1: "CIRCLE",
    2: "STABILIZE",
    3: "TRAINING",
    4: "ACRO",
    5: "FBWA",
    6: "FBWB",
    7: "CRUISE",
    8: "AUTOTUNE",
    10: "AUTO",
    11: "RTL",
    12: "LOITER",
    13: "TAKEOFF",
    14: "AVOID_ADSB",
    15: "GUIDED",
    16: "INITIALISING",
    17: "QSTABILIZE",
    18: "QHOVER",
    19: "QLOITER",
    20: "QLAND",
    21: "QRTL",
    22: "QAUTOTUNE",
    23: "QACRO",
    24: "THERMAL",
    25: "LOITERALTQLAND",
}


def _time_of(arr: np.ndarray) -> np.ndarray:
    names = arr.dtype.names
    if "TimeUS" in names:
        return arr["TimeUS"].astype(np.float64) * 1e-6
    if "TimeMS" in names:
        return arr["TimeMS"].astype(np.float64) * 1e-3
    return np.full(arr.shape[0], np.nan)


def _make_table(name: str, arr: np.ndarray, mf: MsgFormat, t: np.ndarray) -> Table:
    fields = [n for n in arr.dtype.names if n != "_hdr"]

    def loader(f: str, arr=arr, mf=mf) -> np.ndarray:
        return scaled(arr, mf, f)

    units = {}
    chars = dict(zip(mf.columns, mf.fmt))
    for c, u in mf.units.items():
        m = mf.mults.get(c, 1.0)
        # a multiplier other than 1 on a field the format does not scale: the stored number
        # is in (multiplier x unit); only plain units are reported
        if m in (0.0, 1.0) or chars.get(c, "") in SCALED_CHARS:
            units[c] = UNIT_LABELS.get(u, u)
    for c, m in mf.mults.items():
        units[f"{c}.__mult__"] = str(m)
    return Table(name, t, {}, units, loader, fields)


def read_dataflash(path: str | os.PathLike, *, strict: bool = False) -> RawLog:
    """Read an ArduPilot DataFlash .bin log into raw tables.

    Times are ``TimeUS`` [us since autopilot boot] converted to seconds. ``strict`` raises
    :class:`LogReadError` at the first damage instead of recording it in ``damage``.
    """
    path = Path(path)
    arrays, formats, damage = message_arrays(path)
    if not arrays:
        where = damage.where if damage else "byte 0"
        raise LogReadError(
            f"{path}: no DataFlash records found ({where}); is this an ArduPilot "
            ".bin log? Check the file type or pass the right extension",
            path=str(path),
            offset=damage.offset if damage else 0,
            where=where,
        )
    if strict and damage is not None:
        raise LogReadError(
            f"{path}: {damage.message}", path=str(path), offset=damage.offset, where=damage.where, partial=arrays
        )
    _apply_fmtu(arrays, formats)
    by_name = {mf.name: mf for mf in formats.values()}
    tables: dict[str, Table] = {}
    for name, arr in arrays.items():
        mf = by_name[name]
        if name in ("FMT", "FMTU", "UNIT", "MULT"):
            continue
        t = _time_of(arr)
        inst = mf.instance_field
        if inst and inst in arr.dtype.names:
            for i in np.unique(arr[inst]):
                sel = arr[arr[inst] == i]
                tables[f"{name}[{int(i)}]"] = _make_table(f"{name}[{int(i)}]", sel, mf, t[arr[inst] == i])
        else:
            tables[name] = _make_table(name, arr, mf, t)
    params: dict[str, float] = {}
    parm = arrays.get("PARM")
    if parm is not None and {"Name", "Value"} <= set(parm.dtype.names):
        for n, v in zip(parm["Name"], parm["Value"]):
            params[_cstr(n)] = float(v)
    vehicle = ""
    msg = arrays.get("MSG")
    if msg is not None and "Message" in msg.dtype.names:
        for m in msg["Message"][:20]:
            s = _cstr(m)
            if s.startswith(("Ardu", "APM:")):
                vehicle = s
                break
    modes: list[tuple[float, str]] = []
    mode = arrays.get("MODE")
    if mode is not None:
        t = _time_of(mode)
        num = mode["ModeNum"] if "ModeNum" in mode.dtype.names else mode["Mode"]
        for ti, n in zip(t, num):
            name = PLANE_MODES.get(int(n), f"MODE{int(n)}") if "Copter" not in vehicle else f"MODE{int(n)}"
            if not modes or modes[-1][1] != name:
                modes.append((float(ti), name))
    if "Copter" in vehicle and modes:
        try:
            from pymavlink import mavutil

            mm = mavutil.mode_mapping_acm
            modes = [(t0, mm.get(int(n[4:]), n)) for t0, n in modes]
        except Exception:  # pragma: no cover
            pass
    info = {
        "vehicle": vehicle,
        "message_counts": {k: int(v.shape[0]) for k, v in arrays.items()},
        "has_fmtu": "FMTU" in arrays,
    }
    return RawLog(
        tables,
        "dataflash",
        params,
        modes,
        "TimeUS of each record (microseconds since autopilot boot), in s",
        damage,
        info,
    )
