"""Maneuver windows: a time span of a flight (:class:`SegmentSpec`) and the rules that cut,
merge and bound them. Times are seconds from the log's start
(:meth:`pipeline.ingest.flightdata.FlightData.from_log_start`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: the longest maneuver found in a log (:meth:`~pipeline.ingest.flightdata.FlightData.find_segments`) [s]: longer spans
#: of control activity are cut into pieces. 60 s keeps a designed maneuver whole (sweeps of
#: 20-60 s, multisines of 10-20 s per cycle) and gives a continuous 200 s multisine 4 pieces
MAX_AUTO_SEGMENT_S = 60.0


@dataclass
class SegmentSpec:
    """A time span of the flight: ``t0 <= t <= t1`` [s from the log's start].

    kind : "time" (given: a user's range or an archive's named window), "mode" (one flight
        mode), "auto" (control activity)
    axis : the control input whose maneuver it is (None: none)
    """

    name: str
    t0: float
    t1: float
    kind: str = "time"
    mode: str | None = None
    axis: str | None = None

    @property
    def duration(self) -> float:
        return float(self.t1 - self.t0)

    def as_dict(self) -> dict:
        return {
            "name": self.name,
            "t0": float(self.t0),
            "t1": float(self.t1),
            "kind": self.kind,
            "mode": self.mode,
            "axis": self.axis,
            "duration": self.duration,
        }


def between_gaps(a: float, b: float, gaps: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """The pieces of ``a..b`` [s] outside the ``gaps`` [(start, end) s, sorted]."""
    out = []
    for g0, g1 in gaps:
        if g1 <= a or g0 >= b:
            continue
        if g0 > a:
            out.append((a, g0))
        a = g1
    if b > a:
        out.append((a, b))
    return out


def cut_span(t0: float, t1: float, max_duration: float | None = MAX_AUTO_SEGMENT_S) -> list[tuple[float, float]]:
    """``t0..t1`` [s] as equal pieces no longer than ``max_duration`` (itself when it is
    not longer, or max_duration is None)."""
    n = 1 if not max_duration else max(int(np.ceil((t1 - t0) / max_duration - 1e-9)), 1)
    e = np.linspace(t0, t1, n + 1)
    return [(float(a), float(b)) for a, b in zip(e[:-1], e[1:])]


def merge_overlapping(specs: Sequence[SegmentSpec]) -> list[SegmentSpec]:
    """Windows that overlap in time merged into one (their union, axes joined with '+').
    Surfaces moved together (aileron and rudder in a cross-controlled sideslip, elevator
    and throttle, all three in a multi-axis multisine) give one detected window per
    surface over the same span; fitting each would count that data once per window
    (Cramer-Rao bounds too small by sqrt(2) for two) and, when one of them is the
    held-out window, fit the data the proof of match is run on. Every fit over a log's
    windows takes them through here: the axis problems, a user model's, and the
    compatibility stage's reconstruction. Found (auto) windows that merge into one longer
    than :data:`MAX_AUTO_SEGMENT_S` (the pieces of continuous excitation on both surfaces
    chain) are cut again, as :meth:`FlightData.find_segments` cuts them, named
    ``auto_<axes>_<k>``."""
    out: list[SegmentSpec] = []
    for s in sorted(specs, key=lambda s: s.t0):
        if out and s.t0 < out[-1].t1:
            a = out[-1]
            axes = "+".join(dict.fromkeys((a.axis or "").split("+") + [s.axis or ""]))
            name = a.name if s.name in a.name.split("+") else f"{a.name}+{s.name}"  # a range's copies per axis
            out[-1] = SegmentSpec(name, a.t0, max(a.t1, s.t1), a.kind, a.mode, axes)
        else:
            out.append(s)
    cut: list[SegmentSpec] = []
    for s in out:
        pieces = cut_span(s.t0, s.t1) if s.kind == "auto" and "+" in s.name else [(s.t0, s.t1)]
        if len(pieces) == 1:
            cut.append(s)
            continue
        k0 = sum(c.name.startswith(f"auto_{s.axis}_") for c in cut)
        cut += [SegmentSpec(f"auto_{s.axis}_{k0 + i}", a, b, s.kind, s.mode, s.axis) for i, (a, b) in enumerate(pieces)]
    return cut
