"""From canonical flight data to estimation problems: models, segments, start values.

This is where the pipeline decides, for one axis of one flight, which built-in model to
fit, with which constants (:class:`pipeline.ingest.constants.AircraftConstants`), on which
time segments (the maneuvers found in the log), from which start values (an equation-error
regression on the same data), and which maneuver is held out for proof of match.
"""

from pipeline.problems.lateral import (
    LAT_CHANNELS,
    LAT_FREE,
    LAT_OUTPUTS,
    lateral_problem,
    lateral_specs,
    with_airspeed_offsets,
)
from pipeline.problems.longitudinal import (
    LONG_CHANNELS,
    LONG_FREE,
    LONG_OUTPUTS,
    LONG_PSEUDO_LATERAL,
    longitudinal_problem,
)
from pipeline.problems.multiaxis import MULTIAXIS_FILTER_FREE, multi_axis, multiaxis_problem
from pipeline.problems.problem import KINEMATIC_NOTE, Problem
from pipeline.problems.regressions import (
    Regression,
    lateral_regressions,
    lateral_starts,
    longitudinal_regressions,
    longitudinal_starts,
)
from pipeline.problems.sixdof import sixdof_lateral_problem
from pipeline.problems.windows import MAX_RATE_HZ, multirate_frame, usable_segments, with_smoothed_inputs

__all__ = [
    "KINEMATIC_NOTE",
    "LAT_CHANNELS",
    "LAT_FREE",
    "LAT_OUTPUTS",
    "LONG_CHANNELS",
    "LONG_FREE",
    "LONG_OUTPUTS",
    "LONG_PSEUDO_LATERAL",
    "MAX_RATE_HZ",
    "MULTIAXIS_FILTER_FREE",
    "Problem",
    "Regression",
    "lateral_problem",
    "lateral_regressions",
    "lateral_specs",
    "lateral_starts",
    "longitudinal_problem",
    "longitudinal_regressions",
    "longitudinal_starts",
    "multi_axis",
    "multiaxis_problem",
    "multirate_frame",
    "sixdof_lateral_problem",
    "usable_segments",
    "with_airspeed_offsets",
    "with_smoothed_inputs",
]
