"""The time base of a MAVLink telemetry log: the autopilot's own sample stamps.

A .tlog stamps each packet when the ground station received it. Over a telemetry link the
packets arrive in bursts (several within tens of milliseconds, then nothing for up to a
second) and sometimes out of order, so receive times put samples up to a second from
where they were taken. Most
messages carry the autopilot's own stamp (``time_boot_ms``, or ``time_usec`` since boot),
taken with the sample; :func:`boot_time_base` puts every message on that clock:

- a stamped message at its stamp plus the epoch's median receive offset (so the times
  stay near the receive clock, UTC seconds);
- a message without a stamp (VFR_HUD, the HEARTBEATs that give the mode changes) at the
  latest stamp of the packets before it in the file: the link keeps the order packets
  are sent in, and a packet is sent after every sample sent before it was taken (where
  the last stamped packet before it arrived more than :data:`NEIGHBOUR_GAP_S` earlier: at
  its receive time less the link's latency around then, the median receive offset of the
  stamped packets in :data:`LATENCY_BIN_S` bins);
- a stamp more than :data:`STAMP_TOLERANCE_S` from that latency line (garbage, or a reset
  the epochs did not catch) is not trusted: that packet is placed as an unstamped one;
- packets of one type at the same time (unstamped ones placed at the same latest stamp)
  are spread evenly up to the next one's time;
- a 32-bit ``time_usec`` that wrapped (every 71.6 min) is unwrapped;
- an autopilot reboot (the receive offset jumping by more than :data:`EPOCH_JUMP_S`)
  starts an epoch with its own offset;
- each message type is sorted by its new times (packets that arrived out of order go
  back in place) and exact repeats (same stamp, same values: a packet heard on two links)
  are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.ingest.rawlog import Table

#: a jump of the receive offset larger than this (s) is a reboot of the autopilot
EPOCH_JUMP_S = 10.0
#: a stamp further than this (s) from the link's latency line is not trusted
STAMP_TOLERANCE_S = 5.0
#: bin width (s of receive time) of the latency line
LATENCY_BIN_S = 5.0
#: an unstamped packet is placed by the stamped packets before it if the last arrived at most this much earlier (s)
NEIGHBOUR_GAP_S = 2.0
_WRAP32_S = 2**32 * 1e-6


def stamps(tab: Table) -> tuple[np.ndarray, str] | None:
    """Since-boot stamps [s] of a table's rows (n,) and the field they came from, or None
    (no stamp field, a ``time_usec`` in UNIX time, or a stamp that never moves)."""
    if "time_boot_ms" in tab:
        b, name = np.asarray(tab["time_boot_ms"], float) * 1e-3, "time_boot_ms"
    elif "time_usec" in tab:
        b, name = np.asarray(tab["time_usec"], float) * 1e-6, "time_usec"
        if b.size and np.nanmax(b) >= 1e8:  # UNIX time, not since boot
            return None
        if b.size and np.nanmax(b) < _WRAP32_S:  # maybe a 32-bit counter
            b = _unwrap32(b, tab.t)
    else:
        return None
    if b.size < 2 or not np.any(np.isfinite(b)) or np.nanmax(b) == np.nanmin(b):
        return None
    return b, name


def _unwrap32(b: np.ndarray, recv: np.ndarray) -> np.ndarray:
    """Unwrap a 32-bit microsecond counter [s] (n,) received at ``recv`` [s]: where the
    receive offset (receive - stamp) jumps by more than :data:`EPOCH_JUMP_S`, a jump of
    about 2^32 us is a wrap, any other a reboot (which restarts the count of wraps)."""
    jumps = np.flatnonzero(np.abs(np.diff(recv - b)) > EPOCH_JUMP_S)
    if jumps.size == 0:
        return b
    add = np.zeros(b.size)
    count = 0
    for i in jumps:
        wrap = abs((recv[i + 1] - b[i + 1]) - (recv[i] - b[i]) - _WRAP32_S) < STAMP_TOLERANCE_S
        count = count + 1 if wrap else 0
        add[i + 1 :] = count * _WRAP32_S
    return b + add


@dataclass
class BootClock:
    """The receive-to-autopilot clock map of one .tlog (:meth:`fit`).

    Epochs follow the file's order, not the receive times: the ground station writes the
    packets as they arrive, so where its clock jumps back, later packets carry earlier
    receive times than packets before them in the file.

    edges : (n_epochs - 1,) file positions (packet numbers) where an epoch starts: the
        receive offset jumps there.
    at : (n_epochs - 1,) the receive time [s] of each epoch's first packet (for messages).
    c : per epoch the offset [s] that puts its stamps on the log's clock: its median
        receive offset (receive - stamp) after a reboot (the stamps start again); the
        epoch before's after a jump of the ground station's clock (the stamps go on, so the
        flight's times do too).
    centres, offsets : per epoch the latency line, bin centres [s] (receive time) and the
        median receive offset in each bin [s].
    reboot : (n_epochs - 1,) whether each edge is an autopilot reboot (else a jump of the
        receive clock).
    """

    edges: np.ndarray
    at: np.ndarray
    c: np.ndarray
    centres: list[np.ndarray]
    offsets: list[np.ndarray]
    reboot: np.ndarray

    @classmethod
    def fit(cls, recv: np.ndarray, stamp: np.ndarray, seq: np.ndarray) -> BootClock:
        """From every stamped packet's receive time and stamp [s] and file position (1-D,
        any order)."""
        order = np.argsort(seq, kind="stable")
        r, o, q = recv[order], (recv - stamp)[order], seq[order]
        keep = np.isfinite(o) & np.isfinite(r)
        r, o, q = r[keep], o[keep], q[keep]
        st = stamp[order][keep]
        # epochs: the running median of the offset (31 packets) jumps at a reboot
        w = min(31, r.size) | 1
        med = np.median(np.lib.stride_tricks.sliding_window_view(np.pad(o, w // 2, mode="edge"), w), axis=1)
        cut = np.flatnonzero(np.abs(np.diff(med)) > EPOCH_JUMP_S)
        bounds = np.concatenate([[0], cut + 1, [r.size]])
        c, centres, offsets, reboot = [], [], [], []
        for e, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
            rr, oo = r[a:b], o[a:b]
            # a reboot starts the stamps again; where they go on, the receive clock jumped
            again = e > 0 and np.median(st[a : a + w]) < np.median(st[max(bounds[e - 1], a - w) : a]) - EPOCH_JUMP_S
            if e > 0:
                reboot.append(bool(again))
            c.append(float(np.median(oo)) if e == 0 or again else c[-1])
            srt = np.argsort(rr, kind="stable")
            rr, oo = rr[srt], oo[srt]
            k = np.floor((rr - rr[0]) / LATENCY_BIN_S).astype(int)
            bins = [k == j for j in np.unique(k)]
            centres.append(np.array([np.median(rr[s]) for s in bins]))
            offsets.append(np.array([np.median(oo[s]) for s in bins]))
        return cls(q[cut + 1], r[cut + 1], np.asarray(c), centres, offsets, np.asarray(reboot, dtype=bool))

    def epoch(self, seq: np.ndarray) -> np.ndarray:
        """Epoch index (n,) of the packets at file positions ``seq``."""
        return np.searchsorted(self.edges, seq, side="right")

    def from_receive(self, recv: np.ndarray, seq: np.ndarray) -> np.ndarray:
        """Times [s] of packets received at ``recv`` [s] (file positions ``seq``) by the
        latency line: the receive time less the offset around then, plus the epoch's
        median offset."""
        e = self.epoch(seq)
        out = np.empty(recv.shape)
        for k in np.unique(e):
            sel = e == k
            out[sel] = recv[sel] - np.interp(recv[sel], self.centres[k], self.offsets[k]) + self.c[k]
        return out

    def from_stamps(self, recv: np.ndarray, stamp: np.ndarray, seq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Times [s] of stamped packets (stamp + the epoch's offset) and a mask of the
        stamps trusted (within :data:`STAMP_TOLERANCE_S` of the latency line)."""
        t = stamp + self.c[self.epoch(seq)]
        ok = np.isfinite(t) & (np.abs(t - self.from_receive(recv, seq)) <= STAMP_TOLERANCE_S)
        return t, ok


