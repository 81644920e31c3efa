"""The estimate job: a log -> report and recording (DESIGN.md section 5): ingest, the
aircraft, the air-data angles, the validation flights, the data-quality checks, the sensor
compatibility, then the estimation stages of :mod:`pipeline.jobs.estimation`. ``fsid
estimate`` runs it on a log (:func:`estimate_log`), ``fsid run`` on the log a simulated
flight wrote (:mod:`pipeline.jobs.scenario`)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from estimators import Model
from estimators.validation import default_tolerances
from pipeline.conditioning.checks import run_checks, summarize
from pipeline.conditioning.flow_angles import assumptions as flow_assumptions
from pipeline.conditioning.flow_angles import summary as flow_summary
from pipeline.conditioning.identifiability import identifiability, identifiable_axes, reason_lines
from pipeline.conditioning.input_dynamics import summary as dynamics_summary
from pipeline.conditioning.input_sampling import summary as step_summary
from pipeline.conditioning.input_sampling import time_steps
from pipeline.conditioning.sensor_errors import truth_errors
from pipeline.errors import FsidError
from pipeline.ingest.aircraft import aircraft_for_log, servo_travel_for
from pipeline.ingest.flightdata import FlightData
from pipeline.ingest.readers import detect_format, read_log
from pipeline.ingest.sampling import start_statement
from pipeline.jobs.consider_stage import sampling_meta
from pipeline.jobs.estimation import FitJob, FlightContext, fit_stages
from pipeline.jobs.identify import identified_axes
from pipeline.jobs.options import AXES, EstimateOptions, FitOptions
from pipeline.jobs.progress import Progress
from pipeline.jobs.stages import compatibility_after_flow_angles, flow_angle_stage, with_flow_angles
from pipeline.jobs.validation_flights import validation_flights, validation_prefix
from pipeline.jobs.write import write_outputs
from pipeline.outputs.recording_flight import FlightRecord
from pipeline.problems import MAX_RATE_HZ
from pipeline.problems.user_model import check_channels, is_user_model, load_user_model, split_spec
from pipeline.registry import check_methods
from pipeline.uncertainty.consider import wind_summary


@dataclass
class Estimated:
    """What :func:`estimate` found, for the outputs: the fits (``results``, key -> result)
    and their ``validations``, the ``truth`` they were compared with (None for a real log),
    the report's ``meta``, the log's data-quality ``findings`` (and their ``checks``
    summary) on the ``data`` they were made on, the compatibility document ``comp``, and
    the job's ``progress`` (its last stage, the outputs, still to come)."""

    results: dict
    validations: dict
    truth: dict[str, float] | None
    meta: dict[str, Any]
    findings: list
    checks: dict[str, int]
    data: FlightData
    comp: dict[str, Any]
    progress: Progress


def estimate_log(
    log: str | Path, out: Path, options: EstimateOptions | None = None, **settings: Any
) -> dict[str, Path]:
    """``fsid estimate``: ``log`` -> report.md, report.json, run.rrd in ``out`` (see
    :func:`estimate`); returns name -> path. ``options`` (default EstimateOptions()), or
    its fields as keywords (``settings`` replace those of ``options``)."""
    opts = replace(options or EstimateOptions(), **settings)
    est = estimate(log, opts)
    return write_outputs(
        out,
        est.results,
        est.validations,
        est.truth,
        est.progress,
        checks=est.checks,
        meta=est.meta,
        compatibility=est.comp,
        flight=FlightRecord(est.data, est.findings),
        figures=opts.figures,
    )


