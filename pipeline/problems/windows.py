"""The measurements on one estimation grid, and the segment windows cut out of it.

Every problem builder puts the log's channels on one uniform grid
(:func:`multirate_frame`), keeps the maneuver windows that can be fitted
(:func:`usable_segments`; both: :func:`grid_windows`), puts the low-passed control inputs
into them (:func:`with_smoothed_inputs`) and reads thrust and air density from them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.conditioning.checks import AIRBORNE_MPS, airborne_speed, slow_airspeed
from pipeline.conditioning.input_sampling import step_spans
from pipeline.conditioning.input_smoothing import smoothed_control_inputs
from pipeline.errors import FsidError
from pipeline.ingest.constants import AircraftConstants, isa_density
from pipeline.ingest.flightdata import FlightData, SegmentSpec, fit_grid_rate

#: highest grid rate for estimation; faster channels are low-pass filtered down to it
MAX_RATE_HZ = 200.0
#: outputs a control input reaches without dynamics (the control forces on the
#: accelerometers): left out where the fits' input is a ramp standing in for a step between
#: two slow samples (:func:`pipeline.conditioning.input_sampling.step_spans`)
FEEDTHROUGH_OUTPUTS = ("ax", "ay", "az")


def multirate_frame(
    fd: FlightData, outputs: Sequence[str], others: Sequence[str], rate_hz: float | None = None
) -> tuple[pd.DataFrame, float]:
    """Measurements on one uniform grid without inventing samples.

    The grid runs at the fastest output channel's rate, or a whole multiple of it that
    reaches MIN_GRID_HZ (:func:`pipeline.ingest.flightdata.fit_grid_rate`, at most MAX_RATE_HZ),
    or at ``rate_hz``. Output channels at that rate are resampled as usual; slower output
    channels keep only their native samples and are NaN in between, so the likelihood
    counts every real measurement once and no interpolated one (the estimators give NaN
    samples zero weight): each native sample goes to its nearest grid time, with the
    channel's value interpolated there (at most half a grid step from the sample; two
    samples on one grid time count once). Samples that do not fall on the grid - a GPS
    at 5 Hz on a 25 Hz attitude's grid with another phase, telemetry timestamps with
    jitter - are all kept. ``others`` (inputs, air density, ...) are interpolated to every
    grid time. The accelerometers (FEEDTHROUGH_OUTPUTS) are NaN at grid times inside a
    control-input step's span (:func:`pipeline.conditioning.input_sampling.step_spans`).
    Returns (frame, rate).
    """
    rates = {c: fd[c].rate_hz for c in outputs}
    rate = float(rate_hz or fit_grid_rate(max(rates.values()), MAX_RATE_HZ))
    fast = [c for c in outputs if rates[c] >= 0.9 * rate]
    df = fd.resample(rate, list(fast) + [c for c in others if c in fd])
    t = df["t"].to_numpy()
    for c in outputs:
        if c in fast:
            continue
        ch = fd[c]
        idx = np.rint((ch.t - t[0]) * rate).astype(np.int64)
        idx = np.unique(idx[(idx >= 0) & (idx < t.size)])
        col = np.full(t.size, np.nan)
        col[idx] = np.interp(t[idx], ch.t, ch.values)
        df[c] = col
    spans = step_spans(fd.meta)
    blank = [c for c in outputs if c in FEEDTHROUGH_OUTPUTS]
    if spans and blank:
        a, b = np.array(spans).T
        marks = np.zeros(t.size + 1, dtype=np.int64)  # +1 where a span opens, -1 where it closes
        np.add.at(marks, np.searchsorted(t, a, side="right"), 1)
        np.add.at(marks, np.searchsorted(t, b, side="left"), -1)
        df.loc[np.cumsum(marks)[:-1] > 0, blank] = np.nan  # grid times strictly inside a span
    return df, rate


def first_valid(w: pd.DataFrame, cols: Sequence[str]) -> np.ndarray:
    """First non-NaN value of each column (initial states from multi-rate data)."""
    return np.array([w[c].dropna().iloc[0] for c in cols])


def _window(df: pd.DataFrame, spec: SegmentSpec) -> pd.DataFrame:
    """The rows of ``df`` inside segment ``spec`` (ends included), indexed from 0."""
    w = df[(df["t"] >= spec.t0) & (df["t"] <= spec.t1)]
    return w.reset_index(drop=True)


def _window_fault(
    w: pd.DataFrame,
    s: SegmentSpec,
    outputs: Sequence[str],
    others: Sequence[str],
    airborne: bool = True,
    floor: float = AIRBORNE_MPS,
) -> str | None:
    """What makes window ``w`` of segment ``s`` unusable - fewer than 10 rows, an output
    with fewer than 10 samples (outputs may be slower than the grid: NaN between their
    samples), another channel (an input) with any NaN, and with ``airborne`` an airspeed
    column below ``floor`` m/s (:func:`pipeline.conditioning.checks.slow_airspeed`: a control
    check on the ground, a hover) - or None."""
    bad = [k for k in outputs if w[k].notna().sum() < 10] + [k for k in others if w[k].isna().any()]
    if len(w) < 10 or bad:
        return f"segment {s.name} ({s.t0:.2f}-{s.t1:.2f} s) has gaps or NaN in {bad}"
    if airborne and "V" in w:
        slow, why = slow_airspeed(w["V"].dropna().to_numpy(), floor)
        if slow:
            return f"segment {s.name} ({s.t0:.2f}-{s.t1:.2f} s) is on the ground or hovering ({why})"
    return None


def usable_segments(
    df: pd.DataFrame,
    specs: Sequence[SegmentSpec],
    outputs: Sequence[str],
    others: Sequence[str],
    hold_out: int,
    what: str,
    airborne: bool = True,
    floor: float = AIRBORNE_MPS,
) -> tuple[list[SegmentSpec], list[str], dict[int, pd.DataFrame]]:
    """(the segments of ``specs`` whose windows are usable, a note for each one left out,
    their rows of ``df`` by ``id(spec)``): the one place that cuts segment windows out of the
    multi-rate frame.
    Found segments (automatic or by flight mode) that are not - a maneuver detected in a
    hover without forward flight for the rebuilt air-data angles, a telemetry dropout, and
    with ``airborne`` (the aircraft models) one on the ground or hovering - are left out and
    named, so that the others are still fitted; a segment given by time range (kind
    "time") ends with one clear error naming what is missing (the airspeed rule aside: a
    range the user chose is fitted as given). FsidError when fewer than 1 + ``hold_out``
    remain (``what``: the maneuvers, for the message)."""
    keep, faults, frames = [], [], {}
    for s in specs:
        w = _window(df, s)
        fault = _window_fault(w, s, outputs, others, airborne and s.kind != "time", floor)
        if fault is None:
            keep.append(s)
            frames[id(s)] = w
        elif s.kind == "time":
            raise FsidError(f"{fault}: cut it or fix the log")
        else:
            faults.append(fault)
    if len(keep) < 1 + hold_out:
        more = f"; and {len(faults) - 2} more" if len(faults) > 2 else ""
        raise FsidError(
            f"found {len(specs)} {what} segment(s), {len(keep)} usable, but need at "
            f"least {1 + hold_out} (one to fit, {hold_out} to hold out)"
            + (f" - {'; '.join(faults[:2])}{more}" if faults else "")
            + ": fly more maneuvers, give segments by time range (--segments T0:T1,... in s from the log's start)"
            + (" or fit them all (--no-holdout)" if hold_out and len(keep) >= 1 else "")
        )
    return keep, [f"{f}: left out" for f in faults], frames


def with_smoothed_inputs(
    frames: Mapping[int, pd.DataFrame],
    specs: Sequence[SegmentSpec],
    smoothed: pd.DataFrame | None,
    cols: Sequence[str],
    *,
    relative: bool = False,
) -> None:
    """Put the columns ``cols`` of ``smoothed`` (the flight's grid with its control inputs
    low-passed, :func:`pipeline.conditioning.input_smoothing.smoothed_control_inputs`) into each window
    of ``frames`` in place, relative to the window's first sample when ``relative``. The
    equation-error regressions and starts are built before, from the logged samples: they
    filter every signal of their linear relation alike. Nothing to do when ``smoothed``
    is None (no input had a noise floor to remove)."""
    if smoothed is None or not cols:
        return
    for s in specs:
        w, sm = frames[id(s)], _window(smoothed, s)[list(cols)]
        w[list(cols)] = (sm - sm.iloc[0] if relative else sm).to_numpy()


def thrust_signal(df: pd.DataFrame, ac: AircraftConstants) -> np.ndarray:
    """Thrust (N) along the rows of ``df``: its thrust channel, else the throttle through
    the aircraft's throttle-to-thrust map (:meth:`AircraftConstants.thrust`)."""
    if "thrust" in df and df["thrust"].notna().all():
        return df["thrust"].to_numpy()
    thrust = ac.thrust(df["throttle"].to_numpy()) if "throttle" in df else None
    if thrust is not None:
        return thrust
    raise FsidError(
        "the log has neither a thrust channel nor throttle with a known throttle-to-thrust map: "
        "add [propulsion] max_thrust_N (or a throttle = [...], thrust_N = [...] map) to the aircraft file"
    )


