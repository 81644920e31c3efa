"""Identification with the nonlinear 6-DoF model: the lateral-directional axis, and both
axes at once (:func:`sixdof_problem`, e.g. a motion-capture pose's derived states).

The linear lateral model of :mod:`estimators.models.lateral` holds airspeed, angle of
attack and pitch attitude at their mean and linearises the kinematics; on a small UAV the
doublets move those enough to bias the estimates by several standard deviations. This
builder fits the lateral-directional derivatives with :func:`estimators.models.sixdof`
instead: all 11 measured outputs, the longitudinal derivatives held at given values (the
longitudinal estimates of the same flight, or equation-error values) except the three
trim coefficients CL0, CD0, Cm0, which the lateral maneuvers' own trim needs.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from estimators import Segment
from estimators.models import sixdof
from estimators.models.lateral import trim_terms
from estimators.models.sixdof import body_velocity
from pipeline.errors import FsidError
from pipeline.ingest.constants import AircraftConstants
from pipeline.ingest.flightdata import FlightData, SegmentSpec
from pipeline.problems.lateral import LAT_FREE, lateral_specs
from pipeline.problems.problem import Problem
from pipeline.problems.regressions import lateral_starts, longitudinal_starts
from pipeline.problems.windows import first_valid, grid_windows, mean_density, thrust_signal, with_smoothed_inputs

#: measured outputs of the 6-DoF model: every flight state the loggers record
SIXDOF_OUTPUTS = ("V", "alpha", "beta", "p", "q", "r", "phi", "theta", "ax", "ay", "az")
#: control surfaces driving the 6-DoF model (with thrust)
SIXDOF_INPUTS = ("de", "da", "dr")
#: longitudinal coefficients estimated with the lateral ones: the lateral maneuvers' own trim
TRIM_FREE = ("CL0", "CD0", "Cm0")
#: both axes' derivatives a full 6-DoF fit estimates by default, with the trim terms
BOTH_AXES_FREE = (
    *("CL0", "CLalpha", "CLde", "CD0", "CDalpha", "Cm0", "Cmalpha", "Cmq", "Cmde"),
    *("CY0", "CYbeta", "Cl0", "Clbeta", "Clp", "Clr", "Clda", "Cldr", "Cn0", "Cnbeta", "Cnp", "Cnr", "Cnda", "Cndr"),
)
#: bounds that keep drag and thrust apart when the throttle hardly moves (both positive)
POSITIVE = {"CD0": (0.0, np.inf), "kT": (0.0, np.inf)}


def sixdof_constants(ac: AircraftConstants, rho: float) -> dict[str, float]:
    """The 6-DoF model's constants: mass, inertia, geometry, the density ``rho`` (kg/m^3)
    and the sensor positions."""
    return {
        "m": ac.mass,
        "Ixx": ac.Ixx,
        "Iyy": ac.Iyy,
        "Izz": ac.Izz,
        "Ixz": ac.Ixz,
        "S": ac.S,
        "b": ac.b,
        "cbar": ac.cbar,
        "rho": rho,
        "x_vane": ac.airdata[0],
        "y_vane": ac.airdata[1],
        "z_vane": ac.airdata[2],
        "x_imu": ac.imu[0],
        "y_imu": ac.imu[1],
        "z_imu": ac.imu[2],
    }


def _sixdof_segment(s: SegmentSpec, w: pd.DataFrame, thrust: np.ndarray) -> Segment:
    """Segment of window ``w``: inputs de, da, dr, thrust (N), initial states (body
    velocity, rates, attitude) from the window's first samples."""
    V, a, b, p, q, r, phi, th = first_valid(w, ["V", "alpha", "beta", "p", "q", "r", "phi", "theta"])
    return Segment(
        t=w["t"].to_numpy(),
        u=np.column_stack([w["de"], w["da"], w["dr"], thrust]),
        z=w[list(SIXDOF_OUTPUTS)].to_numpy(),
        x0=[*body_velocity(V, a, b), p, q, r, phi, th],
        name=s.name,
    )


