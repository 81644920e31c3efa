"""Filter-error method (FEM): maximum likelihood with process and measurement noise.

Model (DESIGN.md section 8): x' = f(x, u, theta) + F w, y = g(x, u, theta),
z_k = y_k + G v_k with w, v unit white noise; F is diagonal on the states listed in
``process_noise``. The algorithm is the reference software's (Jategaonkar's ml_fem; Maine
and Iliff's relaxation):

* Linearisation: A = df/dx, B = df/du, C = dg/dx, D = dg/du by central differences about
  each segment's initial state and first input (the trim point), re-evaluated for every
  parameter set; the affine parts f(x_r, u_r) - A x_r - B u_r and g(...) - C x_r - D u_r
  are kept, so linear models with trim offsets and output biases are represented exactly.
* Gain: P from A P + P A^T - P C^T (R h)^-1 C P + F F^T = 0 with R the innovation
  covariance and h the sample interval (Potter's method, ``continuous_gain``);
  K = P C^T R^-1. ``gain="discrete"``: P of the sampled filter (``discrete_gain``).
* Prediction (``form="nonlinear"``, the default for linear and nonlinear models alike): one
  integrator step of the model's f from x^_k (default RK4, inputs at the stage times),
  outputs g(x~_k). ``form="linear"``: x~_{k+1} = Phi x^_k + Gamma0 (B u_k + f_0)
  + Gamma1 B (u_k+1 - u_k) with the transition matrix of the linearisation (exact for
  linear models and inputs interpolated linearly, ``input_integrals``).
* Correction x^_k = x~_k + K (z_k - y~_k). A sample where only the outputs o are measured
  (NaN = missing: multi-rate data) is corrected with the gain of those outputs,
  K_o = P C_o^T R_oo^-1 (``pattern_gains``).

Estimation, by relaxation (the reference software's criterion, ml_fem2; Maine and Iliff):

1. R, the diagonal covariance of the innovations, in closed form: R = diag(1/N sum nu nu^T)
   (at the start from the start model run without a gain, or the given std); the cost is
   det R.
2. For that R, Gauss-Newton on phi = [theta, F]: M = sum S^T R^-1 S, g = sum S^T R^-1 nu,
   with S = d y~/d phi from forward differences (they include the gain's gradients
   dK/dphi), all perturbed parameter sets filtered in one batch; the step respects
   diag(K C) <= 1 on the states, linearised on the step (a violated row becomes an
   equality), step halving on the weighted cost, then Levenberg-Marquardt damping.
3. From the ``r_update_from``-th iteration on, R is re-estimated after each step and F
   compensated for the change (Maine and Iliff, ``relax``).

The Cramér-Rao bounds are the inverse of the final information matrix for the final R.
``full_R=True`` is the likelihood's criterion instead: the full R, diag(C K) <= 1 on the
outputs (the implied measurement noise non-negative), the information with R estimated
too; it is refused (:class:`~estimators.errors.DependentOutputsError`) when a measured
output is an exact function of the others and the inputs, where its determinant can be
driven to zero.

The fit has converged when det(R)'s relative change and R's have settled. R is never a
free parameter of the Gauss-Newton step, so it cannot collapse to zero.

Where the pieces are: :mod:`estimators.filters.steady_state` (discretisation, Riccati
equations, gains), :mod:`estimators.filters.fem_problem` (the data, phi and the batched
filter run), :mod:`estimators.filters.fem_information` (information, covariances),
:mod:`estimators.filters.fem_relaxation` (R and F), this module (the iterations and the
result).

Result: an :class:`~estimators.EstimationResult`; ``predicted`` are the one-step
predictions y~_k, ``residuals`` the innovations, ``R`` their sample covariance;
``extra`` holds ``gain`` (K per segment), ``F`` (n, n), ``innovation_cov`` (the R the gain
used, per segment), ``measurement_noise`` (R - C P C^T, diagonal), ``P``, ``A/B/C/D``
(linearisation per segment) and ``filtered_states``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from estimators import statistics as st
from estimators.errors import EstimationError, IdentifiabilityError, ModelDefinitionError
from estimators.filters.fem_information import FemCovariance, covariances, scoring
from estimators.filters.fem_problem import FemProblem, SegmentFilter, check_full_R, sample_interval
from estimators.filters.fem_relaxation import R_SETTLED, feasible_start, relax
from estimators.filters.noise import named_vector, process_noise_start
from estimators.filters.steady_state import output_patterns
from estimators.integrators import DEFAULT_INPUTS, check_options
from estimators.layout import Layout
from estimators.model import Model, Segment, check_outputs_measured
from estimators.results import EstimationResult, frames

#: Levenberg-Marquardt damping tried, in turn, when step halving finds no lower cost
LM_DAMPING = (1e-2, 1e-1, 1.0, 10.0, 1e2, 1e3, 1e4)


def constrained_step(
    M: np.ndarray, g: np.ndarray, active: np.ndarray, res: list[SegmentFilter], dCK: list, lam: float = 0.0
) -> np.ndarray:
    """Gauss-Newton (or, with ``lam``, Levenberg-Marquardt) step on the active
    parameters under the linearised constraints CK + dCK delta <= 1 (diag(K C) on the states,
    with a full R diag(C K) on the outputs; active-set: the violated ones are made
    equalities, as the reference software's KC <= 1 check)."""
    nphi = g.size
    a = np.flatnonzero(active)
    delta = np.zeros(nphi)
    if a.size == 0:
        return delta
    Ma, ga = M[np.ix_(a, a)], g[a]
    delta[a] = st.solve_step(Ma, ga, lam)
    ck = np.concatenate([r.CK[0] for r in res])
    Gk = np.concatenate(dCK, axis=0)[:, a]
    rows: list[int] = []
    for _ in range(ck.size):
        viol = np.flatnonzero((ck + Gk @ delta[a] > 1.0 + 1e-12) & np.any(Gk != 0, axis=1))
        viol = [v for v in viol if v not in rows]
        if not viol:
            break
        rows.append(int(viol[np.argmax((ck + Gk @ delta[a])[viol])]))
        Aeq = Gk[rows]
        beq = 1.0 - ck[rows]
        d = np.sqrt(np.maximum(np.diag(Ma), 1e-300))
        Ms = Ma / np.outer(d, d) + lam * np.eye(a.size)
        Kkt = np.block([[Ms, (Aeq / d).T], [Aeq / d, np.zeros((len(rows), len(rows)))]])
        try:
            sol = np.linalg.lstsq(Kkt, np.concatenate([ga / d, beq]), rcond=1e-12)[0]
        except np.linalg.LinAlgError:
            break
        delta[a] = sol[: a.size] / d
    return delta


def cap_noise_step(prob: FemProblem, phi: np.ndarray, delta: np.ndarray, factor: float = 10.0) -> np.ndarray:
    """delta scaled so that no process-noise entry grows more than ``factor``-fold in
    one step: F's information can start out negligible (a small start gain), and an
    unbounded Gauss-Newton step then throws F far beyond the data."""
    sl = prob.fslice()
    f, d = phi[sl], delta[sl]
    grow = (d > 0) & (f > 0)
    if not np.any(grow):
        return delta
    scale = np.min(np.where(grow, (factor - 1.0) * f / np.where(grow, d, 1.0), np.inf))
    return delta * min(1.0, float(scale))


def step_floor(prob: FemProblem, phi: np.ndarray, factor: float = 10.0) -> np.ndarray:
    """The lower bounds of a trial point from ``phi``: the parameters' own, and each
    positive process-noise entry at most ``factor``-fold smaller (a trial onto F = 0, where
    F's gradient vanishes with the gain, leaves the fit unable to bring it back)."""
    lo = prob.lo.copy()
    sl = prob.fslice()
    f = phi[sl]
    lo[sl] = np.where(f > 0, np.maximum(lo[sl], f / factor), lo[sl])
    return lo


@dataclass
class _State:
    """The fit's current point: phi, its filter run ``res``, det R^ ``cost`` and the
    innovations' covariance ``Rh`` there, and the R the Gauss-Newton steps weight with."""

    phi: np.ndarray
    res: list[SegmentFilter]
    cost: float
    Rh: np.ndarray
    R: np.ndarray


@dataclass
class _Trial:
    """A Gauss-Newton iteration's step: the full step ``delta``, the weighted cost J0 at
    its start, whether a trial point lowered it (``accepted``), the step factor ``alpha``
    (negative: the Levenberg-Marquardt damping that worked), the trial phi and its run."""

    delta: np.ndarray
    J0: float
    accepted: bool = False
    alpha: float = 1.0
    phi: np.ndarray | None = None
    res: list[SegmentFilter] | None = None


@dataclass
class _Iterations:
    """How the iterations ended: their number, whether they converged, why not (message)
    and the history rows."""

    it: int = 0
    converged: bool = False
    message: str = ""
    history: list = field(default_factory=list)


class FilterError:
    """Filter-error method (see module docstring for the equations).

    Parameters
    ----------
    model : the :class:`~estimators.Model`.
    process_noise : states with process noise and their start F (std of the continuous
        white noise, state unit per sqrt(s)): {state: start}, a (n,) vector (0 = no noise
        on that state) or a list of measured states (started at the default below).
        Default: every state that is a measured output, started at
        0.05 sqrt(var(diff z)/h) (a twentieth of the bound the sample-to-sample variation
        gives). Starting from output-error estimates (``start=oem.params``) helps.
    estimate_F : estimate the F entries (True) or hold them at their start values.
    measurement_noise : start of the innovation covariance R as std per output
        ({output: std} or (n_out,)), the reference software's given output-error std;
        default: the residuals of the start model run without a gain (K = 0).
    form : "nonlinear" (default: integrator prediction of the model's f, linear or not,
        gain of the linearisation at the trim point; the reference software's) or "linear"
        (transition matrix of the linearisation at each segment's start: exact for linear
        models only).
    integrator : the one-step predictor of the nonlinear form.
    max_iter, tol : Gauss-Newton iterations; stop when the relative change of det(R) is
        below ``tol`` after an iteration that updated R.
    fd_step : relative forward-difference step of the sensitivities.
    step_halvings : maximum halvings of a step that does not lower det(R).
    r_update_from : first iteration after which R is re-estimated and F compensated (the
        reference software waits until its third; from the first, a start R far from the
        innovations - the output-error residuals of a start in turbulence - weights the
        early steps less wrongly).
    full_R : the likelihood's criterion instead of the reference's (default False): the
        full innovation covariance and the determinant of it, the implied measurement noise
        R - C P C^T kept non-negative (diag(C K) <= 1 on the outputs) and R's own
        uncertainty in the std. Refused when a measured output is an exact function of the
        others and the inputs (:class:`~estimators.errors.DependentOutputsError`).
    gain : "continuous" (default: the reference software's steady-state gain, P from the
        continuous Riccati equation with R h for the measurement noise, exact as h -> 0) or
        "discrete" (the sampled filter's own P, :func:`~estimators.filters.steady_state.discrete_gain`:
        the right gain where a state is fast against the sample interval, as a gust
        filter's is).
    inputs : input variation over a sample interval, as OutputError: "linear" (default) or
        "hold" (zero-order hold); the linear form discretises either exactly.
    compiled : run the nonlinear filter loop compiled with numba (f and g compiled; falls
        back to the numpy loop when the model does not compile).
    """

    method = "fem"

    def __init__(
        self,
        model: Model,
        *,
        process_noise: Any = None,
        estimate_F: bool = True,
        measurement_noise: Any = None,
        form: str = "nonlinear",
        integrator: str = "rk4",
        max_iter: int = 40,
        tol: float = 1e-4,
        fd_step: float = 1e-6,
        step_halvings: int = 10,
        r_update_from: int = 1,
        inputs: str = DEFAULT_INPUTS,
        compiled: bool = True,
        full_R: bool = False,
        gain: str = "continuous",
        callback=None,
    ) -> None:
        if form not in ("linear", "nonlinear"):
            raise ModelDefinitionError(f"form must be 'nonlinear' or 'linear', not {form!r}")
        if gain not in ("continuous", "discrete"):
            raise ModelDefinitionError(f"gain must be 'continuous' or 'discrete', not {gain!r}")
        self.gain = gain
        check_options(integrator, inputs)
        self.model = model
        self.process_noise = process_noise
        self.estimate_F = estimate_F
        self.measurement_noise = measurement_noise
        self.integrator = integrator
        self.max_iter = max_iter
        self.tol = tol
        self.fd_step = fd_step
        self.step_halvings = step_halvings
        self.r_update_from = max(int(r_update_from), 1)
        self.callback = callback
        self.inputs = inputs
        self.compiled = compiled
        self.full_R = full_R
        self._set_form(form)

    def _set_form(self, form: str) -> None:
        self.form = form
        self.method = "fem-nl" if form == "nonlinear" else "fem"

    def _noise_setup(self, segments: Sequence[Segment]) -> tuple[list[int], np.ndarray]:
        """The states with process noise and F's start (n,) for these segments
        (:func:`~estimators.filters.noise.process_noise_start` of ``process_noise``)."""
        return process_noise_start(self.model, self.process_noise, segments)

    # -- the fit --------------------------------------------------------------------------------
    def fit(
        self,
        segments: Segment | Sequence[Segment],
        estimate_x0: bool | Sequence[str] = False,
        start: Mapping[str, float] | None = None,
    ) -> EstimationResult:
        """Estimate the free parameters and F, with R in closed form, from one or several
        segments (see the class). ``start``: start values by expanded name, overriding the
        model's; an ``F_<state>`` entry (an earlier fit's, for a refit) starts that state's
        process noise, or holds it with ``estimate_F=False``."""
        segments = [segments] if isinstance(segments, Segment) else list(segments)
        if not segments:
            raise ModelDefinitionError("fit() needs at least one segment")
        try:
            return self._fit(segments, estimate_x0, start)
        except (np.linalg.LinAlgError, ValueError, ArithmeticError) as exc:
            if isinstance(exc, EstimationError):
                raise
            # a matrix the numerics need is singular or not positive definite: an output
            # predicted exactly, or the data do not determine some parameter
            raise IdentifiabilityError(
                f"filter error: the information or the innovation covariance became singular ({exc}); "
                "check that every output is measured with noise and that the free parameters are "
                "identifiable from these data (fix some, or fit output error first and start from it)"
            ) from exc

    def _fit(
        self, segments: list[Segment], estimate_x0: bool | Sequence[str], start: Mapping[str, float] | None
    ) -> EstimationResult:
        """:meth:`fit` on a list of segments."""
        prob, phi = self._problem(segments, estimate_x0, start)
        R = self._start_R(prob, phi)
        seg_rows = prob.segment_rows(phi.size)
        res = prob.filter(phi[None, :], R)
        phi, res = feasible_start(prob, phi, res, R)
        cost, Rh = prob.cost(res)
        if not np.isfinite(cost):
            prob.raise_diverged(res)
        state = _State(phi, res, cost, Rh, R)
        done = self._iterate(prob, state, seg_rows)
        # information at the final estimate, with R the innovations' covariance there
        cv = covariances(prob, state.phi, state.Rh, seg_rows)
        return self._result(prob, state.phi, state.Rh, cv, done)

    def _problem(
        self, segments: list[Segment], estimate_x0: bool | Sequence[str], start: Mapping[str, float] | None
    ) -> tuple[FemProblem, np.ndarray]:
        """The fit's problem and the start of phi = [free model parameters, F of the noisy
        states (when estimated)]; the form is decided here when it is "auto"."""
        model = self.model
        lay = Layout.build(model, segments, estimate_x0, values=start)
        h = [sample_interval(seg, k) for k, seg in enumerate(segments)]
        patterns = [output_patterns(seg.z) for seg in segments]
        check_outputs_measured(self.model, segments, "filter error")
        if self.full_R:
            check_full_R(model, segments)
        noisy, f0 = self._noise_setup(segments)
        start = dict(start) if start is not None else {}
        for i in noisy:  # an earlier fit's F (``start`` of a refit) over the default
            v = start.get(f"F_{model.states[i]}")
            if v is not None and float(v) > 0.0:
                f0[i] = float(v)
        fi = lay.free_idx
        names = list(lay.free_names)
        lo = list(lay.lower[fi])
        hi = list(lay.upper[fi])
        phi = list(lay.values[fi])
        if self.estimate_F:
            for i in noisy:
                names.append(f"F_{model.states[i]}")
                phi.append(f0[i])
                lo.append(0.0)
                hi.append(np.inf)
        phi = np.array(phi, dtype=float)
        prob = FemProblem(
            model=model,
            segments=segments,
            lay=lay,
            form=self.form,
            integrator=self.integrator,
            inputs=self.inputs,
            compiled=self.compiled,
            full_R=self.full_R,
            gain=self.gain,
            estimate_F=self.estimate_F,
            fd_step=self.fd_step,
            h=h,
            patterns=patterns,
            noisy=noisy,
            f_fixed=f0.copy(),
            names=names,
            lo=np.array(lo, float),
            hi=np.array(hi, float),
            # finite-difference floor: 1 for model parameters (as OEM), the start for F
            floor=np.concatenate([np.ones(fi.size), np.maximum(np.abs(phi[fi.size :]), 1e-12)]),
        )
        return prob, phi

    def _start_R(self, prob: FemProblem, phi: np.ndarray) -> np.ndarray:
        """The start of R: the given output-error std, else the residuals of the start
        model run without a gain, each output's variance at most that of its data (a model
        that misses by more, an unstable aircraft's simulation running away, is no guide
        to R)."""
        model = self.model
        m = len(model.outputs)
        if self.measurement_noise is not None:
            R = np.diag(named_vector(self.measurement_noise, model.outputs, "measurement_noise", np.ones(m)) ** 2)
        else:
            r0 = prob.filter(phi[None, :], np.eye(m), gain=False)
            R = prob.cost(r0)[1]
            Zall = np.concatenate([seg.z for seg in prob.segments])
            var_z = np.nanvar(Zall, axis=0)
            var_z = np.where(var_z > 0, var_z, 1.0)
            d = np.diag(R)
            if not np.all(np.isfinite(R)) or np.any(d > var_z):
                R = np.diag(np.where(np.isfinite(d) & (d > 0), np.minimum(d, var_z), var_z))
        if np.any(np.diag(R) <= 0) or not np.all(np.isfinite(R)):
            raise ModelDefinitionError("measurement_noise: every output needs a positive, finite std")
        return R

    def _iterate(self, prob: FemProblem, s: _State, seg_rows: list[np.ndarray]) -> _Iterations:
        """Gauss-Newton iterations on phi for the current R, each followed (from the
        ``r_update_from``-th on) by the relaxation of R and F; ``s`` is moved along."""
        done = _Iterations()
        names = prob.names
        for it in range(1, self.max_iter + 1):
            done.it = it
            batch, hsteps = prob.sensitivity_batch(s.phi, s.R, seg_rows)
            M, g, dCK, _ = scoring(prob, batch, s.R, hsteps, seg_rows)
            if it == 1:
                _check_start_information(prob, M, s.phi)
            done.history.append(
                {
                    "iteration": it - 1,
                    "J": 0.5 * prob.n_samples * np.log(s.cost),
                    "det_R": s.cost,
                    "step": np.nan,
                    **dict(zip(names, s.phi)),
                }
            )
            if self.callback:
                self.callback(it - 1, s.cost, pd.Series(s.phi, index=names))
            trial = self._line_search(prob, s, M, g, dCK, batch)
            if trial.accepted:
                ct, Rt = prob.cost(trial.res)
            done.history[-1]["step"] = trial.alpha
            prev = s.cost
            if trial.accepted:
                s.phi, s.res, s.cost, s.Rh = trial.phi, trial.res, ct, Rt
            r_change = 0.0
            if it >= self.r_update_from:
                s.phi, s.res, s.cost, s.Rh, s.R, r_change = relax(prob, s.phi, s.res, s.cost, s.Rh, s.R)
            settled = abs(prev - s.cost) <= self.tol * abs(s.cost) and r_change <= R_SETTLED
            if settled and it >= self.r_update_from:
                done.converged = True
                break
            if not trial.accepted and r_change <= R_SETTLED:
                if 0.5 * float(g @ trial.delta) <= 1e-6 * max(1.0, trial.J0):
                    done.converged = True  # the predicted decrease is negligible
                else:
                    done.message = "no step lowered det(R) (line search failed)"
                break
        else:
            done.message = f"stopped at max_iter={self.max_iter} before det(R) settled"
        return done

    def _line_search(
        self, prob: FemProblem, s: _State, M: np.ndarray, g: np.ndarray, dCK: list, batch: list[SegmentFilter]
    ) -> _Trial:
        """The Gauss-Newton step from ``s`` on the parameters not held by a bound, halved
        until the weighted cost J falls within the gain's constraint, else damped
        (Levenberg-Marquardt, :data:`LM_DAMPING`)."""
        phi, R = s.phi, s.R
        span = np.maximum(1.0, np.abs(phi))
        at_lo = phi <= prob.lo + 1e-12 * span
        at_hi = phi >= prob.hi - 1e-12 * span
        active = ~((at_lo & (g < 0)) | (at_hi & (g > 0)))
        trial = _Trial(cap_noise_step(prob, phi, constrained_step(M, g, active, batch, dCK)), prob.weighted(s.res, R))
        lo = step_floor(prob, phi)
        alpha = 1.0
        for _ in range(self.step_halvings + 1):
            trial.phi = np.clip(phi + alpha * trial.delta, lo, prob.hi)
            trial.res = prob.filter(trial.phi[None, :], R)
            if prob.weighted(trial.res, R) < trial.J0 and prob.constraint_ok(trial.res):
                trial.accepted, trial.alpha = True, alpha
                return trial
            alpha *= 0.5
        for lam in LM_DAMPING:
            step = cap_noise_step(prob, phi, constrained_step(M, g, active, batch, dCK, lam))
            trial.phi = np.clip(phi + step, lo, prob.hi)
            trial.res = prob.filter(trial.phi[None, :], R)
            if prob.weighted(trial.res, R) < trial.J0 and prob.constraint_ok(trial.res):
                trial.accepted, trial.alpha = True, -lam  # recorded as a negative step: LM
                return trial
        trial.alpha = alpha
        return trial

    def _result(
        self, prob: FemProblem, phi: np.ndarray, R: np.ndarray, cv: FemCovariance, done: _Iterations
    ) -> EstimationResult:
        """The fit's result at the estimate phi, with R the innovations' covariance there."""
        model, lay, names, batch = self.model, prob.lay, prob.names, cv.batch
        segments = prob.segments
        nf = lay.free_idx.size
        theta, F = prob.unpack(phi)
        E = prob.innovations(batch)
        Ys = [r.Y[0] for r in batch]
        message = done.message or ("" if done.converged else "did not converge")
        noise = [np.diag(np.maximum(np.diag(R) - np.diag(r.C[0] @ r.P[0] @ r.C[0].T), 0.0)) for r in batch]
        return EstimationResult(
            method=self.method,
            model=model,
            names=list(lay.names) + names[nf:],
            values=np.concatenate([theta, phi[nf:]]),
            free=np.concatenate([lay.free, np.ones(phi.size - nf, dtype=bool)]),
            cov=cv.cov,
            R=st.residual_covariance(E, full=True),
            converged=done.converged,
            iterations=done.it,
            history=pd.DataFrame(done.history),
            segments=segments,
            predicted=frames([s.t for s in segments], Ys, model.outputs),
            residuals=frames([s.t for s in segments], E, model.outputs),
            at_bounds=[names[i] for i in np.flatnonzero(cv.on_bound)],
            message=message,
            information=cv.M,
            settings={
                "form": self.form,
                "integrator": self.integrator if self.form == "nonlinear" else "transition matrix",
                "optimizer": "gauss-newton, R by relaxation, F-R compensation",
                "estimate_F": self.estimate_F,
                "inputs": self.inputs,
                "linearisation": "about x0 and u[0] of each segment",
                "gain": self.gain,
                "innovation_covariance": "full" if self.full_R else "diagonal",
            },
            extra={
                "gain": [r.K[0] for r in batch],
                "F": F,
                "measurement_noise": noise[0],
                "innovation_cov": [R for _ in batch],
                "P": [r.P[0] for r in batch],
                "linearisation": [dict(zip("ABCD", r.lin)) for r in batch],
                "filtered_states": [
                    pd.DataFrame(r.X[0], index=pd.Index(s.t, name="t"), columns=model.states)
                    for s, r in zip(segments, batch)
                ],
                "det_R": float(np.linalg.det(R)),
                "residuals_are": "innovations",
                "mk_cov": cv.mk_cov,
                "mk_names": names,
                "mk_max_lag": cv.mk_lags,
                "cluster": cv.cluster,
            },
        )


def _check_start_information(prob: FemProblem, M: np.ndarray, phi: np.ndarray) -> None:
    """At the start only parameters without any effect are an error (the process noise is
    exempt: with a start R far above the innovations its gain, and so its effect, can start
    out negligible)."""
    d = np.diag(M) * np.maximum(np.abs(phi), prob.floor) ** 2  # scale-free
    dead = d <= 1e-14 * max(float(d.max()), 1e-300)
    dead[prob.lay.free_idx.size :] = False
    if np.any(dead):
        st.check_identifiable(np.diag(np.where(dead, 0.0, 1.0)), prob.names, " at the start values")
