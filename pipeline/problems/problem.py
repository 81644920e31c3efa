"""The estimation problem a builder hands to the methods."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from estimators import Segment
from estimators.integrators import DEFAULT_INPUTS
from pipeline.ingest.flightdata import SegmentSpec
from pipeline.problems.regressions import Regression

#: problem note when a gust model measures a rebuilt angle as the rigid body's
KINEMATIC_NOTE = (
    "{angle} rebuilt from the flight path (no vane) is measured as {state}, the "
    "rigid body's angle against the mean wind: it carries no gust"
)


@dataclass
class Problem:
    """One estimation problem: a model, the segments it is fitted to, held-out segments."""

    axis: str
    model: Any
    fit: list[Segment]
    held_out: list[Segment]
    specs: list[SegmentSpec]
    held_specs: list[SegmentSpec]
    estimate_x0: bool | Sequence[str] = True
    inputs: str = DEFAULT_INPUTS
    notes: list[str] = field(default_factory=list)
    #: equation-error regressions on the fitted windows (:class:`Regression`)
    regressions: list[Regression] = field(default_factory=list)
    #: grid rate of the segments (Hz)
    rate_hz: float = 0.0
    #: a-priori values {parameter: (value, std)} for output error (OutputError(priors=))
    priors: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: measurement-noise std per output on this grid, from the log's native samples
    #: (pipeline.methods.noise.attach_logged_noise); outputs not in it use the grid's own estimate
    noise_std: dict[str, float] = field(default_factory=dict)
    #: the control-input steps between slow samples of the flight the segments come from,
    #: input -> [(start, end, std or None), ...] s (pipeline.conditioning.input_sampling.step_times)
    step_times: dict[str, list[tuple[float, float, float | None]]] = field(default_factory=dict)
    #: per held-out segment, those of its own flight when they come from other flights
    #: (pipeline.jobs.validation_flights.with_validation_flight); empty: ``step_times`` for each
    held_step_times: list[dict[str, list[tuple[float, float, float | None]]]] = field(default_factory=list)

    def held_out_step_times(self) -> list[dict[str, list[tuple[float, float, float | None]]]]:
        """The control-input steps between slow samples of each held-out segment's flight."""
        return list(self.held_step_times) or [self.step_times] * len(self.held_out)