def sixdof_lateral_problem(
    fd: FlightData,
    ac: AircraftConstants,
    *,
    longitudinal: Mapping[str, float] | None = None,
    rate_hz: float | None = None,
    segments: Sequence[SegmentSpec] | None = None,
    hold_out: int = 1,
    free: Sequence[str] = LAT_FREE,
    biases: Sequence[str] = ("p", "q", "r", "ay"),
    smooth_inputs: bool = True,
    trim_asymmetry: bool = True,
) -> Problem:
    """The lateral-directional problem on the 6-DoF model.

    trim_asymmetry : free the trim-asymmetry terms identifiable beside ``biases``
        (:func:`estimators.models.lateral.trim_terms`): a real aircraft trims with aileron and
        rudder offsets and a steady sideslip.

    longitudinal : CL*, CD*, Cm* values to hold (default: equation-error values from the
        same windows). segments default to the log's aileron and rudder windows; the last
        ``hold_out`` are kept for proof of match.
    smooth_inputs : the segments' surface positions low-passed where their noise floor
        begins (:mod:`pipeline.conditioning.input_smoothing`); False: as logged.
    """
    g = grid_windows(
        fd,
        lateral_specs(fd, SIXDOF_OUTPUTS + SIXDOF_INPUTS, segments, hold_out),
        SIXDOF_OUTPUTS,
        SIXDOF_INPUTS,
        list(SIXDOF_INPUTS) + ["throttle", "thrust", "rho", "h"],
        rate_hz=rate_hz,
        smooth=SIXDOF_INPUTS if smooth_inputs else (),
        hold_out=hold_out,
        what="aileron/rudder maneuver",
    )
    specs, frames, rho = g.specs, g.frames, mean_density(g.frame)
    c = sixdof_constants(ac, rho)
    held = specs[-hold_out:] if hold_out else []
    fit_specs = [s for s in specs if s not in held]
    thrust = {id(s): thrust_signal(frames[id(s)], ac) for s in specs}
    fit_frames = [frames[id(s)] for s in fit_specs]
    lon = dict(longitudinal) if longitudinal else longitudinal_starts(fit_frames, c, [thrust[id(s)] for s in fit_specs])
    lat_frames = []
    for w in fit_frames:
        w = w.copy()
        w[["da", "dr"]] = w[["da", "dr"]] - w[["da", "dr"]].iloc[0]
        lat_frames.append(w.interpolate(limit_direction="both"))
    lat_c = {**c, "V": float(np.nanmean(g.frame["V"]))}
    start = {**{k: v for k, v in lon.items() if k[:2] in ("CL", "CD", "Cm")}, **lateral_starts(lat_frames, lat_c)}
    asym = trim_terms("beta" in biases, bool({"p", "r"} & set(biases)), "ay" in biases) if trim_asymmetry else ()
    model = sixdof(c, values=start, free=[*free, *TRIM_FREE, *asym], output_biases=biases, name="sixdof-lateral")
    with_smoothed_inputs(frames, specs, g.smoothed, SIXDOF_INPUTS)
    notes = [
        f"nonlinear 6-DoF model on a {g.rate_hz:g} Hz grid, density {rho:.4f} kg/m^3",
        "longitudinal derivatives held at "
        + ("the longitudinal estimates" if longitudinal else "equation-error values")
        + f" except {', '.join(TRIM_FREE)}",
    ] + g.notes
    return Problem(
        "lateral",
        model,
        [_sixdof_segment(s, frames[id(s)], thrust[id(s)]) for s in fit_specs],
        [_sixdof_segment(s, frames[id(s)], thrust[id(s)]) for s in held],
        fit_specs,
        held,
        estimate_x0=True,
        notes=notes,
        rate_hz=g.rate_hz,
    )


def sixdof_segment(w: pd.DataFrame, name: str, inputs: Sequence[str], outputs: Sequence[str], states) -> Segment:
    """Segment of the resampled window ``w``: the model's ``inputs`` and ``outputs`` columns,
    initial states (body velocity from V, alpha, beta; the other ``states`` by name) from
    the window's first valid samples."""
    V, a, b = first_valid(w, ["V", "alpha", "beta"])
    rest = [s for s in states if s not in ("u", "v", "w")]
    return Segment(
        t=w["t"].to_numpy(),
        u=w[list(inputs)].to_numpy(),
        z=w[list(outputs)].to_numpy(),
        x0=[*body_velocity(V, a, b), *first_valid(w, rest)],
        name=name,
    )


