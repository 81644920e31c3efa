"""Problems for maneuvers that move all axes at once (e.g. 3-axis multisines), and for the
filters in turbulence: each axis' model driven by the other axis' measured variables."""

from __future__ import annotations

from pipeline.ingest.constants import AircraftConstants
from pipeline.ingest.flightdata import FlightData
from pipeline.problems.lateral import LAT_FREE, lateral_problem
from pipeline.problems.longitudinal import LONG_FREE, longitudinal_problem
from pipeline.problems.problem import Problem

#: derivatives freed in addition on multi-axis flights for the filters (gust-state models)
MULTIAXIS_FILTER_FREE = {"longitudinal": ("CLalphadot", "Cmalphadot"), "lateral": ("tau_pg",)}


def multi_axis(fd: FlightData) -> bool:
    """Whether the log's elevator windows overlap aileron or rudder windows in time
    (maneuvers on all axes at once, e.g. 3-axis multisines)."""
    lon = [s for s in fd.segments if s.axis == "de"]
    lat = [s for s in fd.segments if s.axis in ("da", "dr")]
    return any(a.t0 < b.t1 and b.t0 < a.t1 for a in lon for b in lat)


def multiaxis_problem(
    fd: FlightData,
    ac: AircraftConstants,
    axis: str,
    *,
    gust_states: bool,
    rate_hz: float | None = None,
    smooth_inputs: bool = True,
    hold_out: int = 1,
) -> Problem:
    """The axis problem for maneuvers that move all axes at once, and for the filters in
    turbulence whatever the maneuvers: the model of that axis driven by the other axis'
    measured variables (longitudinal_measured_lateral / lateral_measured_longitudinal), air
    data at the boom's full position. ``gust_states`` (the filters, in turbulence): the
    Dryden gust states of the models (rotary gusts q_g, p_g in the damping terms), with
    CLalphadot, Cmalphadot (longitudinal; identifiable once the gust angle of attack
    separates alphadot from q) and the roll-gust time constant tau_pg (lateral) free. The
    lateral trim-asymmetry terms are free without the gust states only: the filters'
    process noise on the sideslip and rate equations follows a constant force or moment,
    leaving CY0 no signature but its ay offset, which the accelerometer biases also carry
    (filter error's line search stalls on that near-singular pair)."""
    extra = MULTIAXIS_FILTER_FREE[axis] if gust_states else ()
    if axis == "longitudinal":
        return longitudinal_problem(
            fd,
            ac,
            rate_hz=rate_hz,
            measured_lateral=True,
            rotary_gust=gust_states,
            free=LONG_FREE + extra,
            smooth_inputs=smooth_inputs,
            hold_out=hold_out,
        )
    return lateral_problem(
        fd,
        ac,
        rate_hz=rate_hz,
        measured_longitudinal=True,
        rotary_gust=gust_states,
        free=LAT_FREE + extra,
        smooth_inputs=smooth_inputs,
        hold_out=hold_out,
        trim_asymmetry=not gust_states,
    )