def estimate(log: str | Path, opts: EstimateOptions, count: Progress | None = None) -> Estimated:
    """The estimate job on ``log``, up to its outputs.

    model: a built-in model (auto|longitudinal|lateral; needs ``aircraft``, or a truth.json
    next to the log) or a user model ``path.py:name`` (:mod:`pipeline.problems.user_model`).
    Aircraft and sensor positions: :mod:`pipeline.ingest.aircraft`; a truth.json next to
    the log (a simulated flight) gives the aircraft and, for the report only, the true
    derivatives and sensor errors. No turbulence level enters a fit: the EKF/UKF process
    noise is the filter-error method's estimate. ``bands`` and ``pom`` set the proof of
    match (defaults 1.5 deg/s, 0.1 g, 1.5 deg; auto mode). ``validation_log``: a second
    flight, or a sequence of them, for the proof of match (each read with the same map and
    servo travel, its air-data angles rebuilt the same way, the instruments' scale factors
    and air-data delay removed from ``log`` removed from it too): every maneuver of ``log``
    is fitted and the model proved on their maneuvers. ``time_base``: of a .tlog or .mcap
    log and its validation flights of the same format. ``input_dynamics``: the
    control-input delay and lag stage (auto, off or (delay, lag)); they go to the
    validation flights too (the same servos). ``count``: a job's Progress this one continues
    (``fsid run``'s, whose total planned these stages), instead of its own."""
    user = is_user_model(opts.model)
    if user:  # cheap checks before the log is read
        split_spec(opts.model)
    check_methods(opts.methods, user_model=user)
    axes = AXES if opts.model == "auto" else (opts.model,)
    vlogs = validation_flights(opts.validation_log)
    t0 = time.perf_counter()
    fd, steps, steps_doc = time_steps(
        read_log(log, map=opts.map_path, servo_travel=servo_travel_for(log, opts.aircraft), time_base=opts.time_base),
        MAX_RATE_HZ,
    )
    if opts.segments:  # the user's windows, in seconds from the log's start
        fd.segments = fd.chosen_segments(opts.segments)
    n_axes = 1 if user else identified_axes(fd, axes)
    stages = stage_count(len(opts.methods), n_axes, len(vlogs), user)
    pr = count.plan(stages) if count is not None else Progress(stages, quiet=opts.quiet)
    pr.stage(f"ingest {log}", since=t0)
    pr.done(
        f"{len(fd.channels)} channels, {len(fd.segments)} segments"
        + (f"; {step_summary(steps_doc)}" if steps_doc else "")
    )
    try:
        ac, ac_name, truth_doc = _aircraft(log, opts, fd, user, pr)
    except FsidError:
        if not user:  # a log with nothing to fit says so before it asks for an aircraft
            _identifiable(fd, run_checks(fd), None, axes, log, opts, len(vlogs), pr)
        raise
    _check_priors(opts, ac)
    fd.meta["stall_speed_mps"] = getattr(ac, "stall_speed", None)  # the airborne floor
    truth = (
        {k: float(v) for k, v in truth_doc["derivatives"].items()}
        if truth_doc and truth_doc.get("derivatives")
        else None
    )
    ac_sensors = ac
    fd, ac, fd_logged, flow = flow_angle_stage(fd, ac, pr)
    fd_vals, val_checks = _validation_flights(log, vlogs, fd, flow, ac_sensors, opts, pr)
    for vfd in fd_vals:  # the same aircraft
        vfd.meta["stall_speed_mps"] = fd.meta["stall_speed_mps"]
    um = _user_model(opts.model, ac, fd, pr) if user else None
    pr.stage("data-quality checks")
    findings = run_checks(fd)
    summary = summarize(findings)
    pr.done(str(summary))
    if not user:  # refused before any fit, for the reasons fsid check gives
        axes = _identifiable(fd, findings, ac, axes, log, opts, len(vlogs), pr)
    meta = {"log": str(log), "aircraft": ac_name, "time": start_statement(fd.meta)}
    if "rate risk" in fd.meta:
        meta["rate risk"] = fd.meta["rate risk"]
    if fd_vals:
        meta["validation flight"] = "; ".join(
            f"{validation_prefix(k, len(vlogs))}{vlog}" if len(vlogs) > 1 else str(vlog) for k, vlog in enumerate(vlogs)
        ) + (
            f": the proof of match; every maneuver of {Path(log).name} fitted; data-quality "
            "checks: " + "; ".join(", ".join(f"{k} {v}" for k, v in c.items()) for c in val_checks)
        )
    _servo_travel(fd, meta, pr, opts.quiet)
    ctx = _corrected(fd, fd_logged, flow, ac, ac_sensors, truth_doc, steps, meta, opts, pr)
    meta["data"] = f"{Path(log).name}, {ctx.comp['data_for_estimation']}"
    job = FitJob(ctx.ac, opts.methods, truth, _fit_options(opts, ctx.ac), axes=axes, model=um)
    done = fit_stages(pr, job, ctx, fd_vals, opts.input_dynamics, meta)
    if user:
        meta["model"] = opts.model
    ctx = done.context
    _fit_meta(meta, ctx.dynamics, sampling_meta(steps_doc, done.sampling), ctx.flow, truth is not None)
    return Estimated(done.results, done.validations, truth, meta, findings, summary, fd, ctx.comp, pr)


def _check_priors(opts: EstimateOptions, ac: Any) -> None:
    """``--priors`` needs the aircraft's [apriori] values: one error when it has none."""
    if opts.priors and not (ac is not None and ac.apriori):
        raise FsidError(
            f"--priors: the aircraft ({opts.aircraft or 'truth.json next to the log'}) gives no "
            "[apriori] values; add them to the aircraft file (e.g. Cmq = { value = -12.0, std = 4.0 }) "
            "or leave --priors out"
        )


