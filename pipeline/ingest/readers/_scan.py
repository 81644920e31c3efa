"""Record-boundary scanning and gathering for DataFlash logs.

Compiled with numba (a project dependency): the walk over record headers is a sequential
byte loop that numpy cannot vectorise.
"""

from __future__ import annotations

import numpy as np
from numba import njit

HEAD1, HEAD2, FMT_ID = 0xA3, 0x95, 0x80


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
    return _walk_nb(buf, lengths)


def gather(buf: np.ndarray, offs: np.ndarray, length: int) -> np.ndarray:
    """Copy the records at ``offs`` (each ``length`` bytes) into an (m, length) uint8 array."""
    return _gather_nb(buf, offs, length)
