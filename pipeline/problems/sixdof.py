"""Lateral-directional identification with the nonlinear 6-DoF model.

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

from estimators import Segment
from estimators.models import sixdof
from estimators.models.sixdof import body_velocity
from pipeline.conditioning.input_smoothing import smoothed_control_inputs
from pipeline.ingest.flightdata import FlightData, SegmentSpec
from pipeline.problems.identify import (
    LAT_FREE,
    AircraftConstants,
    Problem,
    _first_valid,
    lateral_specs,
    lateral_starts,
    longitudinal_starts,
    mean_density,
    multirate_frame,
    thrust_signal,
    usable_segments,
    with_smoothed_inputs,
)

SIXDOF_OUTPUTS = ("V", "alpha", "beta", "p", "q", "r", "phi", "theta", "ax", "ay", "az")
SIXDOF_INPUTS = ("de", "da", "dr")
TRIM_FREE = ("CL0", "CD0", "Cm0")


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
) -> Problem:
    """The lateral-directional problem on the 6-DoF model.

    longitudinal : CL*, CD*, Cm* values to hold (default: equation-error values from the
        same windows). segments default to the log's aileron and rudder windows; the last
        ``hold_out`` are kept for proof of match.
    smooth_inputs : the segments' surface positions low-passed where their noise floor
        begins (:mod:`pipeline.conditioning.input_smoothing`); False: as logged.
    """
    specs = lateral_specs(fd, SIXDOF_OUTPUTS + SIXDOF_INPUTS, segments, hold_out)
    df, rate_hz = multirate_frame(fd, SIXDOF_OUTPUTS, list(SIXDOF_INPUTS) + ["throttle", "thrust", "rho", "h"], rate_hz)
    smoothed, input_note = smoothed_control_inputs(fd, df, rate_hz, SIXDOF_INPUTS if smooth_inputs else ())
    rho = mean_density(df)
    c = {
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
        "z_imu": ac.imu[2],
    }
    specs, left_out, frames = usable_segments(
        df, specs, SIXDOF_OUTPUTS, SIXDOF_INPUTS, hold_out, "aileron/rudder maneuver"
    )
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
    lat_c = {**c, "V": float(np.nanmean(df["V"]))}
    start = {**{k: v for k, v in lon.items() if k[:2] in ("CL", "CD", "Cm")}, **lateral_starts(lat_frames, lat_c)}
    model = sixdof(c, values=start, free=list(free) + list(TRIM_FREE), output_biases=biases, name="sixdof-lateral")
    with_smoothed_inputs(frames, specs, smoothed, SIXDOF_INPUTS)

    def seg(s):
        w = frames[id(s)]
        V, a, b, p, q, r, phi, th = _first_valid(w, ["V", "alpha", "beta", "p", "q", "r", "phi", "theta"])
        return Segment(
            t=w["t"].to_numpy(),
            u=np.column_stack([w["de"], w["da"], w["dr"], thrust[id(s)]]),
            z=w[list(SIXDOF_OUTPUTS)].to_numpy(),
            x0=[*body_velocity(V, a, b), p, q, r, phi, th],
            name=s.name,
        )

    notes = (
        [
            f"nonlinear 6-DoF model on a {rate_hz:g} Hz grid, density {rho:.4f} kg/m^3",
            "longitudinal derivatives held at "
            + ("the longitudinal estimates" if longitudinal else "equation-error values")
            + f" except {', '.join(TRIM_FREE)}",
        ]
        + ([input_note] if input_note else [])
        + left_out
    )
    return Problem(
        "lateral",
        model,
        [seg(s) for s in fit_specs],
        [seg(s) for s in held],
        fit_specs,
        held,
        estimate_x0=True,
        notes=notes,
        rate_hz=rate_hz,
    )
