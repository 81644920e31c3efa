"""Where things go in run.rrd: entity-path parts, colours, SI units of the series, and the
place of every segment on the ``t`` and ``segment`` timelines (layout in the module doc of
:mod:`pipeline.outputs.recording`)."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from estimators import EstimationResult
from pipeline.registry import method_colour
from pipeline.validation import display_unit

#: gap in s between segments laid end to end on the ``t`` timeline
SEGMENT_GAP = 1.0
#: colours of the measured, truth and data lines (RGB); the methods' are the catalogue's
COLORS = {"measured": (40, 40, 40), "truth": (200, 160, 0), "data": (40, 40, 40)}


def entity_part(name: str) -> str:
    """One entity-path part from a name: characters outside [A-Za-z0-9_.-] become '_'."""
    return re.sub(r"[^A-Za-z0-9_.\-]", "_", str(name))


def method_color(key: str, order: Sequence[str]) -> tuple[int, int, int]:
    """The colour of a measured/truth/data line (COLORS) or of a method or result key
    (:func:`pipeline.registry.method_colour`)."""
    return COLORS[key] if key in COLORS else method_colour(key, order)


def si_unit(channel: str) -> str:
    """The SI unit of a canonical channel, for the legends (the series are SI)."""
    fac, unit = display_unit(channel)
    if fac == 1.0:
        return unit
    return {"deg": "rad", "deg/s": "rad/s", "deg/s^2": "rad/s^2", "g": "m/s^2"}[unit]


def segment_starts(
    t_list: Sequence[np.ndarray], gap: float = SEGMENT_GAP, origin: float = 0.0, start: float = 0.0
) -> list[float]:
    """Offset in s to add to each segment's own times (t, (N_k,)) on the shared ``t`` line:
    ``-origin`` for all when the segments are pairwise disjoint in time (pieces of one log:
    they keep their times, counted from ``origin``, the log's start), else end to end in
    the given order from ``start``, each ``gap`` s after the previous one ends."""
    t_list = [np.asarray(t, dtype=float) for t in t_list]
    spans = sorted((float(t[0]), float(t[-1])) for t in t_list)
    if all(a1 < b0 for (_, a1), (b0, _) in zip(spans, spans[1:])):
        return [-float(origin)] * len(t_list)
    offs, at = [], float(start)
    for t in t_list:
        offs.append(at - float(t[0]))
        at += float(t[-1] - t[0]) + gap
    return offs


def _sig(t, name: str) -> tuple[float, float, int, str]:
    """Identity of a segment: its name and its own times (first, last, count)."""
    t = np.asarray(t, dtype=float)
    return (round(float(t[0]), 9), round(float(t[-1]), 9), int(t.size), str(name))


def segment_names(r: EstimationResult) -> list[str]:
    """Names of a result's fitted segments: ``Segment.name``, or ``#k`` when unnamed or when
    the result keeps no Segment objects (a regression)."""
    segs = r.segments if len(r.segments) == len(r.predicted) else [None] * len(r.predicted)
    return [(s.name if s is not None and s.name else f"#{k}") for k, s in enumerate(segs)]


class SegmentLayout:
    """Where every distinct segment sits on ``t`` and its ``segment`` index.

    Segments are told apart by name and times (:func:`_sig`); the same maneuver fitted by
    several methods is one segment. Order of first appearance: for each result its fitted
    segments, then its held-out ones. Offsets from :func:`segment_starts` over that order."""

    def __init__(
        self,
        results: Mapping[str, EstimationResult],
        validations: Mapping[str, Mapping[str, Any]],
        origin: float = 0.0,
        start: float = 0.0,
    ) -> None:
        """``origin``: the log's start on its time base [s] (segments at their own times
        are shown from it); ``start``: where segments laid end to end begin on ``t`` [s]
        (after the whole flight when the recording shows it)."""
        times: dict[tuple, np.ndarray] = {}
        self.held_out: set[tuple] = set()
        for m, r in results.items():
            for p, name in zip(r.predicted, segment_names(r)):
                times.setdefault(_sig(p.index, name), np.asarray(p.index, dtype=float))
            for a in held_out_arrays(validations.get(m)):
                k = _sig(a["t"], a["name"])
                times.setdefault(k, np.asarray(a["t"], dtype=float))
                self.held_out.add(k)
        self.origin, self.start = float(origin), float(start)
        offs = segment_starts(list(times.values()), origin=self.origin, start=self.start) if times else []
        self.index = {k: i for i, k in enumerate(times)}
        self.offset = dict(zip(times, offs))

    def place(self, t, name: str) -> tuple[float, int]:
        """(offset s, segment index) of segment ``name`` with own times t; unseen ones keep
        their own times when they and every segment so far do, else are appended after the
        last one."""
        k = _sig(t, name)
        if k not in self.index:
            overlap = any(not (k[1] < s[0] or s[1] < k[0]) for s in self.offset)
            if overlap or any(o != -self.origin for o in self.offset.values()):
                end = max((s[1] + o + SEGMENT_GAP for s, o in self.offset.items()), default=self.start)
                self.offset[k] = max(end, self.start) - k[0]
            else:
                self.offset[k] = -self.origin
            self.index[k] = len(self.index)
        return self.offset[k], self.index[k]

    def spans(self) -> list[tuple[str, float, float, bool]]:
        """Every segment placed so far: (name, first and last time on ``t`` [s], held out)."""
        return [(k[3], k[0] + o, k[1] + o, k in self.held_out) for k, o in self.offset.items()]

    def cat(
        self, frames: Sequence[pd.DataFrame], names: Sequence[str], times: Sequence[Any] | None = None
    ) -> tuple[np.ndarray, np.ndarray, pd.DataFrame]:
        """Concatenate per-segment DataFrames on t (or with explicit own ``times``) of the
        named segments into (t_run (N,), segment (N,), values)."""
        times = [df.index for df in frames] if times is None else times
        ts, sg = [], []
        for df, t, name in zip(frames, times, names):
            o, k = self.place(t, name)
            ts.append(np.asarray(t, dtype=float) + o)
            sg.append(np.full(len(df), k, dtype=np.int64))
        vals = pd.concat([df.reset_index(drop=True) for df in frames], ignore_index=True)
        return np.concatenate(ts), np.concatenate(sg), vals


def held_out_arrays(v: Mapping[str, Any] | None) -> list[dict[str, Any]]:
    """The proof-of-match ``arrays["match"]`` entries of a validation (empty without)."""
    return list(((v or {}).get("arrays") or {}).get("match") or [])
