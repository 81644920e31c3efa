"""The longitudinal problem: the elevator maneuvers of one flight fitted with the nonlinear
longitudinal model.

The model of :mod:`estimators.models.longitudinal` observes V, alpha, theta, q, ax, az
(angular acceleration is not measured by loggers), with the air-data and IMU positions as
constants, per-segment initial states and per-segment biases on q, ax, az. Thrust (N)
comes from a ``thrust`` channel when the log has one, else from ``throttle * max_thrust``.
Start values come from an equation-error regression on the same windows; the last
elevator maneuvers are held out for proof of match.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from estimators import Segment
from estimators.models import longitudinal
from estimators.models.longitudinal import longitudinal_measured_lateral
from pipeline.conditioning.flow_angles import rebuilt
from pipeline.errors import FsidError
from pipeline.ingest.constants import AircraftConstants
from pipeline.ingest.flightdata import FlightData, SegmentSpec, merge_overlapping
from pipeline.problems.problem import KINEMATIC_NOTE, Problem
from pipeline.problems.pseudo_inputs import LONG_PSEUDO_CORNER_HZ, smooth_pseudo_inputs
from pipeline.problems.regressions import longitudinal_regressions, longitudinal_starts, start_note
from pipeline.problems.windows import (
    GridWindows,
    first_valid,
    grid_windows,
    mean_density,
    thrust_signal,
    window_density,
    with_smoothed_inputs,
)

#: derivatives estimated by default for the longitudinal axis
LONG_FREE = ("CD0", "CDalpha", "CDalpha2", "CL0", "CLalpha", "CLq", "CLde", "Cm0", "Cmalpha", "Cmq", "Cmde")
#: measured outputs of the longitudinal model
LONG_OUTPUTS = ("V", "alpha", "theta", "q", "ax", "az")
#: channels the longitudinal problem needs from the log
LONG_CHANNELS = ("V", "alpha", "theta", "q", "ax", "az", "de")
#: measured lateral-directional variables that drive the longitudinal model of multi-axis
#: maneuvers (longitudinal_problem(measured_lateral=True))
LONG_PSEUDO_LATERAL = ("beta", "p", "r", "phi", "ay")
#: problem note while the angle-of-attack rate derivatives are held: their effect moves
#: into the pitch-rate derivatives
ALPHADOT_HELD_NOTE = (
    "CLalphadot, Cmalphadot held at 0: without gusts to separate them, the "
    "angle-of-attack rate moves with q, so CLq and Cmq carry their effect "
    "(Cmq estimates about Cmq + Cmalphadot)"
)
#: problem note of the gust states of the measured-lateral model
VERTICAL_GUST_NOTE = (
    "vertical gust in the states (Dryden shaping filters): "
    "rotary gust q_g = -s/(1 + tau s) alpha_g + q_gi in the pitch "
    "damping"
)


def longitudinal_specs(
    fd: FlightData, channels: Sequence[str], segments: Sequence[SegmentSpec] | None, hold_out: int
) -> list[SegmentSpec]:
    """The elevator/throttle windows of a longitudinal problem (default: the log's 'de' and
    'throttle' segments), after checking the log has ``channels`` and enough maneuvers to
    fit and hold out ``hold_out``."""
    missing = fd.missing(channels)
    if missing:
        raise FsidError(
            f"longitudinal identification needs channels {missing} that the log "
            f"does not provide ({fd.meta.get('source', 'log')}); add them to the "
            "channel map (--map) or choose another model"
        )
    specs = list(
        segments
        if segments is not None
        else merge_overlapping([s for s in fd.segments if s.axis in ("de", "throttle")])
    )
    if len(specs) < 1 + hold_out:
        raise FsidError(
            f"found {len(specs)} longitudinal maneuver segment(s) but need at least "
            f"{1 + hold_out} (one to fit, {hold_out} to hold out): fly more elevator "
            "maneuvers or give segments by time range"
        )
    return specs


def longitudinal_constants(ac: AircraftConstants, rho: float, measured_lateral: bool) -> dict[str, float]:
    """The longitudinal model's constants: mass, Iyy, S, cbar, the density ``rho`` and the
    sensor positions; with ``measured_lateral`` also the lateral inertia, the span and the
    air-data boom's lateral offset."""
    c = {
        "m": ac.mass,
        "Iyy": ac.Iyy,
        "S": ac.S,
        "cbar": ac.cbar,
        "rho": rho,
        "x_vane": ac.airdata[0],
        "z_vane": ac.airdata[2],
        "x_imu": ac.imu[0],
        "z_imu": ac.imu[2],
    }
    if measured_lateral:
        c.update({"Ixx": ac.Ixx, "Izz": ac.Izz, "Ixz": ac.Ixz, "y_vane": ac.airdata[1], "b": ac.b})
    return c


