"""One fit of one method on one problem, validated on its held-out segments
(:func:`fit_and_validate`), and its refits from an earlier result (the consider stage's)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from estimators import EstimationError, EstimationResult, IdentifiabilityError, ModelDefinitionError, OutputError
from pipeline.ingest.constants import AircraftConstants
from pipeline.ingest.flightdata import FlightData
from pipeline.jobs.options import FitOptions
from pipeline.jobs.progress import Progress, counted, quiet_progress
from pipeline.methods.alphadot import ALPHADOT_PAIRS, free_alphadot, inseparable_alphadot, unidentifiable_alphadot
from pipeline.methods.fitting import fit_problem
from pipeline.problems import Problem, sixdof_lateral_problem
from pipeline.registry import Method, method_spec
from pipeline.validation import validate, widened


def fit_and_validate(
    pb: Problem,
    method: str,
    what: str,
    truth: Mapping[str, float] | None,
    progress: Progress,
    *,
    options: FitOptions | None = None,
    start: Mapping[str, float] | Any = None,
    process_noise: Mapping[str, float] | None = None,
    calm_air: bool = False,
    held_alphadot: str | None = None,
) -> tuple[Any, dict[str, Any] | None] | None:
    """Fit ``method`` on ``pb`` and validate the result on its held-out segments, with a
    progress stage each; ``what`` names the fit in messages ("lateral axis", "model 'x'");
    ``options``: the proof-of-match bands and mode (default FitOptions()). A method that
    fails - an EstimationError (plain OEM diverging on an unstable aircraft) or a singular
    matrix inside a method on a model it cannot handle - is reported and gives None: one
    method failing must not cost the others. Returns (result, validation).

    start : a refit (the consider stage's): fit only, no validation (returns (result,
        None)), starting from these values (or the values of this earlier result) for the
        methods whose estimate does not depend on the start (``Method.start_free``; the
        EKF/UKF start as before). Output error given its earlier result moves it by one
        Gauss-Newton step with that fit's sensitivities
        (:meth:`estimators.OutputError.step_from`) instead of refitting.
    process_noise: the EKF/UKF process noise (state -> F).
    calm_air: the held-out maneuvers are known to be flown in calm air.
    held_alphadot: the note of another method's fit of this axis that held CLalphadot,
        Cmalphadot (its ``extra["alphadot_held"]``): this fit holds them too, so the
        methods estimate, and are cross-checked on, the same derivatives. Otherwise a fit
        that cannot separate them from CLq, Cmq is repeated with them held."""
    spec = method_spec(method)
    options = options or FitOptions()
    earlier = start if isinstance(start, EstimationResult) else None
    start = start.params if earlier is not None else start
    refit = start is not None
    pb, alphadot = _alphadot_held(pb, start, held_alphadot)
    pb = _with_priors(pb, options)
    if refit and spec.start_free and len(start):  # (then fit_problem's equation-error starts off)
        free = {p.name for p in pb.model.parameters if p.free}  # held values stay the problem's
        pb = replace(
            pb,
            model=pb.model.with_values({n: v for n, v in start.items() if n in free}),
            regressions=pb.regressions if spec.regressions else [],
        )
    if not refit:
        progress.stage(
            f"estimate {what} ({method.upper()}, {pb.model.name} model, "
            f"{counted(len(pb.fit), 'maneuver')}, {len(pb.held_out)} held out, {pb.rate_hz:g} Hz)"
        )

    def fit(p: Problem) -> Any:
        return _fit(p, spec, start, earlier, process_noise, progress)

    try:
        res, pb = _fit_holding_alphadot(fit, pb, what, spec, progress, alphadot, refit, held_alphadot)
    except (EstimationError, np.linalg.LinAlgError) as exc:
        if refit:
            return None
        progress.done(f"FAILED: {exc}")
        print(f"note: {method.upper()} on the {what} failed: {exc}", file=progress.stream)
        progress.stage(f"validate {what} {method.upper()} (skipped)")
        progress.done()
        return None
    if refit:
        return res, None
    progress.done(f"{'converged' if res.converged else 'NOT converged'} in {counted(res.iterations, 'iteration')}")
    progress.stage(f"validate {what} {method.upper()} (fit, residuals, modes, proof of match)")
    v = validate(
        res,
        held_out=pb.held_out,
        truth=truth,
        tolerances=options.tolerances,
        proof_of_match=options.pom,
        calm_air=calm_air,
        step_times=pb.held_out_step_times(),
        apriori=options.apriori,
        signs=options.signs,
    )
    v["problem"] = {"notes": list(pb.notes)}
    if options.structure and spec.regressions:  # what structure the data ask for (the report's)
        from pipeline.methods.structure import structure_search

        res = res.with_extra(structure=structure_search(pb, options.structure))
    progress.done()
    return widened(res, v["uncertainty"]), v


def _with_priors(pb: Problem, options: FitOptions) -> Problem:
    """``pb`` with the aircraft's a-priori values of its free parameters as priors when the
    job asks for them (``options.priors``), and a note naming them."""
    if not (options.priors and options.apriori):
        return pb
    free = {p.name for p in pb.model.parameters if p.free}
    got = {n: (float(d["value"]), float(d["std"])) for n, d in options.apriori.items() if n in free}
    if not got:
        return pb
    note = "a-priori values as priors (output error's a-priori penalty; other methods ignore them): " + ", ".join(
        f"{n} {v:g} +- {sd:g}" for n, (v, sd) in got.items()
    )
    return replace(pb, priors={**pb.priors, **got}, notes=[*pb.notes, note])


def _alphadot_held(pb: Problem, start: Any, held_alphadot: str | None) -> tuple[Problem, list[str]]:
    """(``pb`` with CLalphadot, Cmalphadot held at 0 where the fit repeats one that held
    them - a free estimate is never exactly 0 - or another method's fit held them
    (``held_alphadot``), the free alphadot derivatives left to check)."""
    alphadot = free_alphadot(pb.model)
    if start is not None and alphadot and all(start.get(b) == 0.0 for b in alphadot):
        pb = replace(pb, model=pb.model.hold({b: 0.0 for b in alphadot}))
    elif alphadot and held_alphadot:
        pb = replace(
            pb,
            model=pb.model.hold({b: 0.0 for b in alphadot}),
            notes=[*pb.notes, f"{held_alphadot} (found by filter error's fit)"],
        )
        alphadot = []
    return pb, alphadot


def _fit(
    pb: Problem,
    spec: Method,
    start: Mapping[str, float] | None,
    earlier: Any,
    process_noise: Mapping[str, float] | None,
    progress: Progress,
) -> Any:
    """One fit of ``spec`` on ``pb``: from ``start`` in a refit (``earlier``: the result it
    repeats), with the iterations ticked on the progress line otherwise."""
    refit = start is not None
    if earlier is not None and spec.one_step_refit and earlier.sensitivities is not None:
        # a refit moves the estimates by a fraction of their std: one Gauss-Newton step with
        # the earlier sensitivities is their first-order change
        try:
            return OutputError(pb.model, inputs=pb.inputs).step_from(earlier, pb.fit, estimate_x0=pb.estimate_x0)
        except ModelDefinitionError:
            pass  # other parameters or segments: refit
    # a refit starts from all the free values, initial states, per-segment values and
    # filter error's F included; the held ones stay the problem's (the values a refit
    # moves). The other start-free methods get the model's values.
    free = {p.name for p in pb.model.parameters if p.free}
    carry = (
        {n: v for n, v in start.items() if n.split("[")[0] in free or n.startswith(spec.refit_carry)}
        if refit and spec.refit_carry
        else None
    )
    return fit_problem(
        pb,
        spec.name,
        process_noise=process_noise,
        callback=None if refit else lambda it, cost, p: progress.tick(str(it + 1)),
        start=carry,
    )


def _fit_holding_alphadot(
    fit: Callable[[Problem], Any],
    pb: Problem,
    what: str,
    spec: Method,
    progress: Progress,
    alphadot: list[str],
    refit: bool,
    held_alphadot: str | None,
) -> tuple[Any, Problem]:
    """(result, problem) of ``fit(pb)``, repeated with the ``alphadot`` derivatives held
    at 0 (a substage) when the first fit could not separate them or stopped on them."""
    try:
        res = fit(pb)
        held = inseparable_alphadot(res) if alphadot and not refit else None
    except IdentifiabilityError as exc:
        held = unidentifiable_alphadot(exc, alphadot) if not refit else None
        if held is None:
            raise
        res = None
    if held is not None:
        progress.done(
            ("not identifiable" if res is None else "converged" if res.converged else "NOT converged")
            + "; alphadot derivatives not separable: refit with them held"
        )
        pb = replace(pb, model=pb.model.hold({b: 0.0 for b in alphadot}), notes=[*pb.notes, held])
        progress.substage(f"estimate {what} ({spec.name.upper()}, {pb.model.name} model, CLalphadot, Cmalphadot held)")
        res = fit(pb).with_extra(alphadot_held=held)
    elif held_alphadot and not [b for _, b in ALPHADOT_PAIRS if b in res.free_names]:
        res = res.with_extra(alphadot_held=held_alphadot)
    return res, pb


def held_refit(
    fd: FlightData, ac: AircraftConstants, options: FitOptions, res: Any, hold_out: int = 1
) -> Callable[[Mapping[str, float]], Any]:
    """values -> the 6-DoF lateral output error ``res`` refitted with those longitudinal
    values held, started from ``res`` (on the same maneuvers: ``hold_out`` as in the fit).
    The problem is built once, at the first call: the held values enter only its model's
    values."""
    built: list[Problem] = []

    def refit(values: Mapping[str, float]) -> Any:
        if not built:
            built.append(
                sixdof_lateral_problem(
                    fd, ac, longitudinal=values, smooth_inputs=options.smooth_inputs, hold_out=hold_out
                )
            )
            built[0].inputs = options.inputs
        pb = built[0]
        held = {
            n: float(v) for n, v in values.items() if n in pb.model.parameter_names and not pb.model.parameter(n).free
        }
        done = fit_and_validate(
            replace(pb, model=pb.model.with_values(held)), "oem", "lateral axis", None, quiet_progress(), start=res
        )
        return None if done is None else done[0]

    return refit
