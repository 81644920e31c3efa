"""The settings of the jobs, as the commands build them from the command line (plain
dataclasses: the command line reads them without loading the jobs)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

#: the axes of the built-in models
AXES = ("longitudinal", "lateral")


@dataclass(frozen=True)
class FitOptions:
    """How every fit of a job is made and proved.

    inputs: how the inputs vary between samples (estimators.integrators.INPUT_MODES).
    tolerances: proof-of-match bands per channel (SI; None: those of DESIGN.md section 8).
    pom: the proof-of-match mode (auto, simulation, air-data).
    smooth_inputs: the measured surface positions low-passed where a flat noise floor
        begins (:mod:`pipeline.conditioning.input_smoothing`), else as logged.
    calm: the flight is known to be flown in calm air (its flight plan says so): the filters
        fit each axis' own model; otherwise (a real log) the air may be turbulent and the
        filters fit the gust models. No turbulence level enters a fit: the methods derive
        their noise levels from the data.
    validation_calm: the validation flights are known to be flown in calm air (the automatic
        proof-of-match mode is then the open-loop simulation whatever the method).
    hold_out: the last maneuver of each axis is held out for the proof of match when there
        is no validation flight; False: every maneuver is fitted (no proof of match).
    apriori: the aircraft's a-priori values (derivative -> {value, std, source}), judged
        against by the validation; priors: also used as output error's priors.
    signs: derivative -> the sign (+1/-1) the validation expects (None: the defaults,
        :func:`estimators.validation.expected_signs`).
    structure: "stepwise" or "mof": equation error's regressions also searched for the
        structure the data ask for (:mod:`pipeline.methods.structure`).
    """

    inputs: str = "linear"
    tolerances: Mapping[str, float] | None = None
    pom: str = "auto"
    smooth_inputs: bool = True
    calm: bool = False
    validation_calm: bool = False
    hold_out: bool = True
    apriori: Mapping[str, Mapping[str, float | str]] | None = None
    priors: bool = False
    signs: Mapping[str, int] | None = None
    structure: str | None = None


@dataclass(frozen=True)
class EstimationSettings:
    """What ``fsid estimate`` and ``fsid run`` share: how a flight is estimated and reported.

    quiet: no progress lines; compat: run the sensor-compatibility stage; bands:
    proof-of-match bands (``rate_deg_s``, ``accel_g``, ``angle_deg``); pom: the
    proof-of-match mode; smooth_inputs: see :class:`FitOptions`; input_dynamics: auto, off
    or (delay, lag) [s]; figures: draw the report's figures (PNG; off for batch runs that
    read report.json only).
    """

    quiet: bool = False
    compat: bool = True
    bands: Mapping[str, float] | None = None
    pom: str = "auto"
    smooth_inputs: bool = True
    input_dynamics: str | tuple[float, float] = "auto"
    figures: bool = True

    def shared(self) -> dict[str, Any]:
        """This object's :class:`EstimationSettings` fields by name (to build another kind)."""
        return {f.name: getattr(self, f.name) for f in fields(EstimationSettings)}


@dataclass(frozen=True)
class EstimateOptions(EstimationSettings):
    """``fsid estimate``'s settings (see :func:`pipeline.jobs.estimate.estimate_log`):
    :class:`EstimationSettings` and

    aircraft: the aircraft TOML (None: a truth.json next to the log, or none for a user
        model); map_path: a channel map; methods: the method names; inputs: how the inputs
        vary between samples; model: auto, longitudinal, lateral or a user model
        ``path.py:name``; validation_log: a second flight, or several, for the proof of
        match; time_base: of a .tlog or .mcap log; calm, validation_calm: the flight, the
        validation flights known to be flown in calm air (a flight plan's, see
        :class:`FitOptions`; unknown for a real log); segments: the maneuver windows to fit
        (time ranges (t0, t1) [s from the log's start] or segment names,
        :meth:`pipeline.ingest.flightdata.FlightData.chosen_segments`; None: those found);
        hold_out: see :class:`FitOptions`; priors: the aircraft file's a-priori values used
        as output error's priors too; accept_low_rate: estimate axes whose response
        channels are slower than their motion needs, the risk stated in the report;
        structure: see :class:`FitOptions`.
    """

    aircraft: str | Path | None = None
    map_path: str | None = None
    methods: Sequence[str] = ("oem",)
    inputs: str = "linear"
    model: str = "auto"
    validation_log: str | Path | Sequence[str | Path] | None = None
    time_base: str | None = None
    calm: bool = False
    validation_calm: bool = False
    segments: Sequence[str | tuple[float, float]] | None = None
    hold_out: bool = True
    priors: bool = False
    accept_low_rate: bool = False
    structure: str | None = None


@dataclass(frozen=True)
class RunOptions(EstimationSettings):
    """``fsid run``'s settings (see :func:`pipeline.jobs.scenario.run_scenario`):
    :class:`EstimationSettings` and

    seed: instead of the scenario's; methods: the method names (None: those that suit the
    flight plan).
    """

    seed: int | None = None
    methods: Sequence[str] | None = None
