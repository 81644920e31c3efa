"""The estimation stages every fitting job ends with, once its data are corrected for the
sensor errors: the control-input delays and lags, the fits and their validation
(:func:`pipeline.jobs.identify.identify`) and the uncertainty of what the fits held as
exact (:mod:`pipeline.jobs.consider_stage`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from estimators import Model
from pipeline.conditioning.input_dynamics import with_input_dynamics
from pipeline.ingest.constants import AircraftConstants
from pipeline.ingest.flightdata import FlightData
from pipeline.jobs.consider_stage import HeldAsExact, carry_consider_uncertainty
from pipeline.jobs.identify import Identified, identify
from pipeline.jobs.options import AXES, FitOptions
from pipeline.jobs.progress import Progress, quiet_progress
from pipeline.jobs.stages import (
    input_dynamics_stage,
    refine_input_dynamics_stage,
    with_flow_angles,
    with_instrument_errors_removed,
)


@dataclass(frozen=True)
class FitJob:
    """What a job fits: the aircraft (None for a user model), the methods, the built-in
    ``axes`` or a user ``model``, how (``options``), and the truth the validation compares
    with (derivative -> value; None for a real log)."""

    ac: AircraftConstants | None
    methods: Sequence[str]
    truth: Mapping[str, float] | None
    options: FitOptions
    axes: Sequence[str] = AXES
    model: Model | None = None

    def fits(
        self,
        fd: FlightData,
        progress: Progress,
        *,
        methods: Sequence[str] | None = None,
        starts: Mapping[str, Any] | None = None,
        validation: Sequence[FlightData] = (),
        fit_all: bool | None = None,
    ) -> Identified:
        """:func:`pipeline.jobs.identify.identify` of this job on ``fd`` (``methods``: some
        of the job's)."""
        return identify(
            fd,
            self.ac,
            methods or self.methods,
            self.truth,
            progress,
            axes=self.axes,
            model=self.model,
            options=self.options,
            starts=starts,
            validation=list(validation),
            fit_all=fit_all,
        )


@dataclass(frozen=True)
class FlightContext:
    """One flight through the estimation stages: each stage takes it and returns it with
    its own part set (``dataclasses.replace``), so what a later stage reads is what an
    earlier one made, named.

    ac: the aircraft (None for a user model without one); logged: the data as logged
    (with the air-data angles of the flow-angle stage; the corrections' refits correct it
    again); corrected: the compatibility stage's data (angles not rebuilt); comp: its
    document; flow: the air-data-angle stage's document ({} when there was none); ready:
    the data the fits start from (corrected, angles rebuilt), before the control-input
    dynamics; steps: the control-input steps logged more slowly than the fits' grid;
    dynamics: the control-input dynamics stage's document and fitted: ``ready`` with them
    applied (None before that stage).
    """

    ac: AircraftConstants | None
    logged: FlightData
    corrected: FlightData
    comp: dict[str, Any]
    flow: dict[str, Any]
    ready: FlightData
    steps: list
    dynamics: dict[str, Any] | None = None
    fitted: FlightData | None = None


@dataclass(frozen=True)
class FitStages:
    """What :func:`fit_stages` made: the flight's context with its input dynamics, the
    fits by key (text of :class:`pipeline.registry.FitKey`), their validations and
    problems, and the step-timing part of the consider stage's document."""

    context: FlightContext
    results: dict[str, Any]
    validations: dict[str, Any]
    problems: list
    sampling: dict[str, Any]


def fit_stages(
    pr: Progress,
    job: FitJob,
    ctx: FlightContext,
    validation: Sequence[FlightData],
    input_dynamics: str | tuple[float, float],
    meta: dict[str, Any],
) -> FitStages:
    """The control-input dynamics stage (refined by output error's fits), the fits of
    ``job`` proved on the ``validation`` flights (corrected as the fitted flight: its
    instrument errors, ``meta["validation flight corrections"]``, and input dynamics) or on
    held-out maneuvers, and the consider stage."""
    fd_before = ctx.ready
    fd, dyn_doc = input_dynamics_stage(fd_before, pr, input_dynamics)
    fit_all = bool(validation)

    def fits(d: FlightData, starts: Mapping[str, Any], only: Sequence[str] | None = None) -> dict:
        """The fits (of ``only`` methods, default all) repeated on ``d`` from ``starts``."""
        return job.fits(d, quiet_progress(), methods=only, starts=starts, fit_all=fit_all).results

    fd, dyn_doc = refine_input_dynamics_stage(
        fd_before,
        fd,
        dyn_doc,
        job.methods,
        pr,
        lambda dyn, starts: fits(with_input_dynamics(fd_before, dyn), {} if starts is None else starts, only=("oem",)),
    )
    applied = dict(dyn_doc["applied"])
    vals = [with_input_dynamics(with_instrument_errors_removed(fv, ctx.comp, meta), applied) for fv in validation]
    done = job.fits(fd, pr, validation=vals)
    results, validations, problems = done.results, done.validations, done.problems
    starts = dict(results)

    def refit(fd_j: FlightData, st: Mapping[str, Any], wind_offset: Sequence[float] = (0.0, 0.0, 0.0)) -> dict:
        """The fits repeated on corrected data ``fd_j`` (the angles rebuilt with
        ``wind_offset``, the input dynamics applied as in the fits) from ``st``."""
        return fits(with_input_dynamics(with_flow_angles(fd_j, ctx.flow, wind_offset)[0], dyn_doc["applied"]), st)

    # the wind's refits (models that see an air-data angle): the corrected data the fits
    # saw, the angles rebuilt with the wind moved
    angles = any({"alpha", "beta"} & {*pb.model.inputs, *pb.model.outputs} for pb in problems)
    held = HeldAsExact(
        ctx.logged,
        ctx.comp,
        refit,
        flow=ctx.flow,
        wind_refit=(lambda offset: refit(ctx.corrected, starts, offset)) if angles else None,
        dynamics=dyn_doc,
        dynamics_refit=lambda dyn: fits(with_input_dynamics(fd_before, dyn), starts),
        steps=ctx.steps,
        inputs_data=fd_before,
        inputs_refit=lambda d: fits(with_input_dynamics(d, dyn_doc["applied"]), starts),
        held_fits=done.held,
    )
    sampling = carry_consider_uncertainty(held, results, validations, job.truth, pr)
    return FitStages(replace(ctx, dynamics=dyn_doc, fitted=fd), results, validations, problems, sampling)