def _longitudinal_model(
    c: Mapping[str, float],
    start: Mapping[str, float],
    free: Sequence[str],
    biases: Sequence[str],
    measured_lateral: bool,
    rotary_gust: bool,
) -> Any:
    """The longitudinal model (or the measured-lateral one) observing LONG_OUTPUTS."""
    if measured_lateral:
        return longitudinal_measured_lateral(
            c, values=start, free=free, output_biases=biases, name="longitudinal-measured", rotary_gust=rotary_gust
        ).select_outputs(LONG_OUTPUTS)
    return longitudinal(c, values=start, free=free, output_biases=biases, name="longitudinal").select_outputs(
        LONG_OUTPUTS
    )


def _longitudinal_segment(
    s: SegmentSpec, w: pd.DataFrame, thrust: np.ndarray, rho: float, measured_lateral: bool, rotary_gust: bool
) -> Segment:
    """Segment of window ``w``: inputs de, thrust (N) (and with ``measured_lateral`` the
    measured lateral variables and the air density along the window), initial states from
    the window's first samples (the gust states at rest)."""
    pseudo = list(LONG_PSEUDO_LATERAL) if measured_lateral else []
    x0 = list(first_valid(w, ["V", "alpha", "theta", "q"]))
    if rotary_gust:  # alpha_k = alpha (no gust at the start), lags 0
        x0 += [x0[1], 0.0, 0.0]
    u = np.column_stack(
        [w["de"], thrust] + [w[k] for k in pseudo] + ([window_density(w, rho)] if measured_lateral else [])
    )
    return Segment(t=w["t"].to_numpy(), u=u, z=w[list(LONG_OUTPUTS)].to_numpy(), x0=x0, name=s.name)


def _longitudinal_notes(
    ac: AircraftConstants,
    c: Mapping[str, float],
    start: Mapping[str, float],
    g: GridWindows,
    free: Sequence[str],
    measured_lateral: bool,
    rotary_gust: bool,
) -> list[str]:
    """The problem notes: the model, grid, density, thrust and start values, then those of
    the grid ``g`` (input smoothing, segments left out), then what the free derivatives and
    gust states imply."""
    notes = (
        [
            f"measured beta, p, r, phi, ay as inputs (the lateral motion as flown); air data at "
            f"({ac.airdata[0]:g}, {ac.airdata[1]:g}, {ac.airdata[2]:g}) m"
        ]
        if measured_lateral
        else []
    )
    notes += [
        f"grid {g.rate_hz:g} Hz; slower channels at their own samples only",
        f"density {c['rho']:.4f} kg/m^3 (mean over the flight)",
        f"thrust from {'thrust channel' if 'thrust' in g.frame else 'throttle x max_thrust'}",
        start_note(start),
        *g.notes,
    ]
    if not {"CLalphadot", "Cmalphadot"} & set(free):
        notes.append(ALPHADOT_HELD_NOTE)
    if rotary_gust:
        notes.append(VERTICAL_GUST_NOTE)
        if c["kin_angles"]:
            notes.append(KINEMATIC_NOTE.format(angle="alpha", state="alpha_k"))
    return notes


