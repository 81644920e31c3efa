"""Output-error maximum-likelihood estimation (measurement noise only).

For fixed parameters the noise covariance is R = (1/N) sum e e^T; for fixed R the cost
J = 1/2 sum e^T R^-1 e is minimised by Gauss-Newton with F = sum S^T R^-1 S and
G = sum S^T R^-1 e, S = dy/dtheta from finite differences over a batch of perturbed
parameter sets integrated together (:mod:`estimators.output_error.likelihood`). The two
alternate (relaxation) until det(R) stops falling. Cramér-Rao bounds come from F^-1 at
the optimum.

Safeguards (:mod:`estimators.optim`): step halving, Levenberg-Marquardt, bounded-variable
Gauss-Newton (a parameter on a bound whose gradient points outward leaves the active
set), an a-priori penalty (theta - theta*)^T W (theta - theta*), and a Nelder-Mead start
for poor starts.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd

from estimators import statistics as st
from estimators.defaults import AT_BOUND_RTOL, ATOL, FD_STEP, MAX_ITER, RTOL, STEP_HALVINGS, TOL
from estimators.errors import ModelDefinitionError
from estimators.integrators import DEFAULT_INPUTS, check_options
from estimators.layout import Layout
from estimators.model import Model, Segment, check_outputs_measured
from estimators.optim import FALLBACKS, OPTIMIZERS, GaussNewtonSettings, Outcome, minimise
from estimators.output_error.diagnostics import follow_note, slowest_mode
from estimators.output_error.likelihood import (
    LikelihoodSettings,
    OutputErrorLikelihood,
    OutputErrorLinearisation,
    SensitivityHook,
)
from estimators.results import EstimationResult, frames


class OutputError:
    """Output-error method.

    Parameters
    ----------
    model : the :class:`~estimators.Model` to fit.
    integrator : "euler", "rk2", "rk3", "rk4" (default) or "rkf45" (adaptive; rtol/atol).
    noise : "diagonal" (default) or "full" R.
    optimizer : "gauss-newton" (with step halving) or "levenberg-marquardt".
    jacobian : "forward" or "central" finite differences, or a callable
        ``hook(model, segment, k, layout, theta) -> (Y, S)`` returning analytic sensitivities
        for the free parameters ``layout.relevant[k]``.
    fd_step : relative perturbation; parameter j moves by fd_step * max(|theta_j|, 1).
    max_iter : maximum Gauss-Newton iterations.
    tol : convergence when the relative change of det(R) between iterations is below tol.
    step_halvings : maximum halvings of a step that does not lower the cost.
    priors : {name: (value, std)} a-priori values; adds (theta-theta*)^2 / (2 std^2) to J.
    fallback : "auto" runs Nelder-Mead when Gauss-Newton cannot lower the cost from the
        start (no step accepted yet; a line search that fails after accepted steps is near
        the optimum, where the simplex over every free parameter only costs time),
        "always" runs it first, "never" does not.
    rtol, atol : tolerances of the adaptive integrator.
    inputs : input variation inside a sample interval: "linear" (default: each integration
        stage reads them interpolated at its own time) or "hold" (see
        :data:`estimators.integrators.INPUT_MODES`).
    callback : called as callback(iteration, cost, params Series) after each iteration.

    A fit whose model does not follow the data (residuals of most outputs coloured and
    large, or trial steps whose simulation ran away: an unstable aircraft or strong
    turbulence, see :func:`estimators.output_error.diagnostics.follow_note`) keeps
    ``converged`` as the optimiser left it; its ``message`` says so and names the methods
    for unstable aircraft, and ``extra["not_followed"]`` holds the numbers.
    """

    method = "oem"
    #: add :func:`follow_note` to the message; off for the transformed problems of
    #: estimators.output_error.stabilized, which are the remedy it names
    _check_follow = True

    def __init__(
        self,
        model: Model,
        integrator: str = "rk4",
        *,
        noise: str = "diagonal",
        optimizer: str = "gauss-newton",
        jacobian: str | SensitivityHook = "forward",
        fd_step: float = FD_STEP,
        max_iter: int = MAX_ITER,
        tol: float = TOL,
        step_halvings: int = STEP_HALVINGS,
        priors: Mapping[str, tuple[float, float]] | None = None,
        fallback: str = "auto",
        rtol: float = RTOL,
        atol: float = ATOL,
        inputs: str = DEFAULT_INPUTS,
        callback: Callable[[int, float, pd.Series], None] | None = None,
    ) -> None:
        check_options(integrator, inputs)
        if noise not in ("diagonal", "full"):
            raise ModelDefinitionError(f"noise must be 'diagonal' or 'full', not {noise!r}")
        aliases = {"gn": "gauss-newton", "lm": "levenberg-marquardt"}
        optimizer = aliases.get(optimizer, optimizer)
        if optimizer not in OPTIMIZERS:
            raise ModelDefinitionError(f"unknown optimizer {optimizer!r}: use one of {OPTIMIZERS}")
        if not callable(jacobian) and jacobian not in ("forward", "central"):
            raise ModelDefinitionError("jacobian must be 'forward', 'central' or a callable")
        if fallback not in FALLBACKS:
            raise ModelDefinitionError("fallback must be 'auto', 'always' or 'never'")
        self.model = model
        self.integrator = integrator
        self.noise = noise
        self.optimizer = optimizer
        self.jacobian = jacobian
        self.fd_step = fd_step
        self.max_iter = max_iter
        self.tol = tol
        self.step_halvings = step_halvings
        self.priors = dict(priors or {})
        self.fallback = fallback
        self.rtol, self.atol = rtol, atol
        self.inputs = inputs
        self.callback = callback

    def _likelihood(
        self,
        segments: list[Segment],
        estimate_x0: bool | str | Sequence[str],
        values: Mapping[str, float] | None,
        R: np.ndarray | None = None,
    ) -> OutputErrorLikelihood:
        """The likelihood of this model over ``segments`` with the parameter layout for
        ``estimate_x0`` and start ``values``; ``R`` a fixed noise covariance or None."""
        lay = Layout.build(self.model, segments, estimate_x0, values=values)
        settings = LikelihoodSettings(
            self.integrator, self.noise, self.jacobian, self.fd_step, self.priors, self.rtol, self.atol, self.inputs
        )
        R_fixed = None if R is None else np.atleast_2d(np.asarray(R, dtype=float))
        return OutputErrorLikelihood(self.model, segments, lay, settings, R_fixed)

    # -- the fit --------------------------------------------------------------------------
    def fit(
        self,
        segments: Segment | Sequence[Segment],
        estimate_x0: bool | str | Sequence[str] = "auto",
        R: np.ndarray | None = None,
        start: Mapping[str, float] | None = None,
    ) -> EstimationResult:
        """Estimate the free parameters from one or several segments.

        segments : data; system parameters are shared, per-segment ones get ``[k]``.
        estimate_x0 : False, True (all states), a list of state names whose initial value
            is estimated per segment (``x0_<state>[k]``), or "auto" (default): the
            measured states of each segment built without an ``x0`` are estimated (their
            start is the first measured sample, which carries the sensor noise), a given
            ``x0`` is held. Held at a noisy first sample, the initial state biases the
            derivatives, more so the more segments a flight is cut into.
        R : a fixed measurement-noise covariance (n_out, n_out); estimated when None.
        start : start values by expanded name, overriding the model's.
        """
        segments = [segments] if isinstance(segments, Segment) else list(segments)
        if not segments:
            raise ModelDefinitionError("fit() needs at least one segment")
        lik = self._likelihood(segments, estimate_x0, start, R)
        check_outputs_measured(self.model, lik.segments, "output error")
        lay = lik.layout
        if lay.free_idx.size == 0:
            raise ModelDefinitionError("no free parameters: mark some Parameter(..., free=True)")
        theta = lay.values.copy()
        if lik.simulate(theta) is None:
            lik.raise_simulation_failure(theta, "with the start values")
        settings = GaussNewtonSettings(self.optimizer, self.max_iter, self.tol, self.step_halvings, self.fallback)
        fi = lay.free_idx
        hook = self._report_iteration(lay)
        outcome = minimise(lik, theta, fi, lay.lower[fi], lay.upper[fi], lay.free_names, settings, hook)
        return self._result(lik, outcome)

    def _report_iteration(self, lay: Layout) -> Callable[[int, OutputErrorLinearisation, np.ndarray], None] | None:
        """The optimiser's per-iteration hook that calls the user's ``callback`` with
        (iteration, det(R), free parameters as a Series), or None without one."""
        if not self.callback:
            return None

        def report(it: int, lin: OutputErrorLinearisation, theta: np.ndarray) -> None:
            self.callback(it, lin.report["det_R"], pd.Series(theta[lay.free_idx], index=lay.free_names))

        return report

    def _covariance(
        self, lik: OutputErrorLikelihood, theta: np.ndarray, F: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(Cramér-Rao covariance (n_free, n_free), on-bound mask (n_free,)): F^-1 over the
        free parameters inside their bounds, NaN on the rows and columns of those at a
        bound (within AT_BOUND_RTOL relative), where the likelihood is not stationary.
        Raises IdentifiabilityError when F is singular at the estimates."""
        lay = lik.layout
        fi = lay.free_idx
        lo, hi = lay.lower[fi], lay.upper[fi]
        tf = theta[fi]
        span = np.maximum(1.0, np.abs(tf))
        on_bound = (tf <= lo + AT_BOUND_RTOL * span) | (tf >= hi - AT_BOUND_RTOL * span)
        inner = np.flatnonzero(~on_bound)
        cov = np.full((fi.size, fi.size), np.nan)
        if inner.size:
            st.check_identifiable(F[np.ix_(inner, inner)], [lay.free_names[i] for i in inner], " at the estimates")
            cov[np.ix_(inner, inner)] = st.covariance(F[np.ix_(inner, inner)])
        return cov, on_bound

    def _notes(
        self, lik: OutputErrorLikelihood, outcome: Outcome, lin: OutputErrorLinearisation
    ) -> tuple[str, dict[str, Any]]:
        """The result's message (why the optimiser stopped, the Nelder-Mead start, the
        note of a model that does not follow the data) and its ``extra`` entries."""
        message = outcome.message
        if not outcome.converged and not message:
            message = "did not converge"
        if outcome.used_simplex:
            message = (
                message + "; " if message else ""
            ) + f"started with Nelder-Mead ({lik.n_simplex_evals} evaluations)"
        extra: dict[str, Any] = {}
        if self.priors:
            # the a-priori part of F (free-parameter order): the Morelli-Klein sandwich adds
            # it to its middle term (estimators.validation.morelli_klein, prior_info)
            extra["prior_information"] = lik.prior_terms(outcome.theta[lik.layout.free_idx])[0]
        if self._check_follow:
            sigma = slowest_mode(self.model, lik.segments, outcome.theta[lik.layout.pidx[0]])
            note, info = follow_note(self.model.outputs, lik.segments, lin.E, lik.runaways, sigma)
            if note:
                message = (message + "; " if message else "") + note
                extra["not_followed"] = info
        return message, extra

    def _result(self, lik: OutputErrorLikelihood, outcome: Outcome) -> EstimationResult:
        """The fit's result at the optimiser's final theta, linearised once more there for
        the information matrix, R and the predictions."""
        theta, lay, segments = outcome.theta, lik.layout, lik.segments
        lin = lik.linearise(theta)
        cov, on_bound = self._covariance(lik, theta, lin.F)
        message, extra = self._notes(lik, outcome, lin)
        if extra.get("not_followed", {}).get("std_withdrawn"):  # a bound of a model at its stability boundary
            extra["not_followed"]["crb_std"] = dict(zip(lay.free_names, np.sqrt(np.abs(np.diag(cov))).tolist()))
            cov = np.full_like(cov, np.nan)
        return EstimationResult(
            method=self.method,
            model=self.model,
            names=list(lay.names),
            values=theta,
            free=lay.free.copy(),
            cov=cov,
            R=lin.R,
            converged=outcome.converged,
            iterations=outcome.iterations,
            history=pd.DataFrame(outcome.history),
            segments=segments,
            predicted=frames([s.t for s in segments], lin.Ys, self.model.outputs),
            residuals=frames([s.t for s in segments], lin.E, self.model.outputs),
            at_bounds=[lay.free_names[i] for i in np.flatnonzero(on_bound)],
            message=message,
            information=lin.F,
            sensitivities=lin.Ss,
            extra=extra,
            settings={
                "integrator": self.integrator,
                "optimizer": self.optimizer,
                "noise": self.noise,
                "inputs": self.inputs,
                "jacobian": self.jacobian if isinstance(self.jacobian, str) else "analytic",
                "tol": self.tol,
                "max_iter": self.max_iter,
            },
        )

    def step_from(
        self,
        result: EstimationResult,
        segments: Segment | Sequence[Segment],
        estimate_x0: bool | str | Sequence[str] = "auto",
    ) -> EstimationResult:
        """``result``'s estimates moved to this model and these data by one Gauss-Newton
        step that reuses the result's sensitivities, information and R:

            theta = theta_hat + M^-1 sum S^T R^-1 (e - e_hat)

        with e the residuals of this model on ``segments`` at theta_hat (its held values
        this model's) and e_hat the result's own. For the first-order change of the
        estimates when a held value or the data move a little (the Jacobian of a consider
        parameter), for one simulation instead of a refit's several sensitivity batches;
        exact when the outputs are linear in the parameters. Parameters at a bound stay
        there. ``segments`` must be the result's (same spans) and give the same free
        parameters.

        Returns a copy of ``result`` with the moved values and the new residuals; its
        covariance, information and sensitivities are the result's. Raises
        ModelDefinitionError when the free parameters or segments differ, and
        SimulationDivergedError when the model diverges over a segment.
        """
        segments = [segments] if isinstance(segments, Segment) else list(segments)
        if result.sensitivities is None or result.information is None:
            raise ModelDefinitionError("step_from needs a result with sensitivities and information")
        if [s.n for s in segments] != [len(r) for r in result.residuals]:
            raise ModelDefinitionError("step_from needs the result's segments (same samples)")
        free = set(result.free_names)
        lik = self._likelihood(segments, estimate_x0, {n: v for n, v in result.params.items() if n in free})
        lay = lik.layout
        if list(lay.free_names) != list(result.free_names):
            raise ModelDefinitionError(
                "step_from: this model and these segments give other free parameters than the result"
            )
        theta = lay.values.copy()
        Ys = lik.simulate(theta)
        if Ys is None:
            lik.raise_simulation_failure(theta, "at the result's estimates")
        E = lik.residuals(Ys)
        dE = [e - r.to_numpy(dtype=float) for e, r in zip(E, result.residuals)]
        _, G, _ = st.information_and_gradient(result.sensitivities, dE, st.whitener(result.R))
        inner = np.array([i for i, n in enumerate(result.free_names) if n not in result.at_bounds], dtype=int)
        fi = lay.free_idx
        if inner.size:
            theta[fi[inner]] += st.solve_step(result.information[np.ix_(inner, inner)], G[inner])
        Ys = lik.simulate(theta)
        if Ys is None:
            lik.raise_simulation_failure(theta, "one step from the result's estimates")
        return replace(
            result,
            model=self.model,
            values=theta,
            segments=segments,
            predicted=frames([s.t for s in segments], Ys, self.model.outputs),
            residuals=frames([s.t for s in segments], lik.residuals(Ys), self.model.outputs),
            message="one Gauss-Newton step from the earlier estimates (step_from)",
            extra=dict(result.extra),
            consider_cov=None,
            consider_source="",
        )
