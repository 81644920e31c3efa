"""The lateral-directional problem: the aileron and rudder maneuvers of one flight fitted
with the linear lateral model, or with the measured longitudinal motion as its inputs.

Control inputs are taken relative to their value at the start of each window; start values
come from an equation-error regression on the same windows, and the last maneuvers are held
out for proof of match. The trim-asymmetry terms identifiable with the output biases (CY0
with the default biases; :func:`estimators.models.lateral.trim_terms`) are free by
default: a real aircraft trims with aileron and rudder and a steady bank, which a model
without them cannot hold (it books the trim as a steady turn the gyros read with a bias),
and its bank and rates drift off in predictions.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd

from estimators import Segment
from estimators.models import lateral_directional
from estimators.models.lateral import lateral_measured_longitudinal, trim_terms, with_airspeed_offset
from pipeline.conditioning.airdata_kinematics import V_CORNER_HZ, kinematic_air_data
from pipeline.conditioning.flow_angles import rebuilt
from pipeline.errors import FsidError
from pipeline.ingest.constants import AircraftConstants
from pipeline.ingest.flightdata import FlightData, SegmentSpec, merge_overlapping
from pipeline.problems.problem import KINEMATIC_NOTE, Problem
from pipeline.problems.pseudo_inputs import airspeed_window_std, smooth_pseudo_inputs
from pipeline.problems.regressions import lateral_regressions, lateral_starts, start_note
from pipeline.problems.windows import first_valid, grid_windows, mean_density, with_smoothed_inputs

#: derivatives estimated by default for the lateral-directional axes
LAT_FREE = (
    "CYbeta",
    "CYp",
    "CYr",
    "CYda",
    "CYdr",
    "Clbeta",
    "Clp",
    "Clr",
    "Clda",
    "Cldr",
    "Cnbeta",
    "Cnp",
    "Cnr",
    "Cnda",
    "Cndr",
)
#: measured outputs of the lateral-directional models
LAT_OUTPUTS = ("beta", "p", "r", "phi", "ay")
#: channels the lateral problem needs from the log
LAT_CHANNELS = ("V", "alpha", "theta", "beta", "p", "r", "phi", "ay", "da", "dr")


def lateral_specs(
    fd: FlightData, channels: Sequence[str], segments: Sequence[SegmentSpec] | None, hold_out: int
) -> list[SegmentSpec]:
    """The aileron/rudder windows of a lateral problem (default: the log's 'da' and 'dr'
    segments), after checking the log has ``channels`` and enough maneuvers to fit and
    hold out ``hold_out``."""
    missing = fd.missing(channels)
    if missing:
        raise FsidError(
            f"lateral identification needs channels {missing} that the log does not "
            f"provide ({fd.meta.get('source', 'log')}); add them to the channel map"
        )
    specs = list(
        segments if segments is not None else merge_overlapping([s for s in fd.segments if s.axis in ("da", "dr")])
    )
    if len(specs) < 1 + hold_out:
        raise FsidError(
            f"found {len(specs)} aileron/rudder maneuver segment(s) but need at least "
            f"{1 + hold_out}: fly more doublets or give segments by time range"
        )
    return specs


def lateral_constants(ac: AircraftConstants, rho: float, windows: pd.DataFrame) -> dict[str, float]:
    """The lateral models' constants: mass, inertia, S, b, the density ``rho``, the sensor
    positions, and the reference airspeed (m/s), angle of attack and pitch attitude (rad):
    the means over the maneuver ``windows``."""
    return {
        "m": ac.mass,
        "Ixx": ac.Ixx,
        "Izz": ac.Izz,
        "Ixz": ac.Ixz,
        "S": ac.S,
        "b": ac.b,
        "rho": rho,
        "V": float(windows["V"].mean()),
        "alpha0": float(windows["alpha"].mean()),
        "theta0": float(windows["theta"].mean()),
        "x_vane": ac.airdata[0],
        "z_vane": ac.airdata[2],
        "x_imu": ac.imu[0],
        "z_imu": ac.imu[2],
    }


def _with_kinematic_air_data(
    fd: FlightData,
    frames: Mapping[int, pd.DataFrame],
    specs: Sequence[SegmentSpec],
    rate_hz: float,
    ac: AircraftConstants,
) -> bool:
    """Columns V_kin, beta_kin, alpha_kin put into each window of ``frames`` in place: the
    air data at the CG blended with the integrated IMU
    (:func:`pipeline.conditioning.airdata_kinematics.kinematic_air_data`), for the
    equation-error regressors and, with ``kinematic``, the pseudo-inputs V and alpha.
    False when the log has no blend (nothing put)."""
    kin = kinematic_air_data(fd, rate_hz, ac.imu, ac.airdata)
    if kin is None:
        return False
    for s in specs:
        w = frames[id(s)]
        tw = w["t"].to_numpy()
        w["V_kin"] = np.interp(tw, kin["t"], kin["V"])
        w["beta_kin"] = np.interp(tw, kin["t"], kin["beta"])
        w["alpha_kin"] = np.interp(tw, kin["t"], kin["alpha"])
    return True


def _with_pseudo_inputs(
    frames: dict[int, pd.DataFrame], specs: Sequence[SegmentSpec], rate_hz: float, kinematic: bool
) -> None:
    """Each window of ``frames`` replaced by one with its pseudo-inputs V, alpha, theta, q
    low-passed, V and alpha taken from the kinematic blend when ``kinematic``."""
    for s in specs:
        if kinematic:
            frames[id(s)]["V"] = frames[id(s)]["V_kin"]
            frames[id(s)]["alpha"] = frames[id(s)]["alpha_kin"]
        frames[id(s)] = smooth_pseudo_inputs(frames[id(s)], rate_hz)


def _lateral_model(
    ac: AircraftConstants,
    c: Mapping[str, float],
    start: Mapping[str, float],
    free: Sequence[str],
    biases: Sequence[str],
    measured_longitudinal: bool,
    rotary_gust: bool,
) -> Any:
    """The linear lateral model observing LAT_OUTPUTS, or the measured-longitudinal one."""
    if measured_longitudinal:
        return lateral_measured_longitudinal(
            {**c, "Iyy": ac.Iyy},
            values=start,
            free=free,
            output_biases=biases,
            name="lateral-measured",
            rotary_gust=rotary_gust,
        )
    return lateral_directional(c, values=start, free=free, output_biases=biases, name="lateral").select_outputs(
        LAT_OUTPUTS
    )


def _lateral_segment(s: SegmentSpec, w: pd.DataFrame, ucols: Sequence[str], rotary_gust: bool) -> Segment:
    """Segment of window ``w`` with inputs ``ucols``, initial states from its first samples
    (with ``rotary_gust``: the roll-gust state at rest, beta_k = beta)."""
    return Segment(
        t=w["t"].to_numpy(),
        u=w[ucols].to_numpy(),
        z=w[list(LAT_OUTPUTS)].to_numpy(),
        x0=list(first_valid(w, ["beta", "p", "r", "phi"]))
        + ([0.0, float(first_valid(w, ["beta"])[0]), 0.0] if rotary_gust else []),
        name=s.name,
    )


def _lateral_notes(
    c: Mapping[str, float],
    start: Mapping[str, float],
    more: Sequence[str],
    measured_longitudinal: bool,
    kinematic: bool,
    rotary_gust: bool,
) -> list[str]:
    """The problem notes: the model and its reference values, the start values, what the
    gust states imply, then ``more`` (input smoothing, segments left out)."""
    if measured_longitudinal:
        model = f"measured V, alpha, theta, q as inputs, density {c['rho']:.4f} kg/m^3" + (
            f" (V, alpha: the air data blended with the integrated IMU, the air data below {V_CORNER_HZ:g} Hz)"
            if kinematic
            else ""
        )
    else:
        model = (
            f"linear model about V={c['V']:.2f} m/s, alpha0={np.degrees(c['alpha0']):.2f} deg, "
            f"theta0={np.degrees(c['theta0']):.2f} deg, density {c['rho']:.4f} kg/m^3"
        )
    notes = [model, start_note(start)]
    if rotary_gust:
        notes.append("roll-gust state p_g (Dryden, time constant 4b/(pi V)) in the roll damping")
        if c["kin_angles"]:
            notes.append(KINEMATIC_NOTE.format(angle="beta", state="beta_k"))
    return notes + list(more)


def lateral_problem(
    fd: FlightData,
    ac: AircraftConstants,
    *,
    rate_hz: float | None = None,
    segments: Sequence[SegmentSpec] | None = None,
    hold_out: int = 1,
    free: Sequence[str] = LAT_FREE,
    biases: Sequence[str] = ("beta", "p", "r", "ay"),
    measured_longitudinal: bool = False,
    rotary_gust: bool = False,
    kinematic: bool = False,
    smooth_inputs: bool = True,
    trim_asymmetry: bool = True,
) -> Problem:
    """Build the lateral-directional problem (linear model about the flight's mean
    airspeed, angle of attack and pitch attitude) from the aileron and rudder maneuvers;
    control inputs are taken relative to their value at the start of each window.

    measured_longitudinal : fit :func:`lateral_measured_longitudinal` instead, with the
        measured V, alpha, theta, q as inputs (the linear model's frozen airspeed and
        small bank angles bias the derivatives when the maneuvers bank the aircraft by
        tens of degrees).
    rotary_gust : with ``measured_longitudinal``: the model's roll-gust state p_g (the
        aerodynamics see p - p_g; for the filters, whose process noise drives it).
    kinematic : with ``measured_longitudinal``: the pseudo-inputs V and alpha are the air
        data blended with the integrated IMU (:mod:`pipeline.conditioning.airdata_kinematics`: pitot
        and vane below 0.1 Hz, the kinematic rates above), not the air data low-passed at
        1 and 5 Hz. For calm-air output error, which takes its inputs as exact: the pitot
        noise between 0.1 and 1 Hz scales every moment of the window, and an angle of
        attack rebuilt from the GPS velocity (no vane) puts its noise into the kinematic
        coupling. In turbulence the blend misses the gusts above 0.1 Hz.
    smooth_inputs : the segments' aileron and rudder low-passed where their noise floor
        begins (:mod:`pipeline.conditioning.input_smoothing`); False: as logged.
    trim_asymmetry : the trim-asymmetry terms free in addition to ``free`` (those
        identifiable with ``biases``: :func:`estimators.models.lateral.trim_terms`);
        False: held at 0 (a wings-level trim balanced at zero sideslip, or one the
        sideslip bias alone takes)."""
    rotary_gust = rotary_gust and measured_longitudinal
    if trim_asymmetry:
        extra = trim_terms("beta" in biases, "r" in biases)
        free = tuple(free) + tuple(n for n in extra if n not in free)
    q = ["q"] if measured_longitudinal else []
    g = grid_windows(
        fd,
        lateral_specs(fd, LAT_CHANNELS + tuple(q), segments, hold_out),
        LAT_OUTPUTS,
        ["V", "alpha", "theta", "da", "dr"] + q,
        ["V", "alpha", "theta"] + q + ["da", "dr", "rho", "h"],
        rate_hz=rate_hz,
        smooth=("da", "dr") if smooth_inputs else (),
        hold_out=hold_out,
        what="aileron/rudder maneuver",
    )
    specs, frames, rate_hz = g.specs, g.frames, g.rate_hz
    c = lateral_constants(ac, mean_density(g.frame), pd.concat(frames.values()))
    for s in specs:
        w = frames[id(s)]
        w[["da", "dr"]] = w[["da", "dr"]] - w[["da", "dr"]].iloc[0]
    kinematic = _with_kinematic_air_data(fd, frames, specs, rate_hz, ac) and kinematic and measured_longitudinal
    held = specs[-hold_out:] if hold_out else []
    fit_specs = [s for s in specs if s not in held]
    regs = lateral_regressions([frames[id(s)] for s in fit_specs], c)
    start = lateral_starts([frames[id(s)] for s in fit_specs], c, regs)
    if rotary_gust:  # Dryden roll-gust time constant 4 b / (pi V)
        start["tau_pg"] = 4.0 * ac.b / (np.pi * c["V"])
        c["kin_angles"] = float(rebuilt(fd, "beta"))
    model = _lateral_model(ac, c, start, free, biases, measured_longitudinal, rotary_gust)
    ucols = ["da", "dr", "V", "alpha", "theta", "q"] if measured_longitudinal else ["da", "dr"]
    with_smoothed_inputs(frames, specs, g.smoothed, ["da", "dr"], relative=True)
    if measured_longitudinal:
        _with_pseudo_inputs(frames, specs, rate_hz, kinematic)
    notes = _lateral_notes(c, start, g.notes, measured_longitudinal, kinematic, rotary_gust)
    return Problem(
        "lateral",
        model,
        [_lateral_segment(s, frames[id(s)], ucols, rotary_gust) for s in fit_specs],
        [_lateral_segment(s, frames[id(s)], ucols, rotary_gust) for s in held],
        fit_specs,
        held,
        estimate_x0=["beta", "p", "r", "phi"] if rotary_gust else True,
        notes=notes,
        regressions=regs,
        rate_hz=rate_hz,
    )


def with_airspeed_offsets(problem: Problem, fd: FlightData) -> Problem:
    """The lateral-measured problem with a per-segment airspeed correction dV[k] on the
    pseudo-input V (:func:`estimators.models.lateral.with_airspeed_offset`) and the
    a-priori penalty dV[k] ~ N(0, sigma_V / sqrt(n_k)) (:func:`airspeed_window_std`) for
    output error, so that its Cramer-Rao bounds include the pitot noise of the input.

    Why: output error takes inputs as exact, while each fitted window's mean airspeed is
    off by sigma_V / sqrt(n): a dynamic-pressure error comparable to the bounds of the
    stiff derivatives (control and damping derivatives, Cnbeta). Not covered: the pitot
    noise's fluctuation inside a window (below the 1 Hz corner), which a constant dV[k]
    leaves."""
    sigma, sds = airspeed_window_std(fd, problem.fit)
    priors = {f"dV[{k}]": (0.0, float(max(sd, 1e-6))) for k, sd in enumerate(sds)}
    note = (
        f"per-maneuver airspeed correction dV on the pseudo-input V, a priori 0 +- "
        f"sigma_V/sqrt(n) = {min(sds):.3f}-{max(sds):.3f} m/s (pitot noise {sigma:.2f} m/s)"
    )
    return replace(
        problem,
        model=with_airspeed_offset(problem.model),
        priors={**problem.priors, **priors},
        notes=list(problem.notes) + [note],
    )
