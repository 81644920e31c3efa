"""DataFlash (.bin) byte layout for tests that damage a log on purpose."""

from __future__ import annotations

import struct
from pathlib import Path


def records(buf: bytes):
    """(offset, name) of every record of a DataFlash log, from its FMT records."""
    fmt = {128: ("FMT", 89)}
    off, out = 0, []
    while off + 3 <= len(buf):
        if buf[off] != 0xA3 or buf[off + 1] != 0x95 or buf[off + 2] not in fmt:
            off += 1
            continue
        mid = buf[off + 2]
        name, length = fmt[mid]
        if mid == 128:
            typ, ln = buf[off + 3], buf[off + 4]
            fmt[typ] = (buf[off + 5 : off + 9].rstrip(b"\0").decode(), ln)
        out.append((off, name))
        off += length
    return out


def late_record(src: Path, dst: Path, name: str = "IMU", late_us: int = 10**13) -> None:
    """A copy of ``src`` with the middle ``name`` record's TimeUS ``late_us`` later."""
    buf = bytearray(src.read_bytes())
    offs = [o for o, n in records(bytes(buf)) if n == name]
    o = offs[len(offs) // 2] + 3
    (t,) = struct.unpack_from("<Q", buf, o)
    struct.pack_into("<Q", buf, o, t + late_us)
    dst.write_bytes(bytes(buf))
