"""The canonical flight-data container every reader produces.

Units and names follow DESIGN.md section 3: SI units, body axes x forward / y right /
z down, angles in rad, NED velocities, altitude positive up. Each channel keeps its own
native sample times; :meth:`FlightData.resample` puts any subset on one common time base.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from scipy.signal import butter, sosfiltfilt

from estimators.statistics import difference_noise_std
from pipeline.errors import FsidError
from pipeline.ingest.sampling import (
    GAP_FACTOR,
    MAX_GRID_HZ,
    contiguous,
    sample_gaps,
    sample_rate,
    start_kind,
    uniform_grid,
)
from pipeline.ingest.segments import MAX_AUTO_SEGMENT_S as MAX_AUTO_SEGMENT_S
from pipeline.ingest.segments import SegmentSpec as SegmentSpec
from pipeline.ingest.segments import between_gaps, cut_span
from pipeline.ingest.segments import merge_overlapping as merge_overlapping

#: canonical channel name -> SI unit (DESIGN.md section 3)
CANONICAL_UNITS: dict[str, str] = {
    "t": "s",
    "ax": "m/s^2",
    "ay": "m/s^2",
    "az": "m/s^2",
    "p": "rad/s",
    "q": "rad/s",
    "r": "rad/s",
    "pdot": "rad/s^2",
    "qdot": "rad/s^2",
    "rdot": "rad/s^2",
    "phi": "rad",
    "theta": "rad",
    "psi": "rad",
    "V": "m/s",
    "alpha": "rad",
    "beta": "rad",
    "u": "m/s",
    "v": "m/s",
    "w": "m/s",
    "vn": "m/s",
    "ve": "m/s",
    "vd": "m/s",
    "h": "m",
    "qbar": "Pa",
    "rho": "kg/m^3",
    "de": "rad",
    "da": "rad",
    "dr": "rad",
    "throttle": "-",
    "thrust": "N",
    "x_n": "m",
    "y_e": "m",
    "z_d": "m",
    "q_w": "-",
    "q_x": "-",
    "q_y": "-",
    "q_z": "-",
}

#: channels holding angles that wrap at +-pi (interpolated unwrapped)
WRAPPED_ANGLES = ("phi", "psi")
#: control-input channels used for automatic segmentation
CONTROL_INPUTS = ("de", "da", "dr")
#: the channels whose gaps end a maneuver window (:meth:`FlightData.find_segments`), besides
#: the control input's own
GAP_CHANNELS = ("p", "q", "r", "ax", "ay", "az")


@dataclass
class Channel:
    """One canonical channel at its native rate.

    t : (n,) float64, seconds on the log's time base (see ``FlightData.meta['time_base']``)
    values : (n,) float64 in the SI unit ``unit``
    source : the log field it came from, e.g. ``"IMU[0].GyrX"``
    """

    t: np.ndarray
    values: np.ndarray
    unit: str
    source: str = ""
    notes: str = ""  #: e.g. the log's own unit metadata disagreeing with the map
    #: why the channel is no independent measurement (an autopilot's estimate computed
    #: from other channels, e.g. ArduPilot's AOA from the EKF velocity and wind); "" = a sensor
    derived: str = ""
    #: the stated white-noise std of a channel computed by the ingest (its unit; e.g. a pose's
    #: smoothed derivative, :mod:`pipeline.ingest.pose`); None = estimate it from the samples
    noise: float | None = None

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def rate_hz(self) -> float:
        """Sample rate [Hz] from the sample stamps (:func:`sample_rate`): gaps between
        maneuvers neither lower it nor count as irregular sampling."""
        return sample_rate(self.t)

    def gaps(self) -> list[tuple[float, float]]:
        """The gaps of this channel [(last sample before, first sample after) s]: intervals
        longer than GAP_FACTOR typical intervals (:func:`sample_gaps`)."""
        return sample_gaps(self.t)


@dataclass
class FlightData:
    """Canonical flight data: per-channel series at native rates, metadata, segments.

    channels : canonical name -> :class:`Channel` (SI units)
    meta : ``source`` (path), ``format``, ``map`` (map name), ``time_base`` (sentence
        saying which clock ``t`` is), ``params`` (dict name -> float), ``modes`` (list of
        ``(t_start [s], mode name)``), ``damage`` (dict or None: where the file stops being
        readable), ``unmapped`` (canonical name -> why it could not be filled), ``rates``.
    segments : user, mode or automatic segments (:class:`SegmentSpec`)
    """

    channels: dict[str, Channel] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    segments: list[SegmentSpec] = field(default_factory=list)

    # ----------------------------------------------------------------- access
    def __contains__(self, name: str) -> bool:
        return name in self.channels

    def __getitem__(self, name: str) -> Channel:
        return self.channels[name]

    @property
    def names(self) -> list[str]:
        return list(self.channels)

    @property
    def params(self) -> dict[str, float]:
        return self.meta.setdefault("params", {})

    @property
    def modes(self) -> list[tuple[float, str]]:
        return self.meta.setdefault("modes", [])

    @property
    def span(self) -> tuple[float, float]:
        """(first, last) sample time over all channels [s]; (nan, nan) when empty."""
        starts = [c.t[0] for c in self.channels.values() if len(c)]
        ends = [c.t[-1] for c in self.channels.values() if len(c)]
        if not starts:
            return (float("nan"), float("nan"))
        return (float(min(starts)), float(max(ends)))

    def rates(self) -> dict[str, float]:
        """Native rate of each channel [Hz] (:func:`sample_rate` of its stamps)."""
        return {k: c.rate_hz for k, c in self.channels.items()}

    def gaps(self, channels: Iterable[str] | None = None) -> list[tuple[float, float]]:
        """The gaps of ``channels`` (default: all) merged [(start, end) s, sorted]: the
        spans where one of them has no samples for longer than GAP_FACTOR of its typical
        intervals (:func:`sample_gaps`). A maneuver window never spans one."""
        spans = sorted(
            g for c in (self.names if channels is None else channels) if c in self.channels for g in self[c].gaps()
        )
        out: list[tuple[float, float]] = []
        for a, b in spans:
            if out and a < out[-1][1]:
                out[-1] = (out[-1][0], max(out[-1][1], b))
            else:
                out.append((a, b))
        return out

    def from_log_start(self) -> FlightData:
        """This flight with its times in seconds from the log's start (its first sample over
        all channels at t = 0): channels, flight modes and segments moved alike. Where t = 0
        is on the log's own clock goes to ``meta["t0_abs"]`` [s] (added to an earlier one)
        and its kind to ``meta["t0_kind"]`` (:func:`start_kind`; :func:`start_statement`
        says it in one sentence). Raw epoch or boot stamps (1.7e9 s) are unreadable in
        reports and lose precision in float text."""
        lo = self.span[0]
        shift = float(lo) if np.isfinite(lo) else 0.0
        meta = dict(self.meta)
        t0_abs = float(meta.get("t0_abs", 0.0)) + shift
        meta.update(t0_abs=t0_abs, t0_kind=meta.get("t0_kind") or start_kind(t0_abs))
        meta["modes"] = [(float(t) - shift, m) for t, m in self.modes]
        return FlightData(
            {k: replace(c, t=np.asarray(c.t, dtype=float) - shift) for k, c in self.channels.items()},
            meta,
            [replace(g, t0=g.t0 - shift, t1=g.t1 - shift) for g in self.segments],
        )

    def missing(self, channels: Iterable[str]) -> list[str]:
        """Those of ``channels`` this flight does not have (or has with no samples)."""
        return [c for c in channels if c not in self.channels or len(self.channels[c]) == 0]

    def explain_missing(self, channels: Iterable[str]) -> dict[str, str]:
        """``missing(channels)`` with the map's reason for each (e.g. "no ARSP messages")."""
        why = self.meta.get("unmapped", {})
        return {c: why.get(c, "not in the channel map") for c in self.missing(channels)}

    def noise_std(
        self, name: str, windows: Sequence[tuple[float, float]] | None = None, rate_hz: float | None = None
    ) -> float:
        """White measurement-noise std of channel ``name`` (its unit) from its own native
        samples (second differences, estimators.statistics.difference_noise_std), pooled
        over ``windows`` [(t0, t1) s] (default: all samples). With ``rate_hz``: the std the
        same noise has on a grid from :meth:`resample` at that rate
        (:func:`resample_noise_gain`). NaN with fewer than 4 samples in every window.
        A channel with a stated ``Channel.noise`` (computed by the ingest) returns that.
        Native samples keep white noise white, and a fast signal's curvature (a rate
        driven by turbulence) leaks into the second differences less than on a slower
        grid."""
        ch = self.channels[name]
        if ch.noise is not None:  # smoothed: its second differences would understate it
            return float(ch.noise)
        t, v = np.asarray(ch.t, dtype=float), np.asarray(ch.values, dtype=float)
        spans = windows if windows is not None else [(-np.inf, np.inf)]
        parts = [v[(t >= a) & (t <= b)][:, None] for a, b in spans]
        parts = [p for p in parts if p.shape[0] >= 4]
        if not parts:
            return float("nan")
        sd = float(difference_noise_std(parts)[0])
        return sd * resample_noise_gain(ch.rate_hz, rate_hz) if rate_hz else sd

    # ----------------------------------------------------------------- resampling
    def resample(
        self,
        rate_hz: float,
        channels: Sequence[str] | None = None,
        *,
        t0: float | None = None,
        t1: float | None = None,
        span: str = "common",
        antialias: bool = True,
        unwrap: bool = False,
        max_gap: float | None = None,
    ) -> pd.DataFrame:
        """Channels on one uniform time base.

        Parameters
        ----------
        rate_hz : output rate [Hz], above 0 and at most MAX_GRID_HZ (else FsidError); spans
            far from every sample are left out of the grid (:func:`uniform_grid`)
        channels : canonical names (default: all present); absent names are skipped
        t0, t1 : limits [s] (default from ``span``)
        span : "common" (overlap of the channels) or "union" (NaN where a channel has no data)
        antialias : low-pass (zero-phase 4th-order Butterworth at 0.4 x rate_hz) channels
            sampled faster than ``rate_hz`` before interpolating
        unwrap : keep phi/psi unwrapped (continuous) instead of wrapping to (-pi, pi]
        max_gap : samples further than this [s] from native data become NaN
            (default: 5 native periods, at least 2 output periods)

        Returns
        -------
        DataFrame with column ``t`` [s] and one column per channel, SI units; shape (N, 1 + n).
        """
        if not 0 < rate_hz <= MAX_GRID_HZ:
            raise FsidError(
                f"a grid rate of {rate_hz:g} Hz: give a rate above 0 and at most {MAX_GRID_HZ:g} Hz "
                "(the sensors' own rates are typically 10-1000 Hz)"
            )
        names = [
            c
            for c in (channels if channels is not None else self.names)
            if c in self.channels and len(self.channels[c]) > 0
        ]
        if not names:
            return pd.DataFrame({"t": np.zeros(0)})
        starts = np.array([self.channels[c].t[0] for c in names])
        ends = np.array([self.channels[c].t[-1] for c in names])
        if span == "common":
            lo, hi = float(starts.max()), float(ends.min())
        else:
            lo, hi = float(starts.min()), float(ends.max())
        lo = lo if t0 is None else float(t0)
        hi = hi if t1 is None else float(t1)
        t = uniform_grid(lo, hi, rate_hz, [self.channels[c].t for c in names])
        out = {"t": t}
        for c in names:
            out[c] = _resample_channel(
                self.channels[c], t, rate_hz, antialias, unwrap or c not in WRAPPED_ANGLES, c in WRAPPED_ANGLES, max_gap
            )
        return pd.DataFrame(out)

    # ----------------------------------------------------------------- segments
    def add_segment(self, t0: float, t1: float, name: str | None = None) -> SegmentSpec:
        """Add a user segment ``t0..t1`` [s] and return it."""
        seg = SegmentSpec(name or f"time_{len(self.segments)}", float(t0), float(t1), "time")
        self.segments.append(seg)
        return seg

    def mode_segments(self, min_duration: float = 0.0) -> list[SegmentSpec]:
        """One segment per flight-mode interval (from ``meta['modes']``), clipped to the data."""
        lo, hi = self.span
        modes = sorted(self.modes, key=lambda m: m[0])
        segs: list[SegmentSpec] = []
        for i, (ts, name) in enumerate(modes):
            te = modes[i + 1][0] if i + 1 < len(modes) else hi
            a, b = max(ts, lo), min(te, hi)
            if b - a >= min_duration and b > a:
                segs.append(SegmentSpec(f"mode_{i}_{name}", float(a), float(b), "mode", mode=name))
        return segs

    def find_segments(
        self,
        inputs: Sequence[str] = CONTROL_INPUTS,
        *,
        window: float = 1.0,
        threshold: float | None = None,
        pad_before: float = 1.0,
        pad_after: float = 3.0,
        min_duration: float = 2.0,
        rate_hz: float = 50.0,
        max_duration: float | None = MAX_AUTO_SEGMENT_S,
    ) -> list[SegmentSpec]:
        """Segments where a control input is being moved (maneuvers).

        Activity is the moving standard deviation of each input over ``window`` [s]; an
        input is active where it exceeds ``threshold`` [rad] (default: max(0.25 x its peak
        moving std, 0.2 deg)). Active spans are padded, merged per axis and kept when at
        least ``min_duration`` [s] long. A span longer than ``max_duration`` [s] (continuous
        excitation: a long multisine, minutes of piloted or autopilot activity) is cut into
        equal pieces no longer than that, each fitted with its own initial state: one
        segment of 200 s could be neither fitted by a simulation that drifts over minutes
        nor held out for the proof of match (None: never cut). A gap in the input or in
        the IMU channels (:meth:`gaps`, GAP_CHANNELS) ends a segment: a window never spans
        one.
        """
        segs: list[SegmentSpec] = []
        for axis in inputs:
            if axis not in self.channels or len(self.channels[axis]) < 3:
                continue
            df = self.resample(rate_hz, [axis], antialias=False)
            t, x = df["t"].to_numpy(), df[axis].to_numpy()
            if t.size < 3:
                continue
            w = max(int(round(window * rate_hz)), 3)
            s = pd.Series(x).rolling(w, center=True, min_periods=2).std().to_numpy()
            s = np.nan_to_num(s)
            thr = threshold if threshold is not None else max(0.25 * float(s.max()), np.radians(0.2))
            active = s > thr
            if not active.any():
                continue
            edges = np.flatnonzero(np.diff(np.r_[0, active.astype(np.int8), 0]))
            spans = [(t[a] - pad_before, t[min(b, t.size) - 1] + pad_after) for a, b in zip(edges[::2], edges[1::2])]
            merged: list[list[float]] = []
            for a, b in spans:
                a, b = max(a, t[0]), min(b, t[-1])
                if merged and a <= merged[-1][1]:
                    merged[-1][1] = max(merged[-1][1], b)
                else:
                    merged.append([a, b])
            # a gap in the input or the IMU ends a maneuver (a logging pause between two)
            cuts = self.gaps([axis, *GAP_CHANNELS])
            merged = [
                [a, b]
                for a0, b0 in merged
                for a, b in between_gaps(a0, b0, cuts)
                if b - a >= min_duration and active[(t >= a) & (t <= b)].any()
            ]
            pieces = [p for a, b in merged for p in cut_span(a, b, max_duration)]
            for k, (a, b) in enumerate(pieces):
                segs.append(SegmentSpec(f"auto_{axis}_{k}", float(a), float(b), "auto", axis=axis))
        segs.sort(key=lambda s: s.t0)
        return segs

    def moved_inputs(self, a: float, b: float) -> list[str]:
        """The control inputs moved within a..b [s] by more than MOVED_RAD (std), the most
        moved first: the axes of a window given by time or by name."""
        std = {c: _window_std(self[c], a, b) for c in CONTROL_INPUTS if c in self}
        return sorted((c for c, v in std.items() if v > MOVED_RAD), key=lambda c: -std[c])

    def answered_inputs(self, a: float, b: float) -> list[str]:
        """The control inputs whose axis' body rate (AXIS_RATE) moves within a..b [s] by
        more than ANSWER_RAD_S (std), the most moving first: the axes of a given window
        whose surfaces hardly move - a pulse and the free motion after it (a phugoid)."""
        std = {c: _window_std(self[r], a, b) for c, r in AXIS_RATE.items() if c in self and r in self}
        return sorted((c for c, v in std.items() if v > ANSWER_RAD_S), key=lambda c: -std[c])

    def chosen_segments(
        self, items: Sequence[str | tuple[float, float]], *, per_axis: bool = True
    ) -> list[SegmentSpec]:
        """The segments a user chose: each item a time range (t0, t1) [s from the log's
        start] or the name of a segment found in the log (``self.segments``, else its
        flight-mode and automatic ones: ``auto_de_0``, ``mode_2_FBWA``, ...). A range's
        control axes are those of the automatic segments it overlaps (else the inputs
        moved in it by more than 0.2 deg std, else those whose body rate moves by more than
        0.5 deg/s); with ``per_axis`` it gives one segment per
        axis over the same span (the problem builders pick theirs by axis), else one
        segment. FsidError for an empty or reversed range, one outside the log, or an
        unknown name (the names found are listed)."""
        if not items:
            return []
        by_name = any(isinstance(item, str) for item in items)
        found = (self.segments or (self.mode_segments() + self.find_segments())) if by_name else self.segments
        auto = ([g for g in found if g.kind == "auto"] or self.find_segments()) if per_axis else []
        lo, hi = self.span
        out: list[SegmentSpec] = []
        for item in items:
            if isinstance(item, str):
                hit = [g for g in found if g.name == item]
                if not hit:
                    names = ", ".join(g.name for g in found) or "none"
                    raise FsidError(
                        f"segment '{item}' is not in the log (found: {names}); give one of those names "
                        "or a range T0:T1 in seconds from the log's start"
                    )
                out += hit
                continue
            a, b = (float(x) for x in item)
            if not (np.isfinite(a) and np.isfinite(b) and a < b):
                raise FsidError(
                    f"segment {a:g}:{b:g} is empty or reversed; give T0:T1 with T0 < T1 in s from the start"
                )
            if b <= lo or a >= hi:
                raise FsidError(
                    f"segment {a:g}:{b:g} s is outside the log (0 to {hi - lo:.3f} s from its start); "
                    "give times in seconds from the log's start"
                )
            axes = list(dict.fromkeys(g.axis for g in auto if g.axis and g.t0 < b and g.t1 > a))
            axes = axes or self.moved_inputs(a, b) or self.answered_inputs(a, b)
            name = f"time_{a:g}-{b:g}s"
            out += [SegmentSpec(name, a, b, "time", axis=x) for x in (axes if per_axis else [None])] or [
                SegmentSpec(name, a, b, "time")
            ]
        return out

    def segment_frames(
        self, rate_hz: float, channels: Sequence[str] | None = None, segments: Sequence[SegmentSpec] | None = None, **kw
    ) -> list[pd.DataFrame]:
        """One resampled DataFrame per segment (default: ``self.segments``)."""
        segs = list(segments if segments is not None else self.segments)
        return [self.resample(rate_hz, channels, t0=s.t0, t1=s.t1, **kw) for s in segs]

    # ----------------------------------------------------------------- conversion
    @classmethod
    def from_frame(cls, df: pd.DataFrame, *, time: str = "t", meta: dict | None = None, source: str = "") -> FlightData:
        """Build from a DataFrame whose columns are canonical names in SI units."""
        t = df[time].to_numpy(dtype=float)
        chans = {
            c: Channel(t.copy(), df[c].to_numpy(dtype=float), CANONICAL_UNITS.get(c, ""), f"{source}{c}")
            for c in df.columns
            if c != time
        }
        return cls(chans, dict(meta or {}), [])

    def summary(self) -> str:
        """Short text: one line per channel with samples, rate, span and source."""
        lines = [
            f"{self.meta.get('format', '?')} {self.meta.get('source', '')}",
            f"time base: {self.meta.get('time_base', '?')}",
        ]
        for k, c in self.channels.items():
            lines.append(f"  {k:9s} {len(c):8d} samples {c.rate_hz:8.2f} Hz  [{c.unit}]  <- {c.source}")
        return "\n".join(lines)


