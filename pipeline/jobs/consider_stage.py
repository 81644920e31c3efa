"""The stage after the fits: what each fit held as exact gets its uncertainty into the
results' ``consider_cov`` (:mod:`pipeline.uncertainty.consider`), then the truth checks and
verdicts are redone with the total std."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from pipeline.conditioning.input_sampling import summary as step_summary
from pipeline.ingest.flightdata import FlightData
from pipeline.jobs.progress import Progress
from pipeline.uncertainty.consider import fitted_steps, held_estimates, input_dynamics, input_sampling, propagate, wind
from pipeline.validation import refresh_plausibility, refresh_prediction_uncertainty, refresh_truth_check


@dataclass
class HeldAsExact:
    """What the fits held as exact and how to repeat them with it moved.

    fd_logged: the data as logged, before the sensor corrections; comp: the compatibility
    document (``applied`` corrections, their covariance); refit(fd, starts): the fits on
    other corrected data (results only). flow: the air-data-angle document
    (``wind_uncertainty`` goes to it); wind_refit(offset): the fits with the rebuilt angles'
    wind moved (None: no angle rebuilt that a model sees). dynamics: the control-input
    dynamics document (``uncertainty`` goes to it); dynamics_refit(dynamics): the fits with
    other delays and lags. steps: the control-input steps logged more slowly than the fits'
    grid (:func:`pipeline.conditioning.input_sampling.time_steps`' list); inputs_data: the
    data before the input dynamics; inputs_refit(data): the fits on data with steps moved.
    held_fits: key -> :class:`pipeline.jobs.identify.HeldFit` of the fits that held
    another axis' estimates.
    """

    fd_logged: FlightData
    comp: dict[str, Any]
    refit: Callable[[FlightData, dict], Mapping[str, Any]]
    flow: dict[str, Any] | None = None
    wind_refit: Callable[[tuple[float, ...]], Mapping[str, Any]] | None = None
    dynamics: dict[str, Any] | None = None
    dynamics_refit: Callable[[dict], Mapping[str, Any]] | None = None
    steps: Sequence[Any] = ()
    inputs_data: FlightData | None = None
    inputs_refit: Callable[[FlightData], Mapping[str, Any]] | None = None
    held_fits: Mapping[str, Any] = field(default_factory=dict)


def carry_consider_uncertainty(
    held: HeldAsExact, results: dict, validations: dict, truth: Mapping[str, float] | None, progress: Progress
) -> dict[str, Any]:
    """One stage: the other axis' estimates a fit held (``held.held_fits``, the 6-DoF
    lateral output error holding the longitudinal derivatives; the doc goes to the
    validation's ``held_estimates``), the sensor corrections applied before estimation
    (``comp["propagation"]``), the wind of air-data angles rebuilt from the flight path
    (``flow["wind_uncertainty"]``), the control-input delays and lags applied before the
    fits (``dynamics["uncertainty"]``) and the times of the control-input steps logged more
    slowly than the fits' grid, each carried to the results' consider covariance by refits;
    then the truth checks and verdicts are redone with the total std. Returns the
    step-timing part's document (empty when no input is slow)."""
    comp, flow, dynamics = held.comp, held.flow, held.dynamics
    kept = [k for k in held.held_fits if k in results]
    rebuilt = (flow or {}).get("status") == "reconstructed" and held.wind_refit is not None
    delayed = bool(
        (dynamics or {}).get("status") == "estimated" and dynamics.get("applied") and held.dynamics_refit is not None
    )
    slow = (
        held.inputs_refit is not None and held.inputs_data is not None and bool(fitted_steps(list(held.steps), results))
    )
    parts = [f"{k}: held estimates" for k in kept]
    parts += [f"{len(comp['applied'])} sensor corrections"] if comp.get("applied") else []
    parts += ["the wind of the rebuilt air-data angles"] if rebuilt else []
    parts += [f"the delay and lag of {len(dynamics['applied'])} control inputs"] if delayed else []
    parts += ["the times of the control-input steps between slow samples"] if slow else []
    progress.stage("uncertainty of what the fits held as exact" + (f" ({', '.join(parts)})" if parts else ""))
    for k in kept:
        doc = held_estimates(results, k, held.held_fits[k].result, held.held_fits[k].refit, progress)
        if k in validations:
            validations[k]["held_estimates"] = doc
    if comp.get("applied"):
        comp["propagation"] = propagate(held.fd_logged, comp, results, held.refit, progress)
    if rebuilt:
        flow["wind_uncertainty"] = wind(flow, results, held.wind_refit, progress)
    if delayed:
        dynamics["uncertainty"] = input_dynamics(dynamics, results, held.dynamics_refit, progress)
    sampling = input_sampling(held.inputs_data, results, held.inputs_refit, list(held.steps), progress) if slow else {}
    for key, res in results.items():
        if key in validations:
            refresh_prediction_uncertainty(validations[key], res)
            refresh_truth_check(validations[key], res, truth)
            refresh_plausibility(validations[key], res)
    progress.done(
        "nothing held"
        if not parts
        else f"{sum(r.consider_cov is not None for r in results.values())} of {len(results)} fits with a consider part"
    )
    return sampling


def sampling_meta(timing: Mapping[str, Any], carried: Mapping[str, Any]) -> dict[str, Any]:
    """report.json/report.md meta entries of control inputs logged more slowly than the
    gyros: their steps timed from the rates (``timing``, the document of
    :func:`pipeline.conditioning.input_sampling.time_steps`) and those times' uncertainty
    carried to the estimates (``carried``, :func:`pipeline.uncertainty.consider.input_sampling`'s);
    none when no input was slow."""
    if not timing:
        return {}
    line = step_summary(timing)
    if carried:
        chans = ", ".join(
            f"{c} {v['steps']} ({v['timed']} timed, rms std {1e3 * v['time_std_s']:.1f} ms)"
            for c, v in carried["channels"].items()
        )
        line += (
            f"; the fitted windows' steps ({chans}) carried to the estimates' total std ({carried['refits']} refits)"
        )
    return {"control-input sampling": line, "input_sampling": {**timing, "uncertainty": dict(carried)}}