def _fit_options(opts: EstimateOptions, ac: Any) -> FitOptions:
    """The fits' settings from the job's options and the aircraft's a-priori values and
    expected signs."""
    return FitOptions(
        inputs=opts.inputs,
        tolerances=default_tolerances(**(opts.bands or {})),
        pom=opts.pom,
        smooth_inputs=opts.smooth_inputs,
        calm=opts.calm,
        validation_calm=opts.validation_calm,
        hold_out=opts.hold_out,
        apriori=dict(ac.apriori) if ac is not None and ac.apriori else None,
        priors=opts.priors,
        signs=ac.expected_signs() if ac is not None else None,
        structure=opts.structure,
    )


def _fit_meta(meta: dict[str, Any], dyn_doc: Any, sampling: dict[str, Any], flow: dict[str, Any], truth: bool) -> None:
    """What the fit stages add to the report's metadata: the input dynamics and sampling,
    the rebuilt angles' wind uncertainty, where the truth came from."""
    meta["control-input delay and lag"] = dynamics_summary(dyn_doc)
    meta["input_dynamics"] = dyn_doc
    meta.update(sampling)
    if "wind_uncertainty" in flow:
        meta["flow_angles"]["wind_uncertainty"] = flow["wind_uncertainty"]
        meta["air-data angles' wind"] = wind_summary(flow["wind_uncertainty"])
    if truth:
        meta["truth"] = "truth.json next to the log"


def stage_count(n_methods: int, n_axes: int, n_validation: int, user: bool) -> int:
    """The stages of :func:`estimate`, the outputs included: ingest, aircraft, air-data angles; per validation
    flight its ingest and angles; the user model's loading; checks, compatibility, input
    dynamics; a fit and its validation per method and axis; the uncertainty of what the fits
    held, outputs."""
    return 3 + 2 * n_validation + int(user) + 3 + 2 * max(n_axes, 1) * n_methods + 2


def _identifiable(
    fd: FlightData,
    findings: list,
    ac: Any,
    axes: tuple[str, ...],
    log: str | Path,
    opts: EstimateOptions,
    n_validation: int,
    pr: Progress,
) -> tuple[str, ...]:
    """Those of ``axes`` the flight can identify (:mod:`pipeline.conditioning.identifiability`,
    the verdict fsid check ends with; a maneuver per axis held out unless validation flights
    or ``opts.hold_out`` say otherwise): FsidError with every reason, one line each, when none
    can; else a note per reason an axis is left out, its fits taken out of the stage count."""
    hold_out = 0 if n_validation or not opts.hold_out else 1
    ident = identifiability(fd, findings, ac, hold_out=hold_out, axes=axes, accept_low_rate=opts.accept_low_rate)
    ok = identifiable_axes(ident, axes, str(log))
    risks = list(dict.fromkeys(r for a in ok for r in ident[a].risks))
    if risks:  # the user's soft limit: said now and in the report (fd.meta reaches its facts)
        fd.meta["rate risk"] = (
            "; ".join(risks) + " - estimated anyway (--accept-low-rate): the fastest motion is undersampled, "
            "so the derivatives it carries may be biased and their std too small"
        )
        print(f"note: {fd.meta['rate risk']}", file=pr.stream)
    for line in reason_lines(ident, [a for a in axes if a not in ok]) if not opts.quiet else ():
        print(f"note: not identified: {line}", file=pr.stream)
    n = len(opts.methods)
    dropped = stage_count(n, identified_axes(fd, axes), 0, False) - stage_count(n, identified_axes(fd, ok), 0, False)
    if dropped:
        pr.plan(pr.total - pr.n - dropped)
    return ok


def _aircraft(
    log: str | Path, opts: EstimateOptions, fd: FlightData, user: bool, pr: Progress
) -> tuple[Any, str | None, dict | None]:
    """The aircraft stage: (constants, name, truth.json document next to the log or None),
    with the notes of where they came from."""
    pr.stage("aircraft and sensor positions")
    notes: list[str] = []
    ac, ac_name, truth_doc = aircraft_for_log(log, opts.aircraft, fd, required=not user, say=notes.append)
    pr.done(ac_name or "none (user model)")
    for n in notes if not opts.quiet else ():
        print(n, file=pr.stream)
    return ac, ac_name, truth_doc


