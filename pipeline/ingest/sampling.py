"""What a channel's sample stamps say: its rate, its gaps, and the clock the log runs on.

A log's channels are stamped by the autopilot; the stamps, not their span, give the rate:
a log paused between maneuvers keeps its rate, and its pauses (gaps) are segment
boundaries. Times in the product are seconds from the log's start; where that start is on
the log's own clock (Unix epoch or time since boot) is stated once.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

import numpy as np

#: an interval between two samples longer than this many typical intervals is a gap (a
#: logging pause between maneuvers, a dropout): a segment boundary that neither lowers a
#: channel's rate nor counts as jitter. 5 keeps a few lost samples out of the rate too,
#: while bursty arrival (telemetry: a few samples at once, then a pause of a few
#: intervals) stays regular sampling
GAP_FACTOR = 5.0
#: a log whose first stamp is at least this [s] runs on a calendar clock (Unix epoch,
#: UTC; 1e8 s is 1973); smaller ones count from the autopilot's boot or the log's start
EPOCH_MIN_S = 1e8
#: the fastest grid a log is put on [Hz]: above any sensor rate of a flight log, and a
#: bound on the work a mistyped rate can ask for
MAX_GRID_HZ = 10_000.0
#: a uniform grid skips the spans farther than this [s] (or two grid periods) from every
#: sample of its channels: a gap is a gap, never filled sample by sample (one stamp 1e7 s
#: late would otherwise ask for 1e9 rows)
GRID_GAP_S = 0.5


def uniform_grid(lo: float, hi: float, rate_hz: float, stamps: list[np.ndarray]) -> np.ndarray:
    """The times [s] lo + k / rate_hz in [lo, hi] of a grid for channels sampled at
    ``stamps`` (one array per channel): every such time while the grid is at most a few
    times the samples; else only those within GRID_GAP_S (or two grid periods) of a sample,
    so the grid's size is bounded by the data's, not by the span of its stamps."""
    if not hi >= lo:
        return np.zeros(0)
    total = sum(int(np.size(s)) for s in stamps)
    n = int(np.floor((hi - lo) * rate_hz + 1e-9)) + 1
    if n <= 4 * total + 1000:
        return lo + np.arange(n) / rate_hz
    g = max(GRID_GAP_S, 2.0 / rate_hz)
    s = np.unique(np.concatenate([np.asarray(x, dtype=float) for x in stamps]))
    s = s[np.isfinite(s) & (s >= lo - g) & (s <= hi + g)]
    if s.size == 0:
        return np.zeros(0)
    cut = np.flatnonzero(np.diff(s) > 2 * g)
    starts = np.maximum(np.r_[s[0], s[cut + 1]] - g, lo)
    ends = np.minimum(np.r_[s[cut], s[-1]] + g, hi)
    k0 = np.ceil((starts - lo) * rate_hz - 1e-9)
    k1 = np.floor((ends - lo) * rate_hz + 1e-9)
    # grid steps beyond float64's integers (2^53: 2.8 million years at 100 Hz) have no place
    keep = (k1 >= k0) & (k1 < 2.0**53)
    k = np.concatenate(
        [np.arange(a, b + 1, dtype=np.int64) for a, b in zip(k0[keep].astype(np.int64), k1[keep].astype(np.int64))]
        or [np.zeros(0, np.int64)]
    )
    return lo + k / rate_hz


def contiguous(t: np.ndarray, max_gap: float) -> list[slice]:
    """Slices of the sorted stamps ``t`` between intervals longer than ``max_gap`` [s]."""
    cut = np.flatnonzero(np.diff(t) > max_gap) + 1
    edges = np.r_[0, cut, t.size]
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def _intervals(t: np.ndarray) -> np.ndarray:
    """The positive intervals between the finite stamps ``t`` [s], in time order."""
    t = np.asarray(t, dtype=float)
    t = t[np.isfinite(t)]
    dt = np.diff(t)
    if np.any(dt < 0):
        dt = np.diff(np.sort(t))
    return dt[dt > 0]


def typical_interval(t: np.ndarray) -> float:
    """The typical interval between the stamps ``t`` [s]: the mean interval with the gaps
    (longer than GAP_FACTOR typical intervals) left out, found by iterating from the mean
    of all; NaN with fewer than two distinct stamps. The mean of the regular intervals, not
    their median: bursty arrival (telemetry, a few samples at once) gives the real rate,
    and a gap between maneuvers does not lower it."""
    dt = _intervals(t)
    if dt.size == 0:
        return float("nan")
    m = float(dt.mean())
    for _ in range(50):  # m falls at each step; a few steps in practice
        m_new = float(dt[dt <= GAP_FACTOR * m].mean())
        if m_new >= m:
            break
        m = m_new
    return m


def sample_rate(t: np.ndarray) -> float:
    """Sample rate [Hz] of the stamps ``t`` [s]: 1 / :func:`typical_interval` (0 with fewer
    than two distinct stamps)."""
    m = typical_interval(t)
    return float(1.0 / m) if np.isfinite(m) and m > 0 else 0.0


#: the rate a channel carrying the aircraft's motion needs: this many samples per period of
#: the fastest motion it shows
SAMPLES_PER_PERIOD = 10.0
#: "the fastest motion it shows": the frequency below which this share of its (detrended)
#: variance lies
BANDWIDTH_SHARE = 0.95


def response_floor_hz(t: np.ndarray, v: np.ndarray, ceiling: float, floor: float) -> float:
    """The sample rate [Hz] a channel of the aircraft's motion (a body rate, an
    acceleration) needs: SAMPLES_PER_PERIOD samples per period of the frequency below which
    BANDWIDTH_SHARE of its variance lies, from its own spectrum (Welch, the samples read on
    their own rate), within ``floor``..``ceiling``. A log too slow for its aircraft shows
    its motion folded up to the Nyquist frequency, and sensor noise spreads to it too, so
    either asks for the ceiling; the slow modes of a large aircraft ask for less.
    ``ceiling`` with fewer than 64 finite samples."""
    from scipy import signal  # on use: the readers import this module

    t, v = np.asarray(t, dtype=float), np.asarray(v, dtype=float)
    ok = np.isfinite(t) & np.isfinite(v)
    rate = sample_rate(t[ok]) if ok.sum() >= 2 else 0.0
    if ok.sum() < 64 or rate <= 0:
        return float(ceiling)
    tt = np.arange(t[ok][0], t[ok][-1], 1.0 / rate)
    x = signal.detrend(np.interp(tt, t[ok], v[ok]))
    f, P = signal.welch(x, fs=rate, nperseg=min(x.size, 256))
    share = np.cumsum(P[1:]) / max(np.sum(P[1:]), 1e-300)
    f_hi = float(f[1:][min(int(np.searchsorted(share, BANDWIDTH_SHARE)), f.size - 2)])
    return float(np.clip(SAMPLES_PER_PERIOD * f_hi, floor, ceiling))


def sample_gaps(t: np.ndarray) -> list[tuple[float, float]]:
    """The gaps of the stamps ``t`` [s]: (last stamp before, first stamp after) of every
    interval longer than GAP_FACTOR typical intervals (:func:`typical_interval`)."""
    t = np.asarray(t, dtype=float)
    t = np.sort(t[np.isfinite(t)])
    m = typical_interval(t)
    if not np.isfinite(m):
        return []
    k = np.flatnonzero(np.diff(t) > GAP_FACTOR * m)
    return [(float(t[i]), float(t[i + 1])) for i in k]


def start_kind(t0_abs: float) -> str:
    """The clock of a log whose first stamp is ``t0_abs`` [s]: "epoch UTC" (a calendar
    clock, EPOCH_MIN_S or later) or "boot" (time since the autopilot's boot or the log's
    own start)."""
    return "epoch UTC" if t0_abs >= EPOCH_MIN_S else "boot"


def utc_text(seconds: float, timespec: str = "microseconds") -> str | None:
    """Seconds since 1970 as an ISO UTC time ("2026-11-30T10:00:00.000000 UTC"), or None
    beyond any calendar date (a damaged stamp near 2^64 us)."""
    try:
        return datetime.fromtimestamp(seconds, tz=UTC).isoformat(timespec=timespec).replace("+00:00", " UTC")
    except (ValueError, OverflowError, OSError):
        return None


def start_statement(meta: Mapping[str, Any]) -> str:
    """One sentence saying where t = 0 is on the log's own clock (``meta["t0_abs"]``,
    ``meta["t0_kind"]`` of :meth:`FlightData.from_log_start`); "" when the log's times were
    not moved."""
    if "t0_abs" not in meta:
        return ""
    t0 = float(meta["t0_abs"])
    if meta.get("t0_kind") == "epoch UTC":
        when = utc_text(t0)
        if when is None:
            return (
                f"times are seconds from the log's start; t = 0 is {t0:.6g} s on the log's clock, "
                "beyond any calendar date (a damaged time stamp?)"
            )
        return f"times are seconds from the log's start; t = 0 is {when} ({t0:.6f} s Unix epoch)"
    return f"times are seconds from the log's start; t = 0 is {t0:.6f} s on the log's own clock (since boot)"