#: a control input moved by more than this std [rad] in a given window moves its axis
MOVED_RAD = np.radians(0.2)
#: a body rate moving by more than this std [rad/s] answers its axis (a given window's
#: axis when no surface moves; the response a maneuver must cause)
ANSWER_RAD_S = np.radians(0.5)
#: the body rate that answers each control input
AXIS_RATE = {"de": "q", "da": "p", "dr": "r"}


def _window_std(ch: Channel, a: float, b: float) -> float:
    """Std of channel ``ch``'s finite samples within a..b [s] (0 with fewer than two)."""
    v = np.asarray(ch.values, dtype=float)[(ch.t >= a) & (ch.t <= b)]
    v = v[np.isfinite(v)]
    return float(v.std()) if v.size > 1 else 0.0


#: the fits' grid runs at least this fast [Hz] (:func:`fit_grid_rate`): 100 Hz with room
#: for a 100 Hz IMU whose jittered stamps measure 99.8 Hz (it keeps its own grid)
MIN_GRID_HZ = 90.0


def fit_grid_rate(fastest_hz: float, max_rate_hz: float) -> float:
    """The rate [Hz] of the grid the models are integrated and compared on: the fastest
    output's ``fastest_hz`` when that reaches MIN_GRID_HZ (at most ``max_rate_hz``), else
    the smallest whole multiple of it that does (its samples stay on grid times; the
    outputs are compared at their own samples only). On the grid of a 25 Hz IMU the
    integration's 40 ms steps and the control inputs read as ramps over the steps between
    their samples bias the derivatives."""
    if fastest_hz >= MIN_GRID_HZ:
        return float(min(fastest_hz, max_rate_hz))
    return float(min(fastest_hz * np.ceil(MIN_GRID_HZ / fastest_hz - 1e-9), max_rate_hz))