def _after_stamped(
    seq: np.ndarray, recv: np.ndarray, ref_seq: np.ndarray, ref_t: np.ndarray, ref_recv: np.ndarray, clock: BootClock
) -> np.ndarray:
    """Times [s] of unstamped packets at file positions ``seq`` (n,) received at ``recv``:
    the latest stamp among the trusted stamped packets before them in the file (``ref_seq``
    sorted, their times ``ref_t`` and receive times ``ref_recv``) - a packet is sent after
    every sample sent before it was taken - where the last of those arrived at most
    :data:`NEIGHBOUR_GAP_S` before; by the latency line elsewhere."""
    t = clock.from_receive(recv, seq)
    if ref_seq.size == 0 or seq.size == 0:
        return t
    j = np.searchsorted(ref_seq, seq) - 1
    latest = np.maximum.accumulate(ref_t)[np.maximum(j, 0)]
    ok = (j >= 0) & (recv - ref_recv[np.maximum(j, 0)] <= NEIGHBOUR_GAP_S)
    return np.where(ok, latest, t)


def _drop_repeats(t: np.ndarray, columns: dict[str, np.ndarray]) -> np.ndarray:
    """Mask (n,) of the rows to keep of a table sorted by time: a row equal to the one
    before in time and every column is a repeat."""
    same = np.diff(t) == 0
    for col in columns.values():
        same &= (
            (col[1:] == col[:-1])
            if col.dtype != object
            else np.array([a == b for a, b in zip(col[1:], col[:-1])], bool)
        )
    return np.concatenate([[True], ~same])