def longitudinal_problem(
    fd: FlightData,
    ac: AircraftConstants,
    *,
    rate_hz: float | None = None,
    segments: Sequence[SegmentSpec] | None = None,
    hold_out: int = 1,
    free: Sequence[str] = LONG_FREE,
    biases: Sequence[str] = ("q", "ax", "az"),
    measured_lateral: bool = False,
    rotary_gust: bool = False,
    values: Mapping[str, float] | None = None,
    smooth_inputs: bool = True,
) -> Problem:
    """Build the longitudinal problem from flight data.

    segments : windows to use (default: the log's segments whose axis is 'de' or
        'throttle'); the last ``hold_out`` elevator windows are kept for proof of match.
    measured_lateral : fit :func:`longitudinal_measured_lateral` instead, with the
        measured beta, p, r, phi, ay as inputs (low-pass filtered like the lateral
        model's pseudo-inputs) and the air data at the boom's full (x, y, z) position:
        for maneuvers that move all three axes at once.
    rotary_gust : with ``measured_lateral``: the model's gust states (the rotary gust
        q_g from the vertical gust and its own Markov part in the pitch damping; for the
        filters, whose process noise drives them).
    values : derivative values that override the equation-error starts (held ones stay
        at them: e.g. a-priori CLalphadot, Cmalphadot).
    smooth_inputs : the segments' elevator low-passed where its noise floor begins
        (:mod:`pipeline.conditioning.input_smoothing`); False: as logged.
    """
    pseudo = list(LONG_PSEUDO_LATERAL) if measured_lateral else []
    g = grid_windows(
        fd,
        longitudinal_specs(fd, LONG_CHANNELS + tuple(pseudo), segments, hold_out),
        LONG_OUTPUTS,
        ["de"] + pseudo,
        ["de", "throttle", "thrust", "rho", "h"] + pseudo,
        rate_hz=rate_hz,
        smooth=("de",) if smooth_inputs else (),
        hold_out=hold_out,
        what="longitudinal maneuver",
    )
    frames, rho = g.frames, mean_density(g.frame)
    c = longitudinal_constants(ac, rho, measured_lateral)
    rotary_gust = rotary_gust and measured_lateral
    if rotary_gust:
        c["kin_angles"] = float(rebuilt(fd, "alpha"))
    elev = [s for s in g.specs if s.axis == "de"]
    held = elev[-hold_out:] if hold_out else []
    fit_specs = [s for s in g.specs if s not in held]
    thrust = {id(s): thrust_signal(frames[id(s)], ac) for s in g.specs}
    regs = longitudinal_regressions([frames[id(s)] for s in fit_specs], c, [thrust[id(s)] for s in fit_specs])
    start = longitudinal_starts([frames[id(s)] for s in fit_specs], c, [thrust[id(s)] for s in fit_specs])
    start.update(values or {})
    with_smoothed_inputs(frames, g.specs, g.smoothed, ["de"])
    model = _longitudinal_model(c, start, free, biases, measured_lateral, rotary_gust)
    if measured_lateral:
        for s in g.specs:
            frames[id(s)] = smooth_pseudo_inputs(frames[id(s)], g.rate_hz, LONG_PSEUDO_CORNER_HZ)
    seg = {
        id(s): _longitudinal_segment(s, frames[id(s)], thrust[id(s)], rho, measured_lateral, rotary_gust)
        for s in g.specs
    }
    notes = _longitudinal_notes(ac, c, start, g, free, measured_lateral, rotary_gust)
    return Problem(
        "longitudinal",
        model,
        [seg[id(s)] for s in fit_specs],
        [seg[id(s)] for s in held],
        fit_specs,
        held,
        estimate_x0=["V", "alpha", "theta", "q"] if rotary_gust else True,
        notes=notes,
        regressions=regs,
        rate_hz=g.rate_hz,
    )