def _uniform(t: np.ndarray, v: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    n = int(np.floor((t[-1] - t[0]) * rate)) + 1
    tu = t[0] + np.arange(n) / rate
    return tu, np.interp(tu, t, v)


def _antialias_sos(native_hz: float, rate_hz: float) -> np.ndarray:
    """The anti-alias low-pass of :meth:`FlightData.resample` (applied forwards and
    backwards): 4th-order Butterworth at 0.4 x rate_hz, as second-order sections."""
    return butter(4, min(0.4 * rate_hz / (0.5 * native_hz), 0.99), output="sos")


def resample_noise_gain(native_hz: float, rate_hz: float, antialias: bool = True) -> float:
    """Factor by which :meth:`FlightData.resample` scales the std of white noise on a
    channel sampled at ``native_hz`` when it puts it on a ``rate_hz`` grid: sqrt(sum h^2)
    of the zero-phase anti-alias filter's impulse response h when that filter runs (native
    rate above 1.25 x rate_hz), else 1. (A 100 Hz gyro on a 50 Hz grid keeps 0.60 of its
    noise std: the filter removes the band above 20 Hz.)"""
    if not (antialias and native_hz > 1.25 * rate_hz):
        return 1.0
    n = int(40 * native_hz / rate_hz) * 2 + 201  # many times the filter's memory
    imp = np.zeros(n)
    imp[n // 2] = 1.0
    h = sosfiltfilt(_antialias_sos(native_hz, rate_hz), imp, padtype=None)
    return float(np.sqrt(np.sum(h * h)))


def _resample_channel(
    ch: Channel, t: np.ndarray, rate_hz: float, antialias: bool, unwrap: bool, is_angle: bool, max_gap: float | None
) -> np.ndarray:
    tc = np.asarray(ch.t, dtype=float)
    vc = np.asarray(ch.values, dtype=float)
    ok = np.isfinite(tc) & np.isfinite(vc)
    tc, vc = tc[ok], vc[ok]
    if tc.size == 0:
        return np.full(t.shape, np.nan)
    # sort and drop duplicate times (keep the first)
    if np.any(np.diff(tc) <= 0):
        order = np.argsort(tc, kind="stable")
        tc, vc = tc[order], vc[order]
        keep = np.r_[True, np.diff(tc) > 0]
        tc, vc = tc[keep], vc[keep]
    if is_angle:
        vc = np.unwrap(vc)
    native = sample_rate(tc) if tc.size > 1 else 0.0
    stamps = tc  # the native samples, for the blanking below (the filtered ones are uniform)
    if antialias and native > 1.25 * rate_hz and tc.size > 30:
        # filtered on a uniform grid at the native rate, piece by piece between the gaps
        sos = _antialias_sos(native, rate_hz)
        pieces = []
        for sl in contiguous(tc, GAP_FACTOR / native):
            tu, vu = _uniform(tc[sl], vc[sl], native)
            if vu.size > 3 * (2 * sos.shape[0] + 1):
                vu = sosfiltfilt(sos, vu)
            pieces.append((tu, vu))
        tc, vc = np.concatenate([p[0] for p in pieces]), np.concatenate([p[1] for p in pieces])
    out = (
        np.interp(t, tc, vc, left=np.nan, right=np.nan)
        if tc.size > 1
        else np.where(np.isclose(t, tc[0]), vc[0], np.nan)
    )
    # blank samples far from native data
    gap = max_gap if max_gap is not None else max(5.0 / native if native > 0 else 0.0, 2.0 / rate_hz)
    idx = np.clip(np.searchsorted(stamps, t), 1, max(stamps.size - 1, 1))
    if stamps.size > 1:
        near = np.minimum(np.abs(t - stamps[idx - 1]), np.abs(stamps[idx] - t))
        out[near > gap] = np.nan
    if is_angle and not unwrap:
        out = (out + np.pi) % (2 * np.pi) - np.pi
    return out