def _validation_flights(
    log: str | Path, vlogs: list, fd: FlightData, flow: dict[str, Any], ac: Any, opts: EstimateOptions, pr: Progress
) -> tuple[list[FlightData], list[dict]]:
    """The validation flights read as ``log`` was (its map, servo travel and, for the same
    format, time base), their air-data angles rebuilt with the fitted flight's pitot scale
    factor, and their data-quality check summaries; a stage each for the ingest and the
    angles."""
    seen = {Path(log).resolve(): "the log being fitted"}
    for vlog in vlogs:
        if Path(vlog).resolve() in seen:
            raise FsidError(
                f"--validate-with {vlog}: that is {seen[Path(vlog).resolve()]}; "
                "give another flight (or leave it out to hold out the last maneuver)"
            )
        seen[Path(vlog).resolve()] = "a validation flight already given"
    # the same pitot: a validation flight takes the fitted flight's scale factor
    cal = flow.get("airspeed_scale") or {}
    k_pitot = cal["estimate"] if cal.get("applied") else (0.0 if cal.get("carried") else None)
    fd_vals, val_checks = [], []
    for vlog in vlogs:
        pr.stage(f"ingest the validation flight {vlog}")
        fv = time_steps(
            read_log(
                vlog,
                map=opts.map_path,
                servo_travel=servo_travel_for(vlog, opts.aircraft),
                time_base=opts.time_base if detect_format(vlog) == fd.meta["format"] else None,
            ),
            MAX_RATE_HZ,
        )[0]
        pr.done(f"{len(fv.channels)} channels, {len(fv.segments)} segments")
        fd_vals.append(flow_angle_stage(fv, ac, pr, airspeed_scale=k_pitot)[0])
        val_checks.append(summarize(run_checks(fd_vals[-1])))
    return fd_vals, val_checks


def _user_model(spec: str, ac: Any, fd: FlightData, pr: Progress) -> Model:
    """The user model ``spec`` loaded and checked against the log's channels (a stage,
    before the slow ones: a bad model fails at once)."""
    pr.stage(f"load model {spec}")
    um = load_user_model(spec, ac, fd)
    check_channels(fd, um)
    pr.done(
        f"{um.name}: {len(um.states)} states, {len(um.inputs)} inputs, "
        f"{len(um.outputs)} outputs, {sum(p.free for p in um.parameters)} free parameters"
    )
    return um


def _servo_travel(fd: FlightData, meta: dict[str, Any], pr: Progress, quiet: bool) -> None:
    """The servo travel the surface positions were decoded with, into ``meta``; a note when
    it was assumed (the control derivatives scale with it)."""
    if not fd.meta.get("servo_travel"):
        return
    meta["servo_travel"] = fd.meta["servo_travel"]
    assumed = [k for k, v in fd.meta["servo_travel"].items() if v["from"] == "assumed"]
    if assumed and not quiet:
        print(
            f"note: {', '.join(assumed)} from servo commands with "
            f"{fd.meta['servo_travel'][assumed[0]]['deg']:g} deg at full travel assumed; the "
            f"control derivatives scale with it: give the aircraft TOML's [servos] "
            f"({', '.join(a + '_travel_deg' for a in assumed)})",
            file=pr.stream,
        )


def _corrected(
    fd: FlightData,
    fd_logged: FlightData,
    flow: dict[str, Any],
    ac: Any,
    ac_sensors: Any,
    truth_doc: dict | None,
    steps: list,
    meta: dict[str, Any],
    opts: EstimateOptions,
    pr: Progress,
) -> FlightContext:
    """The flight's context after the compatibility stage on the logged channels only
    (angles rebuilt from the GPS velocity and attitude are no independent air data), then
    the angles rebuilt from the corrected data (or, not rebuilt, the derived ones kept as
    logged). ``ac``: the aircraft the fits use, ``ac_sensors``: its sensor positions as the
    aircraft file gives them (the compatibility stage's)."""
    fd_c, comp = compatibility_after_flow_angles(
        fd_logged, fd, flow, ac_sensors, pr, enabled=opts.compat, truth=truth_errors(truth_doc) if truth_doc else None
    )
    if flow.get("status") == "reconstructed":
        fd, flow = with_flow_angles(fd_c, flow)  # rebuilt from the corrected data
        meta["air-data angles"] = flow_summary(flow)
        meta["air-data angles assume"] = flow_assumptions(flow)
        meta["flow_angles"] = {**flow, "data": comp["data_for_estimation"]}
    else:  # derived angles not rebuilt: as logged
        fd = replace(
            fd_c, channels={**fd_c.channels, **{k: c for k, c in fd.channels.items() if k not in fd_c.channels}}
        )
    return FlightContext(ac=ac, logged=fd_logged, corrected=fd_c, comp=comp, flow=flow, ready=fd, steps=steps)