def mean_density(df: pd.DataFrame) -> float:
    """Mean air density (kg/m^3) of the flight: the rho channel, else ISA at the measured
    altitude, else sea level."""
    if "rho" in df:
        return float(np.nanmean(df["rho"]))
    return float(np.nanmean(isa_density(df["h"]))) if "h" in df else 1.225


def window_density(w: pd.DataFrame, rho: float) -> np.ndarray:
    """Air density (kg/m^3) along window ``w``: the log's rho channel, else ISA at the
    measured altitude, else the flight mean ``rho``."""
    for col, fn in (("rho", lambda x: x), ("h", isa_density)):
        if col in w and w[col].notna().all():
            return fn(w[col].to_numpy(dtype=float))
    return np.full(len(w), rho)


@dataclass
class GridWindows:
    """The flight on one estimation grid and the usable maneuver windows cut out of it."""

    #: the flight on the grid
    frame: pd.DataFrame
    #: grid rate (Hz)
    rate_hz: float
    #: the usable segments
    specs: list[SegmentSpec]
    #: their rows of ``frame`` by ``id(spec)`` (changed in place by the builders)
    frames: dict[int, pd.DataFrame]
    #: the grid with its control inputs low-passed (None: none was)
    smoothed: pd.DataFrame | None
    #: problem notes: the input smoothing, the segments left out
    notes: list[str]


def grid_windows(
    fd: FlightData,
    specs: Sequence[SegmentSpec],
    outputs: Sequence[str],
    inputs: Sequence[str],
    grid_channels: Sequence[str],
    *,
    rate_hz: float | None,
    smooth: Sequence[str],
    hold_out: int,
    what: str,
) -> GridWindows:
    """The grid of ``outputs`` and ``grid_channels`` (:func:`multirate_frame`), its control
    inputs ``smooth`` low-passed (:func:`pipeline.conditioning.input_smoothing.smoothed_control_inputs`),
    and the windows of ``specs`` usable with ``outputs`` and ``inputs`` (:func:`usable_segments`,
    ``hold_out`` and ``what`` as there): the first step of every built-in problem."""
    df, rate = multirate_frame(fd, outputs, grid_channels, rate_hz)
    smoothed, input_note = smoothed_control_inputs(fd, df, rate, smooth)
    usable, left_out, frames = usable_segments(df, specs, outputs, inputs, hold_out, what, floor=airborne_speed(fd))
    return GridWindows(df, rate, usable, frames, smoothed, ([input_note] if input_note else []) + left_out)
