"""How each method of :mod:`pipeline.registry` fits a problem (the functions its entries
name as ``fitter``, :func:`fit_problem`), and the process noise the Kalman filters take
from a filter-error fit when no turbulence level is known (:func:`filters_process_noise`)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from estimators import (
    EKF,
    UKF,
    EigenvalueTransformation,
    EquationDecoupling,
    EstimationError,
    FilterError,
    ModelDefinitionError,
    OutputError,
    StabilizedOutputError,
)
from estimators.filters.fem_problem import dependent_outputs
from pipeline.ingest.flightdata import FlightData
from pipeline.methods.equation_error import equation_error, raw_starts
from pipeline.methods.noise import (
    GUST_NOISE_PARAMETERS,
    attach_logged_noise,
    dryden_known,
    filter_param_std,
    filter_process_noise,
    measurement_noise_std,
    process_noise_std,
)
from pipeline.problems import Problem
from pipeline.registry import method_spec

#: Gauss-Newton iterations of a filter-error refit from an earlier estimate (a consider
#: part's): it moves the estimate by a fraction of its std, a few iterations from a
#: converged fit; one from a fit that did not converge does not converge either
FEM_REFIT_MAX_ITER = 10


@dataclass(frozen=True)
class FitSettings:
    """What a fit takes besides the problem and its model (see :func:`fit_problem`)."""

    turbulence: Mapping[str, Any] | None = None
    process_noise: Mapping[str, float] | None = None
    measurement_noise: Mapping[str, float] | None = None
    callback: Callable[[int, float, Any], None] | None = None
    start: Mapping[str, float] | None = None


def fit_problem(
    problem: Problem,
    method: str,
    *,
    turbulence: Mapping[str, Any] | None = None,
    process_noise: Mapping[str, float] | None = None,
    measurement_noise: Mapping[str, float] | None = None,
    callback: Callable[[int, float, Any], None] | None = None,
    start: Mapping[str, float] | None = None,
) -> Any:
    """Run one estimation method (a name of the catalogue) on a problem. ``turbulence``:
    the Dryden level when known, for the filters' process noise; else ``process_noise``
    (EKF/UKF: state -> F, e.g. :func:`pipeline.methods.noise.filter_process_noise`), else
    the data's default. ``measurement_noise``: EKF/UKF R as output -> std (default: the
    grid's second differences). ``start``: output error's and filter error's start values
    by expanded name (initial states ``x0_V[0]`` and per-segment parameters included: a
    refit from an earlier estimate). ``callback``: called after each iteration (OEM, FEM)
    or pass (EKF, UKF) as callback(iteration, cost, params)."""
    spec = method_spec(method)
    model = problem.model
    if spec.unclamped_starts and problem.regressions:
        model = model.with_values(raw_starts(problem))
    settings = FitSettings(turbulence, process_noise, measurement_noise, callback, start)
    return spec.fit_function()(problem, model, settings)


def _output_error(problem: Problem, model: Any, s: FitSettings) -> Any:
    return OutputError(model, inputs=problem.inputs, priors=problem.priors or None, callback=s.callback).fit(
        problem.fit, estimate_x0=problem.estimate_x0, start=s.start
    )


def _equation_error(problem: Problem, model: Any, s: FitSettings) -> Any:
    return equation_error(problem)


def _filter_error(problem: Problem, model: Any, s: FitSettings) -> Any:
    """The nonlinear form (integrator prediction, gain of the linearisation at each
    segment's start); the full innovation covariance where no output is an exact function
    of the others (the likelihood's: the reference's diagonal one biases derivatives where
    the innovations are correlated, as turbulence makes them), else the diagonal; the
    sampled filter's gain (the gust states are fast against the sample interval, where
    the reference's continuous-form gain is off); process noise started from the turbulence level and estimated; R
    started at the measurement-noise level and estimated by relaxation (no output-error run
    from equation-error starts that may diverge)."""

    def fem(m: Any, estimate_F: bool = True) -> Any:
        return FilterError(
            m,
            form="nonlinear",
            full_R=not dependent_outputs(m, problem.fit),
            gain="discrete",
            inputs=problem.inputs,
            process_noise=process_noise_std(problem, s.turbulence),
            measurement_noise=measurement_noise_std(problem),
            estimate_F=estimate_F,
            callback=s.callback,
            **({} if s.start is None else {"max_iter": FEM_REFIT_MAX_ITER}),
        ).fit(problem.fit, estimate_x0=problem.estimate_x0, start=s.start)

    res = fem(model)
    if not res.converged and s.start is None:  # a refit from an earlier estimate is not restarted
        res = _fem_restart(problem, model, res, fem)
    return res


def _fem_restart(problem: Problem, model: Any, res: Any, fem: Callable[..., Any]) -> Any:
    """Filter error again when its fit did not converge: first the derivatives with the
    process noise (F, and the gust models' time constants) held at their starts, then
    everything from there. The result of lower cost is kept, and the problem's notes say
    which. Equation-error starts can be far off in turbulence, where the fit from them may
    wander into the noise parameters' bounds."""
    held = {
        n: model.parameter(n).value
        for n in GUST_NOISE_PARAMETERS
        if n in model.parameter_names and model.parameter(n).free
    }
    first = fem(model.hold(held) if held else model, estimate_F=False)
    free = {n for n in model.parameter_names if model.parameter(n).free}
    again = fem(model.with_values({n: v for n, v in first.params.items() if n in free}))
    better = again.cost < res.cost
    problem.notes.append(
        f"filter error did not converge from the equation-error starts (det R {res.cost:.4g}); "
        f"refitted with the process noise held first, then free: det R {again.cost:.4g}, "
        f"{'converged' if again.converged else 'not converged'}; "
        f"{'that fit is kept' if better else 'the first fit is kept'}"
    )
    return again if better else res


def _kalman_filter(cls: type) -> Callable[[Problem, Any, FitSettings], Any]:
    """The fit of an EKF or UKF (``cls``). Process noise: twice the Dryden level when known
    (white noise standing in for coloured gusts has to carry what it misses while the
    parameters are still uncertain), else the given one (filter error's, see
    :func:`filters_process_noise`), else the data's default doubled. R: the grid's own
    second differences, the level that process noise was set against."""

    def fit(problem: Problem, model: Any, s: FitSettings) -> Any:
        Q = (
            process_noise_std(problem, s.turbulence, 2.0)
            if dryden_known(s.turbulence) or s.process_noise is None
            else {k: v for k, v in s.process_noise.items() if k in model.states}
        )
        return cls(
            model,
            inputs=problem.inputs,
            process_noise=Q,
            measurement_noise=(
                dict(s.measurement_noise)
                if s.measurement_noise is not None
                else measurement_noise_std(problem, logged=False)
            ),
            param_std=filter_param_std(model),
            callback=s.callback,
        ).fit(problem.fit)

    return fit


def _stabilized_output_error(problem: Problem, model: Any, s: FitSettings) -> Any:
    """Feeds back only the short-period measurements where the model has them (the slow
    states fed back too hold the lift derivatives); central differences, with which the line
    search reaches the optimum of the stabilised problem."""
    fb = ["alpha", "q"] if {"alpha", "q"} <= set(model.states) else None
    return StabilizedOutputError(model, inputs=problem.inputs, feedback=fb, jacobian="central").fit(
        problem.fit, estimate_x0=problem.estimate_x0
    )


def _eigenvalue_transformation(problem: Problem, model: Any, s: FitSettings) -> Any:
    """Exact for linear models only: in the nonlinear longitudinal model the transformed
    airspeed goes to 0 in denominators (qbar, q c/2V, L/mV), so that axis is refused."""
    if problem.axis == "longitudinal":
        raise ModelDefinitionError(
            "eigenvalue transformation needs a linear model; the longitudinal model is "
            "nonlinear (use soem, decouple or the filters for this axis)"
        )
    return EigenvalueTransformation(model, inputs=problem.inputs).fit(problem.fit, estimate_x0=problem.estimate_x0)


def _equation_decoupling(problem: Problem, model: Any, s: FitSettings) -> Any:
    """Decouples only the destabilising coupling where the model has it (alpha in the
    pitch equation of the longitudinal model); every measured state otherwise."""
    states = ["alpha"] if "alpha" in model.states else None
    return EquationDecoupling(model, states=states, inputs=problem.inputs, pseudo=_states_at_cg(model)).fit(
        problem.fit, estimate_x0=problem.estimate_x0
    )


def _states_at_cg(model: Any):
    """Pseudo-inputs for equation decoupling: the vane's V and alpha moved to the CG with
    the measured pitch rate (u = V_v cos a_v - q z_vane, w = V_v sin a_v + q x_vane), other
    states as measured. Without it the vane's q x_vane / V in alpha enters the decoupled
    pitch equation as Cmalpha x_vane / V q and biases Cmq. None when there is nothing to
    move."""
    c, outs = model.constants, model.outputs
    xv, zv = float(c.get("x_vane", 0.0)), float(c.get("z_vane", 0.0))
    if not ({"V", "alpha", "q"} <= set(outs)) or (xv == 0.0 and zv == 0.0):
        return None

    def pseudo(seg, states):
        V, a, q = (seg.z[:, outs.index(k)] for k in ("V", "alpha", "q"))
        V = np.interp(seg.t, seg.t[np.isfinite(V)], V[np.isfinite(V)])
        a_ok = np.isfinite(a)
        a = np.interp(seg.t, seg.t[a_ok], a[a_ok])
        q = np.interp(seg.t, seg.t[np.isfinite(q)], q[np.isfinite(q)])
        u, w = V * np.cos(a) - q * zv, V * np.sin(a) + q * xv
        cg = {"V": np.hypot(u, w), "alpha": np.arctan2(w, u)}
        return np.column_stack([cg[s] if s in cg else seg.z[:, outs.index(s)] for s in states])

    return pseudo


#: the Kalman filters' fits (the registry's fitter "pipeline.methods.fitting:_ekf", "..._ukf")
_ekf = _kalman_filter(EKF)
_ukf = _kalman_filter(UKF)


def filters_process_noise(
    fd: FlightData,
    pb: Problem,
    method: str,
    source: Any,
    cache: dict,
    progress: Any,
    *,
    turbulence: Mapping[str, Any] | None = None,
    quiet: bool = False,
    earlier: Any = None,
) -> tuple[dict[str, float] | None, Problem, Any]:
    """The process noise of a fit of a method with a ``noise_from`` (EKF/UKF) and its
    problem: (None, ``pb``, None) for other methods and when the Dryden level is known
    (fit_problem takes it from there); else from this run's fit of that method on the
    problem (``source``), or one made for it, once per axis (``cache``: axis -> that fit or
    None), with ``pb``'s free GUST_NOISE_PARAMETERS held at that fit's estimates; (None,
    ``pb``, None), the filters' default, when that fit fails. The third element, (process
    noise, held values) or None, goes to the result's ``extra["filters_noise"]``: a refit
    of that result (``earlier``) takes the same noise model instead of another fit.
    ``progress``: its ``stream`` takes the notes unless ``quiet``."""
    spec = method_spec(method)
    if spec.noise_from is None or dryden_known(turbulence):
        return None, pb, None
    noise = (getattr(earlier, "extra", None) or {}).get("filters_noise")
    if noise is None:
        if pb.axis not in cache:
            cache[pb.axis] = _noise_source_fit(fd, pb, spec.noise_from, source, progress, quiet)
        src = cache[pb.axis]
        if src is None:
            return None, pb, None
        free = {p.name for p in pb.model.parameters if p.free}
        noise = (
            filter_process_noise(src),
            {n: float(src.params[n]) for n in GUST_NOISE_PARAMETERS if n in free and n in src.params},
        )
    q, held = noise
    if held:
        pb = replace(
            pb,
            model=pb.model.hold(held),
            notes=list(pb.notes)
            + [
                ", ".join(f"{n} = {v:.4g}" for n, v in held.items())
                + " held at filter error's estimate (the gust model's noise, with its process noise)"
            ],
        )
    return q, pb, noise


def _noise_source_fit(fd: FlightData, pb: Problem, method: str, fit: Any, progress: Any, quiet: bool) -> Any:
    """The fit (of ``method``, filter error) the filters take their noise model from:
    ``fit``, else one made for ``pb`` (None when it fails)."""
    if fit is not None:
        return fit
    try:
        fit = fit_problem(attach_logged_noise(fd, replace(pb)), method)
    except (EstimationError, np.linalg.LinAlgError) as exc:
        if not quiet:
            print(
                f"note: process noise for the {pb.axis} filters: the filter-error fit "
                f"failed ({exc}); the data's default used",
                file=progress.stream,
            )
        return None
    if not quiet:
        print(
            f"note: process noise for the {pb.axis} filters from a filter-error fit (no turbulence level known)",
            file=progress.stream,
        )
    return fit
