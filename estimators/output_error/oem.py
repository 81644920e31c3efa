"""Output-error maximum-likelihood estimation (measurement noise only).

For fixed parameters the noise covariance is R = (1/N) sum e e^T; for fixed R the cost
J = 1/2 sum e^T R^-1 e is minimised by Gauss-Newton with F = sum S^T R^-1 S and
G = sum S^T R^-1 e, S = dy/dtheta from finite differences over a batch of perturbed
parameter sets integrated together. The two alternate (relaxation) until det(R) stops
falling. Cramér-Rao bounds come from F^-1 at the optimum.

Safeguards: step halving, Levenberg-Marquardt, bounded-variable Gauss-Newton (a
parameter on a bound whose gradient points outward leaves the active set), an a-priori
penalty (theta - theta*)^T W (theta - theta*), and a Nelder-Mead start for poor starts.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd

from estimators import statistics as st
from estimators.errors import ModelDefinitionError, SimulationDivergedError
from estimators.model import Model, Segment, check_outputs_measured
from estimators.results import EstimationResult, frames
from estimators.sensitivity import Sensitivity
from estimators.simulation.integrators import DEFAULT_INPUTS, check_options
from estimators.simulation.simulate import Layout, divergence_error, simulate_batch

OPTIMIZERS = ("gauss-newton", "levenberg-marquardt")
DIVERGE_HINT = (
    "Check the units and signs of the start values, set bounds, start closer "
    "(e.g. from an equation-error fit, estimators.LeastSquares); for an unstable "
    "aircraft use a method that keeps the simulation bounded: StabilizedOutputError "
    "(stabilisation matrix S), EigenvalueTransformation (exp(-sigma t) weighting) "
    "or EquationDecoupling (measured states as pseudo-inputs), or the filter "
    "methods FilterError, EKF or UKF."
)

#: a simulated output further from the data's median than this many times the data's own
#: largest deviation from it counts as a diverged (runaway) simulation: an unstable model
#: integrated open loop grows exponentially long before it overflows to Inf
RUNAWAY_FACTOR = 1e3


def runaway(seg: Segment, Y: np.ndarray) -> tuple[int, int] | None:
    """(sample, output) where the simulated outputs Y (N, n_out) first run away from the
    measured ones (see RUNAWAY_FACTOR), or None."""
    with np.errstate(all="ignore"):
        med = np.nanmedian(seg.z, axis=0) if np.any(np.isfinite(seg.z)) else np.zeros(Y.shape[1])
        scale = np.nanmax(np.abs(seg.z - med), axis=0)
    ok = np.isfinite(scale) & (scale > 0)
    if not np.any(ok):
        return None
    bad = np.abs(Y[:, ok] - med[ok]) > RUNAWAY_FACTOR * scale[ok]
    if not np.any(bad):
        return None
    i = int(np.argmax(bad.any(axis=1)))
    return i, int(np.flatnonzero(ok)[np.argmax(bad[i])])


def runaway_error(model: Model, seg: Segment, k: int, where: tuple[int, int], what: str) -> SimulationDivergedError:
    i, o = where
    return SimulationDivergedError(
        f"the simulation of segment {seg.name or k} diverged at t={seg.t[i]:.4g} s (output "
        f"{model.outputs[o]!r} ran away to more than {RUNAWAY_FACTOR:g} times the measured "
        f"range; the model is unstable or far off) {what}. {DIVERGE_HINT}",
        segment=k,
        time=float(seg.t[i]),
        state=model.outputs[o],
    )


#: an output is not followed when its residuals' lag-1 autocorrelation exceeds FOLLOW_LAG1
#: and their variance FOLLOW_SHARE times the measured output's: a slow misfit that is a
#: large part of the signal, not noise. Coloured residuals alone are common in a good
#: output-error fit (light turbulence sampled fast colours them but leaves little of the
#: variance); a model that cannot follow leaves both. The note needs half the outputs or
#: more (one poorly modelled channel is not the aircraft)
FOLLOW_LAG1 = 0.8
FOLLOW_SHARE = 0.1

#: the methods that keep the simulation of an unstable aircraft bounded, named in messages
UNSTABLE_METHODS = "StabilizedOutputError, EigenvalueTransformation, EquationDecoupling or FilterError"


def lag1_autocorrelation(E: Sequence[np.ndarray]) -> np.ndarray:
    """(n_out,) lag-1 autocorrelation of residuals ``E`` (per segment (N_k, n_out)), each
    output over its measured (finite) samples, demeaned per segment and pooled over the
    segments as :func:`estimators.validation.whiteness` pools them; NaN without data."""
    n_out = np.shape(E[0])[1]
    rho = np.full(n_out, np.nan)
    for j in range(n_out):
        cols = [np.asarray(e, float)[:, j] for e in E]
        cols = [c[np.isfinite(c)] for c in cols]
        cols = [c - c.mean() for c in cols if c.size > 2]
        if cols:
            c0 = sum(float(c @ c) for c in cols)
            c1 = sum(float(c[:-1] @ c[1:]) for c in cols)
            if c0 > 0:
                rho[j] = c1 / c0
    return rho


def _pooled_variance(X: Sequence[np.ndarray]) -> np.ndarray:
    """(n,) variance of each column about its per-segment mean, finite samples only."""
    ss = sum(np.nansum((x - np.nanmean(x, axis=0)) ** 2, axis=0) for x in X)
    return ss / np.maximum(sum(np.isfinite(x).sum(axis=0) for x in X), 1)


def follow_note(
    outputs: Sequence[str], segments: Sequence[Segment], E: Sequence[np.ndarray], runaways: int = 0
) -> tuple[str, dict[str, Any]]:
    """A message, and its numbers, when an output-error fit did not follow the data: at
    least half the outputs with residuals coloured and large (see FOLLOW_LAG1), or trial
    parameter values whose simulation ran away (``runaways`` of them). Both mark a model
    simulated open loop that cannot track the flight: an unstable aircraft, or strong
    process noise (turbulence). ("", {}) otherwise."""
    with np.errstate(all="ignore"):
        rho = lag1_autocorrelation(E)
        share = _pooled_variance(E) / _pooled_variance([s.z for s in segments])
    bad = [j for j in range(len(outputs)) if rho[j] > FOLLOW_LAG1 and share[j] > FOLLOW_SHARE]
    coloured = len(bad) >= max(1, int(np.ceil(len(outputs) / 2)))
    if not coloured and not runaways:
        return "", {}
    why = []
    if coloured:
        why.append(
            f"the residuals of {', '.join(outputs[j] for j in bad)} are far from white "
            f"(lag-1 autocorrelation {', '.join(f'{rho[j]:.2f}' for j in bad)}) and "
            f"leave {', '.join(f'{100 * min(share[j], 9.99):.0f}' for j in bad)} % of "
            "their measured variance unexplained"
        )
    if runaways:
        why.append(f"the simulation ran away for {runaways} trial parameter set{'s' if runaways > 1 else ''}")
    msg = (
        f"the model does not follow the data: {' and '.join(why)}. An unstable aircraft "
        "(or strong turbulence) cannot be fitted by simulating it open loop: use "
        f"{UNSTABLE_METHODS}"
    )
    info = {
        "outputs": [outputs[j] for j in bad],
        "runaways": int(runaways),
        "lag1": dict(zip(outputs, rho.tolist())),
        "unexplained": dict(zip(outputs, share.tolist())),
    }
    return msg, info


#: (model, segment, k, layout, theta (n_all,)) -> (Y (N, n_out), S (N, n_out, n_relevant))
SensitivityHook = Callable[[Model, Segment, int, Layout, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _counts(E: Sequence[np.ndarray]) -> np.ndarray:
    """(n_out,) samples of each output in residuals ``E`` (NaN: not measured there)."""
    return sum(np.isfinite(np.asarray(e, float)).sum(axis=0) for e in E)


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
        the optimum, where the simplex over every free parameter only costs time - minutes
        on the numpy path of the stabilised models), "always" runs it first, "never" does
        not.
    rtol, atol : tolerances of the adaptive integrator.
    inputs : input variation inside a sample interval: "linear" (default: each integration
        stage reads them interpolated at its own time) or "hold" (see :data:`estimators.simulation.integrators.INPUT_MODES`).
    callback : called as callback(iteration, cost, params Series) after each iteration.

    A fit whose model does not follow the data (residuals of most outputs coloured and
    large, or trial steps whose simulation ran away: an unstable aircraft or strong
    turbulence, see :func:`follow_note`) keeps ``converged`` as the optimiser left it; its
    ``message`` says so and names the methods for unstable aircraft, and
    ``extra["not_followed"]`` holds the numbers.
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
        fd_step: float = 1e-6,
        max_iter: int = 50,
        tol: float = 1e-6,
        step_halvings: int = 10,
        priors: Mapping[str, tuple[float, float]] | None = None,
        fallback: str = "auto",
        rtol: float = 1e-8,
        atol: float = 1e-10,
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
        if fallback not in ("auto", "always", "never"):
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

    # -- simulation of the whole data set ---------------------------------------------------
    def _simulate(self, theta: np.ndarray) -> list[np.ndarray] | None:
        """Outputs per segment for one parameter vector; None if any simulation diverged."""
        Ys = []
        for k, seg in enumerate(self._segments):
            Y = simulate_batch(
                self.model, seg, theta[None, :], self._lay, k, self.integrator, self.rtol, self.atol, inputs=self.inputs
            )[:, :, 0]
            if not np.all(np.isfinite(Y)) or runaway(seg, Y) is not None:
                return None
            Ys.append(Y)
        return Ys

    def _residuals(self, Ys: Sequence[np.ndarray] | None) -> list[np.ndarray] | None:
        if Ys is None:
            return None
        return [seg.z - Y for seg, Y in zip(self._segments, Ys)]

    def _sensitivities(self, theta: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Outputs Y_k (N, n_out) and sensitivities S_k per segment (:class:`Sensitivity`:
        (N, n_out) by the free parameters segment k depends on), all perturbed parameter
        sets of a segment integrated in one batch."""
        lay = self._lay
        free_idx = lay.free_idx
        col = {j: i for i, j in enumerate(free_idx)}
        Ys, Ss = [], []
        for k, seg in enumerate(self._segments):
            rel = lay.relevant[k]
            cols = np.array([col[j] for j in rel], dtype=int)
            if callable(self.jacobian):
                Y, Srel = self.jacobian(self.model, seg, k, lay, theta)
                Ys.append(Y)
                Ss.append(Sensitivity(np.asarray(Srel, dtype=float), cols, free_idx.size))
                continue
            step = self.fd_step * np.maximum(np.abs(theta[rel]), 1.0)
            up_ok = theta[rel] + step <= lay.upper[rel]
            sgn = np.where(up_ok, 1.0, -1.0)  # step backwards at an upper bound
            m = rel.size
            central = self.jacobian == "central"
            B = 1 + m * (2 if central else 1)
            Theta = np.repeat(theta[None, :], B, axis=0)
            Theta[1 + np.arange(m), rel] += sgn * step
            if central:
                Theta[1 + m + np.arange(m), rel] -= sgn * step
            Yb, Xb = simulate_batch(
                self.model,
                seg,
                Theta,
                lay,
                k,
                self.integrator,
                self.rtol,
                self.atol,
                return_states=True,
                inputs=self.inputs,
            )
            if not np.all(np.isfinite(Yb[:, :, 0])):
                raise divergence_error(self.model, seg, Xb[:, :, 0], k, "at the current parameter values", DIVERGE_HINT)
            Y = Yb[:, :, 0]
            away = runaway(seg, Y)
            if away is not None:
                raise runaway_error(self.model, seg, k, away, "at the current parameter values")
            if central:
                Srel = (Yb[:, :, 1 : 1 + m] - Yb[:, :, 1 + m :]) / (2.0 * sgn * step)
            else:
                Srel = (Yb[:, :, 1 : 1 + m] - Y[:, :, None]) / (sgn * step)
            if not np.all(np.isfinite(Srel)):
                bad = [lay.names[rel[i]] for i in np.flatnonzero(~np.isfinite(Srel).all(axis=(0, 1)))]
                raise divergence_error(
                    self.model,
                    seg,
                    Xb[:, :, 1 + int(np.flatnonzero(~np.isfinite(Srel).all(axis=(0, 1)))[0])],
                    k,
                    f"when perturbing {', '.join(bad)}",
                    DIVERGE_HINT,
                )
            Ys.append(Y)
            Ss.append(Sensitivity(Srel, cols, free_idx.size))
        return Ys, Ss

    def _linearise(self, theta: np.ndarray):
        """Everything a Gauss-Newton step needs at theta: outputs Ys, sensitivities Ss,
        residuals E, R (estimated unless fixed), its whitener L, and the information
        matrix F, gradient G and cost J, a-priori terms included."""
        Ys, Ss = self._sensitivities(theta)
        E = [seg.z - Y for seg, Y in zip(self._segments, Ys)]
        R = self._R(E)
        L = st.whitener(R)
        F, G, J = st.information_and_gradient(Ss, E, L)
        W, gp, Jp = self._prior_terms(theta[self._lay.free_idx])
        return Ys, Ss, E, R, L, F + W, G + gp, J + Jp

    # -- a-priori penalty -----------------------------------------------------------------
    def _prior_terms(self, theta_free: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """W (n_free, n_free), W (theta* - theta), and 1/2 (theta-theta*)^T W (theta-theta*)."""
        n = theta_free.size
        W = np.zeros((n, n))
        g = np.zeros(n)
        J = 0.0
        names = self._lay.free_names
        for name, (mu, sd) in self.priors.items():
            if name not in names:
                raise ModelDefinitionError(f"prior on {name!r}: not a free parameter ({names})")
            i = names.index(name)
            w = 1.0 / float(sd) ** 2
            W[i, i] = w
            g[i] = w * (float(mu) - theta_free[i])
            J += 0.5 * w * (theta_free[i] - float(mu)) ** 2
        return W, g, J

    def _R(self, E: Sequence[np.ndarray]) -> np.ndarray:
        return self._R_fixed if self._R_fixed is not None else st.residual_covariance(E, full=self.noise == "full")

    def _nll(self, theta: np.ndarray) -> float:
        """Negative log-likelihood with R at its optimum: (N/2) log det R + prior penalty."""
        E = self._residuals(self._simulate(theta))
        return np.inf if E is None else self._nll_of(E, theta[self._lay.free_idx])

    def _likelihood_det(self, E: Sequence[np.ndarray]) -> float:
        """det(R) for residuals ``E`` as the likelihood weighs it: prod_j R_jj^(N_j / mean_j
        N_j) for a diagonal R (det(R) when every output has every sample), det(R) for a
        full one."""
        R = self._R(E)
        if self.noise == "full":
            return float(np.linalg.det(R))
        n_j = _counts(E)
        with np.errstate(divide="ignore", invalid="ignore"):
            return float(np.exp(n_j @ np.log(np.diag(R)) / np.mean(n_j)))

    def _nll_of(self, E: Sequence[np.ndarray], theta_free: np.ndarray) -> float:
        """The negative log-likelihood of residuals ``E`` with R at its optimum for them:
        sum_j N_j/2 log R_jj for a diagonal R (N_j the samples of output j: multi-rate
        data), N/2 log det R for a full one, J for a fixed R; plus the prior penalty."""
        R = self._R(E)
        if self._R_fixed is not None:
            val = st.weighted_cost(E, st.whitener(R))
        elif self.noise == "full":
            sign, logdet = np.linalg.slogdet(R)
            if sign <= 0 or not np.isfinite(logdet):
                return np.inf
            val = 0.5 * sum(e.shape[0] for e in E) * logdet
        else:
            d = np.diag(R)
            if not np.all(d > 0):
                return np.inf
            val = 0.5 * float(_counts(E) @ np.log(d))
        return val + self._prior_terms(theta_free)[2]

    def _simplex(self, theta: np.ndarray, max_evals: int | None = None) -> np.ndarray:
        """Nelder-Mead on the free parameters (within bounds) from a poor start."""
        lay = self._lay
        fi = lay.free_idx
        x0 = theta[fi]
        scale = np.where(np.abs(x0) > 1e-8, np.abs(x0), 1.0)

        def fun(xs):
            th = theta.copy()
            th[fi] = np.clip(xs * scale, lay.lower[fi], lay.upper[fi])
            return self._nll(th)

        n = fi.size
        sim0 = np.vstack([x0 / scale] + [x0 / scale + 0.2 * np.eye(n)[i] for i in range(n)])
        from scipy import optimize  # only this start needs it: import on use

        res = optimize.minimize(
            fun,
            x0 / scale,
            method="Nelder-Mead",
            options={"maxfev": max_evals or max(600, 200 * n), "initial_simplex": sim0, "xatol": 1e-6, "fatol": 1e-8},
        )
        out = theta.copy()
        out[fi] = np.clip(res.x * scale, lay.lower[fi], lay.upper[fi])
        self._n_simplex_evals += int(res.nfev)
        return out

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
            derivatives: the HFB-320 test-case-4 flight of tests/test_user_model_api.py
            cut into two segments gave derivatives up to 8.2 std off, 1.5 with "auto".
        R : a fixed measurement-noise covariance (n_out, n_out); estimated when None.
        start : start values by expanded name, overriding the model's.
        """
        segments = [segments] if isinstance(segments, Segment) else list(segments)
        if not segments:
            raise ModelDefinitionError("fit() needs at least one segment")
        self._segments = segments
        lay = self._lay = Layout.build(self.model, segments, estimate_x0, values=start)
        check_outputs_measured(self.model, segments, "output error")
        fi = lay.free_idx
        if fi.size == 0:
            raise ModelDefinitionError("no free parameters: mark some Parameter(..., free=True)")
        self._R_fixed = None if R is None else np.atleast_2d(np.asarray(R, dtype=float))
        self._n_simplex_evals = 0
        theta = lay.values.copy()
        lo, hi = lay.lower[fi], lay.upper[fi]

        if self._simulate(theta) is None:
            self._raise_simulation_failure(theta, "with the start values")
        used_simplex = False
        if self.fallback == "always":
            theta = self._simplex(theta)
            used_simplex = True

        history: list[dict[str, Any]] = []
        converged = False
        message = ""
        runaways = 0  # line-search trials whose simulation ran away or diverged
        lam = 1e-3
        cost_old = np.inf
        it = 0
        R_cur = None
        n_accepted = 0
        for it in range(1, self.max_iter + 1):
            Ys, Ss, E, R_cur, L, F, G, J = self._linearise(theta)
            cost = float(np.linalg.det(R_cur))
            # det(R), or J when R is given; with outputs at several rates the likelihood's
            # own det: prod_j R_jj^(N_j / mean N) (det(R) itself then swings from one
            # iteration to the next while the likelihood falls, and the fit ran on)
            watched = self._likelihood_det(E) if self._R_fixed is None else J
            if it == 1:
                st.check_identifiable(F, lay.free_names, " at the start values")
            history.append(self._history_row(it - 1, cost, J, theta, np.nan, lam))
            if self.callback:
                self.callback(it - 1, cost, pd.Series(theta[fi], index=lay.free_names))
            if np.isfinite(cost_old) and abs(cost_old - watched) <= self.tol * abs(watched):
                converged = True
                break
            cost_old = watched

            # bounded-variable Gauss-Newton: freeze parameters on a bound pushed outward
            tf = theta[fi]
            span = np.maximum(1.0, np.abs(tf))
            at_lo = tf <= lo + 1e-12 * span
            at_hi = tf >= hi - 1e-12 * span
            active = ~((at_lo & (G < 0)) | (at_hi & (G > 0)))
            if not np.any(active):
                converged = True
                message = "every free parameter is held on a bound"
                break
            a = np.flatnonzero(active)
            J_now = self._nll_of(E, tf) if self._R_fixed is None else J
            accepted = False
            tries = self.step_halvings + 1
            alpha = 1.0
            delta = np.zeros_like(tf)
            if self.optimizer == "gauss-newton":
                delta[a] = st.solve_step(F[np.ix_(a, a)], G[a])
            for _ in range(tries):
                if self.optimizer == "levenberg-marquardt":
                    delta = np.zeros_like(tf)
                    delta[a] = st.solve_step(F[np.ix_(a, a)], G[a], lam)
                    step = delta
                else:
                    step = alpha * delta
                trial = theta.copy()
                trial[fi] = np.clip(tf + step, lo, hi)
                Et = self._residuals(self._simulate(trial))
                runaways += Et is None
                if self._R_fixed is None:
                    # the likelihood itself, R at its optimum for each trial: with J at this
                    # iteration's R a full step could raise det(R), and the iterations
                    # zig-zagged (the 6-DoF lateral model of multiaxis_multisine_turbulence:
                    # 35 iterations, det(R) up on every other one)
                    Jt = self._nll_of(Et, trial[fi]) if Et is not None else np.inf
                else:
                    Jt = st.weighted_cost(Et, L) if Et is not None else np.inf
                    Jt += self._prior_terms(trial[fi])[2]
                if Jt < J_now:
                    accepted = True
                    n_accepted += 1
                    theta = trial
                    lam = max(lam / 10.0, 1e-10)
                    break
                alpha *= 0.5
                lam *= 10.0
            history[-1]["step"] = alpha if self.optimizer == "gauss-newton" else 1.0
            if not accepted:
                predicted = 0.5 * float(G[a] @ delta[a])
                if predicted <= 1e-10 * max(J, 1.0):
                    converged = True  # no descent left: at the minimum to round-off
                    break
                if self.fallback == "auto" and not used_simplex and not n_accepted:
                    theta = self._simplex(theta)
                    used_simplex = True
                    cost_old = np.inf
                    continue
                message = (
                    "no step lowered the cost (line search failed) - the start may be poor or the model may not describe the data"
                    if not n_accepted
                    else f"no step lowered the cost after {n_accepted} accepted steps (line "
                    "search failed near the optimum: the finite-difference gradient is "
                    "too coarse there; jacobian='central' refines it)"
                )
                break
        else:
            message = f"stopped at max_iter={self.max_iter} before det(R) settled"

        if not converged and not message:
            message = "did not converge"
        # final information matrix at the final parameters
        Ys, Ss, E, R_cur, L, F, G, J = self._linearise(theta)
        tf = theta[fi]
        span = np.maximum(1.0, np.abs(tf))
        on_bound = (tf <= lo + 1e-9 * span) | (tf >= hi - 1e-9 * span)
        inner = np.flatnonzero(~on_bound)
        cov = np.full((fi.size, fi.size), np.nan)
        if inner.size:
            st.check_identifiable(F[np.ix_(inner, inner)], [lay.free_names[i] for i in inner], " at the estimates")
            cov[np.ix_(inner, inner)] = st.covariance(F[np.ix_(inner, inner)])
        if used_simplex:
            message = (
                message + "; " if message else ""
            ) + f"started with Nelder-Mead ({self._n_simplex_evals} evaluations)"
        extra: dict[str, Any] = {}
        if self.priors:
            # the a-priori part of F (free-parameter order): the Morelli-Klein sandwich adds
            # it to its middle term (estimators.validation.morelli_klein, prior_info)
            extra["prior_information"] = self._prior_terms(theta[lay.free_idx])[0]
        if self._check_follow:
            note, info = follow_note(self.model.outputs, segments, E, runaways)
            if note:
                message = (message + "; " if message else "") + note
                extra["not_followed"] = info
        return EstimationResult(
            method=self.method,
            model=self.model,
            names=list(lay.names),
            values=theta,
            free=lay.free.copy(),
            cov=cov,
            R=R_cur,
            converged=converged,
            iterations=it,
            history=pd.DataFrame(history),
            segments=segments,
            predicted=frames([s.t for s in segments], Ys, self.model.outputs),
            residuals=frames([s.t for s in segments], E, self.model.outputs),
            at_bounds=[lay.free_names[i] for i in np.flatnonzero(on_bound)],
            message=message,
            information=F,
            sensitivities=Ss,
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
        parameter, :mod:`pipeline.uncertainty.consider`), for one simulation instead of
        a refit's several sensitivity batches; exact when the outputs are linear in the
        parameters. Parameters at a bound stay there. ``segments`` must be the result's
        (same spans) and give the same free parameters.

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
        self._segments = segments
        lay = self._lay = Layout.build(
            self.model, segments, estimate_x0, values={n: v for n, v in result.params.items() if n in free}
        )
        if list(lay.free_names) != list(result.free_names):
            raise ModelDefinitionError(
                "step_from: this model and these segments give other free parameters than the result"
            )
        theta = lay.values.copy()
        Ys = self._simulate(theta)
        if Ys is None:
            self._raise_simulation_failure(theta, "at the result's estimates")
        E = self._residuals(Ys)
        dE = [e - r.to_numpy(dtype=float) for e, r in zip(E, result.residuals)]
        _, G, _ = st.information_and_gradient(result.sensitivities, dE, st.whitener(result.R))
        inner = np.array([i for i, n in enumerate(result.free_names) if n not in result.at_bounds], dtype=int)
        fi = lay.free_idx
        if inner.size:
            theta[fi[inner]] += st.solve_step(result.information[np.ix_(inner, inner)], G[inner])
        Ys = self._simulate(theta)
        if Ys is None:
            self._raise_simulation_failure(theta, "one step from the result's estimates")
        return replace(
            result,
            model=self.model,
            values=theta,
            segments=segments,
            predicted=frames([s.t for s in segments], Ys, self.model.outputs),
            residuals=frames([s.t for s in segments], self._residuals(Ys), self.model.outputs),
            message="one Gauss-Newton step from the earlier estimates (step_from)",
            extra=dict(result.extra),
            consider_cov=None,
            consider_source="",
        )

    # -- helpers --------------------------------------------------------------------------
    def _raise_simulation_failure(self, theta: np.ndarray, what: str) -> None:
        """Raise the error of a simulation at ``theta`` that :meth:`_simulate` refused: the
        first segment whose outputs run away (finite), else the one that diverged."""
        for k, seg in enumerate(self._segments):
            Yk = simulate_batch(
                self.model, seg, theta[None, :], self._lay, k, self.integrator, self.rtol, self.atol, inputs=self.inputs
            )[:, :, 0]
            away = runaway(seg, Yk) if np.all(np.isfinite(Yk)) else None
            if away is not None:
                raise runaway_error(self.model, seg, k, away, what)
        k, X = self._first_diverged(theta)
        raise divergence_error(self.model, self._segments[k], X, k, what, DIVERGE_HINT)

    def _first_diverged(self, theta: np.ndarray) -> tuple[int, np.ndarray]:
        for k, seg in enumerate(self._segments):
            _, X = simulate_batch(
                self.model,
                seg,
                theta[None, :],
                self._lay,
                k,
                self.integrator,
                self.rtol,
                self.atol,
                return_states=True,
                inputs=self.inputs,
            )
            if not np.all(np.isfinite(X)):
                return k, X[:, :, 0]
        return 0, X[:, :, 0]  # outputs (not states) went non-finite

    def _history_row(
        self, it: int, cost: float, J: float, theta: np.ndarray, step: float, lam: float
    ) -> dict[str, Any]:
        row: dict[str, Any] = {"iteration": it, "det_R": cost, "J": J, "step": step}
        if self.optimizer == "levenberg-marquardt":
            row["lambda"] = lam
        row.update(zip(self._lay.free_names, theta[self._lay.free_idx]))
        return row
