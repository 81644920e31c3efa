"""Control inputs logged more slowly than the fit's grid: the unknown time of each step.

A log's surface positions are often slower than its IMU (ArduPilot's RCOU at 10-25 Hz
beside a 50-400 Hz IMU). The fits read an input between its samples by linear
interpolation. For a smooth input (a sweep, a multisine, a pilot's stick) that is close
to the truth. A step (a doublet, a 3-2-1-1 flown by the flight computer) happened at an
unknown time between the two samples that bracket it: the linear ramp between them is
its expectation when that time is uniform over the interval (std h / sqrt(12), h the
sample interval), but each step keeps its own timing error, and output error, which
takes the inputs as exact, books those errors on the derivatives with a Cramér-Rao bound
that knows nothing of them. Measured (default.toml, its surfaces logged at 25 Hz beside
the 100 Hz IMU; seed 1, the .bin's fits; ad hoc): the longitudinal output error put Cmq
11-28 std off the truth, whatever the phase of the 25 Hz samples against the steps.

This module finds those steps (:func:`step_edges`) and moves one step in a log
(:func:`with_edge_moved`), so :func:`pipeline.correction_uncertainty.input_sampling` can
carry the timing uncertainty to the estimates as a consider part, by refits, as it
carries the sensor corrections' and the wind's.

A step is a sample-to-sample change of a control input that stands out: at least
``STEP_RATIO`` times both neighbouring changes and at least ``MIN_STEP_RAD``; only inputs
whose sample interval exceeds ``SLOW_FACTOR`` fit-grid steps count (at the grid's rate the
interpolation puts a step within one grid step of where it was).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.flightdata import CONTROL_INPUTS, Channel, FlightData

#: a step's change is at least this many times its neighbouring changes ...
STEP_RATIO = 4.0
#: ... and at least this large [rad] (0.2 deg: below any designed maneuver's steps)
MIN_STEP_RAD = np.radians(0.2)
#: an input counts as slow when its sample interval exceeds this many fit-grid steps
SLOW_FACTOR = 1.5


@dataclass(frozen=True)
class Edge:
    """One step of control input ``channel`` between its samples ``k`` and ``k + 1``
    (times ``t0``, ``t1`` [s]); ``size`` the change [rad]; ``std`` [s] the uncertainty of
    its time, (t1 - t0) / sqrt(12)."""

    channel: str
    k: int
    t0: float
    t1: float
    size: float

    @property
    def std(self) -> float:
        return (self.t1 - self.t0) / np.sqrt(12.0)

    @property
    def name(self) -> str:
        return f"{self.channel} step at {0.5 * (self.t0 + self.t1):.3f} s"


def step_edges(fd: FlightData, spans: Sequence[tuple[float, float]], grid_step_s: float,
               channels: Sequence[str] = CONTROL_INPUTS) -> list[Edge]:
    """The steps (:class:`Edge`, in time order) of the control inputs ``channels`` slower
    than the fit grid (sample interval > SLOW_FACTOR x ``grid_step_s`` [s]) that lie in
    one of ``spans`` ((start, end) [s], the fitted windows)."""
    out: list[Edge] = []
    for c in channels:
        if c not in fd.channels or c == "throttle" or len(fd[c]) < 4:
            continue
        ch = fd[c]
        t, u = np.asarray(ch.t, float), np.asarray(ch.values, float)
        h = np.diff(t)
        d = np.abs(np.diff(u))
        if float(np.median(h)) <= SLOW_FACTOR * grid_step_s:
            continue
        nb = np.maximum(np.r_[0.0, d[:-1]], np.r_[d[1:], 0.0])      # the larger neighbour
        step = (d >= MIN_STEP_RAD) & (d >= STEP_RATIO * nb) & (h > SLOW_FACTOR * grid_step_s)
        inside = np.zeros_like(step)
        for a, b in spans:
            inside |= (t[1:] > a) & (t[:-1] < b)
        out += [Edge(c, int(k), float(t[k]), float(t[k + 1]), float(u[k + 1] - u[k]))
                for k in np.flatnonzero(step & inside)]
    return sorted(out, key=lambda e: (e.t0, e.channel))


def with_edges_moved(fd: FlightData, edges: Sequence[Edge], shifts: Sequence[float]) -> FlightData:
    """``fd`` with each step of ``edges`` moved by ``shifts`` [s] (same length; |shift| <
    the edge's interval / 2): a later step holds the earlier sample's value longer (that
    sample's time moves 2 x shift later), an earlier one takes the later value sooner
    (that sample's time moves 2 x |shift| earlier). The linear ramp's centre moves by the
    shift; moved either way by the same amount, the ramps are equally narrow, so a central
    difference sees the timing alone. The data are copied, never changed in place."""
    chans = dict(fd.channels)
    for c in sorted({e.channel for e in edges}):
        ch = chans[c]
        t = np.array(ch.t, dtype=float)
        for e, s in zip(edges, shifts):
            if e.channel != c or s == 0.0:
                continue
            if abs(s) >= 0.5 * (e.t1 - e.t0):
                raise ValueError(f"{e.name}: a shift of {s:+.4f} s leaves its interval")
            if s > 0:
                t[e.k] = e.t0 + 2.0 * s
            else:
                t[e.k + 1] = e.t1 + 2.0 * s
        chans[c] = Channel(t, ch.values, ch.unit, ch.source, ch.notes, ch.derived)
    return FlightData(chans, fd.meta, fd.segments)