def _inputs_defined(w: pd.DataFrame) -> pd.DataFrame:
    """``w`` without its leading and trailing rows where a control input is missing (a
    grid point a rounding past the segment's last sample)."""
    ok = w[list(SIXDOF_INPUTS)].notna().all(axis=1).to_numpy()
    if not ok.any():
        return w.iloc[:0]
    first, last = np.flatnonzero(ok)[[0, -1]]
    return w.iloc[first : last + 1].reset_index(drop=True)


def sixdof_problem(
    fd: FlightData,
    ac: AircraftConstants,
    segments: Sequence[SegmentSpec],
    *,
    held_out: Sequence[SegmentSpec] = (),
    validation: FlightData | None = None,
    start: Mapping[str, float] | None = None,
    free: Sequence[str] = BOTH_AXES_FREE,
    rate_hz: float = 100.0,
    navigation: bool = False,
    bounds: Mapping[str, tuple[float, float]] | None = None,
) -> Problem:
    """Both axes on the 6-DoF model, fitted to ``segments`` of ``fd`` on a ``rate_hz`` grid.

    The measured outputs are the model's 11 (V alpha beta p q r phi theta ax ay az; with
    ``navigation`` also psi x_n y_e z_d). Thrust: the log's thrust channel, else the
    aircraft's throttle-to-thrust map, else the throttle itself with the model's kT (thrust
    at full throttle, N, proportional) estimated, positive like CD0 (:data:`POSITIVE`).
    ``start``: start values (default the model's); every segment has its own initial state.
    ``held_out``: segments kept for validation, of ``validation`` (another flight) or ``fd``.
    ``bounds``: parameter bounds (a-priori limits) over :data:`POSITIVE`.
    """
    model_out = list(SIXDOF_OUTPUTS) + (["psi", "x_n", "y_e", "z_d"] if navigation else [])
    need = model_out + list(SIXDOF_INPUTS)
    missing = fd.missing(need)
    if missing:
        raise FsidError(
            f"{fd.meta.get('source', 'the log')}: the 6-DoF problem needs {', '.join(missing)}; "
            "a pose-only log gets them from its pose (pipeline.ingest.pose)"
        )
    frames = [
        _inputs_defined(fd.resample(rate_hz, need + ["throttle", "thrust", "rho", "h"], t0=s.t0, t1=s.t1))
        for s in segments
    ]
    held = [
        _inputs_defined(
            (validation or fd).resample(rate_hz, need + ["throttle", "thrust", "rho", "h"], t0=s.t0, t1=s.t1)
        )
        for s in held_out
    ]
    rho = mean_density(pd.concat(frames))
    c = sixdof_constants(ac, rho)
    known = ac.thrust(np.zeros(1)) is not None or all("thrust" in w and w["thrust"].notna().all() for w in frames)
    for w in frames + held:
        w["thrust_in"] = thrust_signal(w, ac) if known else w["throttle"]
    values = {k: v for k, v in (start or {}).items() if k != "kT" or not known}
    limits = {k: v for k, v in {**POSITIVE, **(bounds or {})}.items() if k != "kT" or not known}
    model = sixdof(
        c,
        values=values,
        free=list(free) + ([] if known else ["kT"]),
        bounds=limits,
        throttle=not known,
        navigation=navigation,
        name="sixdof",
    )
    inputs = list(SIXDOF_INPUTS) + ["thrust_in"]
    notes = [
        f"nonlinear 6-DoF model, both axes, on a {rate_hz:g} Hz grid, density {rho:.4f} kg/m^3",
        "thrust from " + ("the log or the aircraft's map" if known else "the throttle x kT (estimated)"),
    ]
    return Problem(
        "sixdof",
        model,
        [sixdof_segment(w, s.name, inputs, model_out, model.states) for s, w in zip(segments, frames)],
        [sixdof_segment(w, s.name, inputs, model_out, model.states) for s, w in zip(held_out, held)],
        list(segments),
        list(held_out),
        estimate_x0=True,
        notes=notes,
        rate_hz=rate_hz,
    )