def _spread_ties(t: np.ndarray) -> np.ndarray:
    """Sorted times (n,) with each run of equal times spread evenly from its time to the
    next distinct one (the last run over the table's median interval): unstamped packets
    of one type placed at the same latest stamp were sent one after the other."""
    d = np.diff(t)
    if t.size < 2 or not np.any(d == 0):
        return t
    step = float(np.median(d[d > 0])) if np.any(d > 0) else 0.0
    start = np.concatenate([[True], d > 0])
    first = np.flatnonzero(start)
    run = np.cumsum(start) - 1  # run index of each sample
    size = np.diff(np.concatenate([first, [t.size]]))
    nxt = np.concatenate([t[first[1:]], [t[first[-1]] + step]])
    pos = np.arange(t.size) - first[run]
    return t[first[run]] + pos * (nxt[run] - t[first[run]]) / size[run]


def boot_time_base(
    tables: dict[str, Table], seq: dict[str, np.ndarray], modes: list[tuple[float, str]] = (), mode_seq: list[int] = ()
) -> tuple[str, list[tuple[float, str]]] | None:
    """Put every table of a .tlog on the autopilot's clock (module docstring), in place.

    tables : message name -> :class:`Table` with receive times ``t`` [s].
    seq : message name -> (n,) position of each row's packet in the file.
    modes, mode_seq : (receive time [s], mode name) mode changes and their packets'
        positions, placed as unstamped packets.

    Returns the time-base sentence and the modes on the new clock, or None (tables
    untouched) when no message carries a usable stamp."""
    own = {n: s for n, tab in tables.items() if (s := stamps(tab)) is not None}
    if not own:
        return None
    clock = BootClock.fit(
        np.concatenate([tables[n].t for n in own]),
        np.concatenate([s[0] for s in own.values()]),
        np.concatenate([np.asarray(seq[n]) for n in own]),
    )
    new_t, trusted = {}, {}
    for name in own:
        new_t[name], trusted[name] = clock.from_stamps(tables[name].t, own[name][0], np.asarray(seq[name]))
    ref_seq, ref_t, ref_recv = (
        np.concatenate([a[n][trusted[n]] for n in own]) for a in (seq, new_t, {n: tables[n].t for n in own})
    )
    order = np.argsort(ref_seq, kind="stable")
    ref_seq, ref_t, ref_recv = ref_seq[order], ref_t[order], ref_recv[order]
    place = lambda s, r: _after_stamped(
        np.asarray(s),
        np.asarray(r, float),  # noqa: E731
        ref_seq,
        ref_t,
        ref_recv,
        clock,
    )
    untrusted = 0
    for name in tables:
        if name in own:
            bad = ~trusted[name]
            untrusted += int(bad.sum())
            if bad.any():
                new_t[name][bad] = place(seq[name][bad], tables[name].t[bad])
        else:
            new_t[name] = place(seq[name], tables[name].t)
    reordered = dropped = 0
    for name, tab in tables.items():
        t = new_t[name]
        idx = np.argsort(t, kind="stable")
        reordered += int(np.sum(idx != np.arange(t.size)))
        t, cols = t[idx], {k: v[idx] for k, v in tab.columns.items()}
        if name in own and t.size > 1:
            keep = _drop_repeats(t, cols)
            if not keep.all():
                dropped += int((~keep).sum())
                t, cols = t[keep], {k: v[keep] for k, v in cols.items()}
        tab.t, tab.columns = _spread_ties(t), cols
    mapped = [(float(t), m) for t, (_, m) in zip(place(mode_seq, [t for t, _ in modes]), modes)] if len(modes) else []
    fields = sorted({s[1] for s in own.values()})
    text = f"autopilot stamps ({' / '.join(fields)}) + the median receive offset {clock.c[0]:.3f} s"
    if clock.reboot.any():
        text += (
            f"; {int(clock.reboot.sum())} autopilot reboot(s) at receive time "
            + ", ".join(f"{e:.1f}" for e in clock.at[clock.reboot])
            + " s, each boot with its own offset"
        )
    if (~clock.reboot).any():
        text += (
            "; the ground station's clock jumped at receive time "
            + ", ".join(f"{e:.1f}" for e in clock.at[~clock.reboot])
            + " s (the autopilot's stamps went on: times follow them)"
        )
    unstamped = sorted(n for n in tables if n not in own)
    if unstamped:
        text += (
            f"; messages without stamps ({', '.join(unstamped[:4])}"
            f"{' ...' if len(unstamped) > 4 else ''}) at the latest stamp sent before them"
        )
    text += f"; {reordered} samples reordered, {dropped} repeats dropped"
    if untrusted:
        text += f"; {untrusted} stamps more than {STAMP_TOLERANCE_S:g} s off the link's timing not trusted"
    return text, mapped
