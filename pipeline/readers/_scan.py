"""Record-boundary scanning and gathering for DataFlash logs.

Compiled with numba when it is importable (it is a project dependency); a pure-Python
fallback keeps the reader working without it (slower, same results).
"""
from __future__ import annotations

import numpy as np

HEAD1, HEAD2, FMT_ID = 0xA3, 0x95, 0x80

try:  # pragma: no cover - exercised implicitly
    from numba import njit
except Exception:  # pragma: no cover
    njit = None


def _walk_py(buf: np.ndarray, lengths: np.ndarray):
    n = buf.shape[0]
    offs = []
    types = []
    pos = 0
    first_bad = -1
    skipped = 0
    truncated = -1
    b = buf.tobytes() if not isinstance(buf, bytes) else buf
    while pos + 3 <= n:
        if b[pos] == HEAD1 and b[pos + 1] == HEAD2 and lengths[b[pos + 2]] > 0:
            mid = b[pos + 2]
            ln = int(lengths[mid])
            if pos + ln > n:
                truncated = pos
                break
            offs.append(pos)
            types.append(mid)
            if mid == FMT_ID and ln >= 5:
                nt, nl = b[pos + 3], b[pos + 4]
                if nl >= 3:
                    lengths[nt] = nl
            pos += ln
        else:
            if first_bad < 0:
                first_bad = pos
            skipped += 1
            pos += 1
    if truncated < 0 and pos < n:
        truncated = pos
    return (np.asarray(offs, dtype=np.int64), np.asarray(types, dtype=np.uint8),
            first_bad, skipped, truncated)


def _gather_py(buf: np.ndarray, offs: np.ndarray, length: int) -> np.ndarray:
    out = np.empty((offs.shape[0], length), dtype=np.uint8)
    step = 65536
    cols = np.arange(length, dtype=np.int64)
    for a in range(0, offs.shape[0], step):
        o = offs[a:a + step]
        out[a:a + step] = buf[o[:, None] + cols]
    return out


if njit is not None:
    @njit(cache=True, nogil=True)
    def _walk_nb(buf, lengths):  # pragma: no cover - compiled
        n = buf.shape[0]
        cap = max(n // 32, 1024)
        offs = np.empty(cap, np.int64)
        types = np.empty(cap, np.uint8)
        k = 0
        pos = 0
        first_bad = -1
        skipped = 0
        truncated = -1
        while pos + 3 <= n:
            mid = buf[pos + 2]
            if buf[pos] == HEAD1 and buf[pos + 1] == HEAD2 and lengths[mid] > 0:
                ln = lengths[mid]
                if pos + ln > n:
                    truncated = pos
                    break
                if k == cap:
                    cap *= 2
                    o2 = np.empty(cap, np.int64)
                    o2[:k] = offs[:k]
                    offs = o2
                    t2 = np.empty(cap, np.uint8)
                    t2[:k] = types[:k]
                    types = t2
                offs[k] = pos
                types[k] = mid
                k += 1
                if mid == FMT_ID and ln >= 5:
                    nl = buf[pos + 4]
                    if nl >= 3:
                        lengths[buf[pos + 3]] = nl
                pos += ln
            else:
                if first_bad < 0:
                    first_bad = pos
                skipped += 1
                pos += 1
        if truncated < 0 and pos < n:
            truncated = pos
        return offs[:k].copy(), types[:k].copy(), first_bad, skipped, truncated

    @njit(cache=True, nogil=True)
    def _gather_nb(buf, offs, length):  # pragma: no cover - compiled
        m = offs.shape[0]
        out = np.empty((m, length), np.uint8)
        for i in range(m):
            o = offs[i]
            for j in range(length):
                out[i, j] = buf[o + j]
        return out


def walk(buf: np.ndarray, lengths: np.ndarray):
    """Find record boundaries.

    buf : (n,) uint8, the whole file. lengths : (256,) int64, record length per message
    id (0 = unknown), updated in place from FMT records met on the way.

    Returns (offsets (m,) int64, ids (m,) uint8, first_bad_offset or -1, skipped_bytes,
    truncated_offset or -1 (start of an incomplete trailing record / trailing bytes)).
    """
    if njit is not None:
        return _walk_nb(buf, lengths)
    return _walk_py(buf, lengths)


def gather(buf: np.ndarray, offs: np.ndarray, length: int) -> np.ndarray:
    """Copy the records at ``offs`` (each ``length`` bytes) into an (m, length) uint8 array."""
    if njit is not None:
        return _gather_nb(buf, offs, length)
    return _gather_py(buf, offs, length)
