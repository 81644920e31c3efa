"""The output-error likelihood of one fit: simulation, residuals, sensitivities and cost.

For fixed parameters the noise covariance is R = (1/N) sum e e^T; for fixed R the cost
is J = 1/2 sum e^T R^-1 e, with the information matrix F = sum S^T R^-1 S and gradient
G = sum S^T R^-1 e, S = dy/dtheta from finite differences over a batch of perturbed
parameter sets integrated together (or the user's sensitivity hook). An a-priori penalty
(theta - theta*)^T W (theta - theta*) adds to all three. :class:`OutputErrorLikelihood`
is what :func:`estimators.optim.minimise` steps on.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimators import statistics as st
from estimators.defaults import (
    ATOL,
    FD_STEP,
    RTOL,
    SIMPLEX_EVALS_PER_PARAMETER,
    SIMPLEX_FATOL,
    SIMPLEX_MIN_EVALS,
    SIMPLEX_SCALE_MIN,
    SIMPLEX_STEP,
    SIMPLEX_XATOL,
)
from estimators.errors import ModelDefinitionError
from estimators.integrators import DEFAULT_INPUTS
from estimators.layout import Layout
from estimators.model import Model, Segment
from estimators.output_error.diagnostics import DIVERGE_HINT, runaway, runaway_error
from estimators.sensitivity import Sensitivity
from estimators.simulation import divergence_error, simulate_batch

#: (model, segment, k, layout, theta (n_all,)) -> (Y (N, n_out), S (N, n_out, n_relevant))
SensitivityHook = Callable[[Model, Segment, int, Layout, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class LikelihoodSettings:
    """How the likelihood simulates and differentiates (see :class:`~estimators.OutputError`):
    integrator, noise ("diagonal" or "full" R), jacobian ("forward", "central" or a
    :data:`SensitivityHook`), fd_step, priors {name: (value, std)}, rtol/atol of the
    adaptive integrator, inputs ("linear" or "hold")."""

    integrator: str = "rk4"
    noise: str = "diagonal"
    jacobian: str | SensitivityHook = "forward"
    fd_step: float = FD_STEP
    priors: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    rtol: float = RTOL
    atol: float = ATOL
    inputs: str = DEFAULT_INPUTS


@dataclass
class OutputErrorLinearisation:
    """The likelihood linearised at theta: outputs Ys and sensitivities Ss per segment,
    residuals E, R (n_out, n_out) and its whitener L, information F (n_free, n_free),
    gradient G (n_free,) and cost J (a-priori terms included), the convergence measure
    ``watched`` and the history's cost columns ``report``."""

    Ys: list[np.ndarray]
    Ss: list[Any]
    E: list[np.ndarray]
    R: np.ndarray
    L: np.ndarray
    F: np.ndarray
    G: np.ndarray
    J: float
    watched: float
    report: dict[str, float]


def _counts(E: Sequence[np.ndarray]) -> np.ndarray:
    """(n_out,) samples of each output in residuals ``E`` (NaN: not measured there)."""
    return sum(np.isfinite(np.asarray(e, float)).sum(axis=0) for e in E)


class OutputErrorLikelihood:
    """The likelihood of ``model`` over ``segments`` on the parameter vector of ``layout``;
    ``R_fixed`` a given measurement-noise covariance (estimated when None). Counts the
    trial steps whose simulation ran away (``runaways``) and the Nelder-Mead evaluations
    (``n_simplex_evals``)."""

    def __init__(
        self,
        model: Model,
        segments: list[Segment],
        layout: Layout,
        settings: LikelihoodSettings,
        R_fixed: np.ndarray | None = None,
    ) -> None:
        self.model = model
        self.segments = segments
        self.layout = layout
        self.settings = settings
        self.R_fixed = R_fixed
        self.runaways = 0
        self.n_simplex_evals = 0

    # -- simulation of the whole data set ---------------------------------------------------
    def simulate(self, theta: np.ndarray) -> list[np.ndarray] | None:
        """Outputs per segment for one parameter vector; None if any simulation diverged."""
        Ys = []
        for k, seg in enumerate(self.segments):
            Y = self._batch(k, theta[None, :])[:, :, 0]
            if not np.all(np.isfinite(Y)) or runaway(seg, Y) is not None:
                return None
            Ys.append(Y)
        return Ys

    def residuals(self, Ys: Sequence[np.ndarray] | None) -> list[np.ndarray] | None:
        if Ys is None:
            return None
        return [seg.z - Y for seg, Y in zip(self.segments, Ys)]

    def _batch(self, k: int, Theta: np.ndarray, return_states: bool = False):
        """Segment k simulated for the parameter vectors Theta (B, n_all):
        :func:`estimators.simulation.simulate_batch` with the fit's settings."""
        s = self.settings
        return simulate_batch(
            self.model,
            self.segments[k],
            Theta,
            self.layout,
            k,
            s.integrator,
            s.rtol,
            s.atol,
            return_states=return_states,
            inputs=s.inputs,
        )

    def sensitivities(self, theta: np.ndarray) -> tuple[list[np.ndarray], list[Sensitivity]]:
        """Outputs Y_k (N, n_out) and sensitivities S_k per segment (:class:`Sensitivity`:
        (N, n_out) by the free parameters segment k depends on), all perturbed parameter
        sets of a segment integrated in one batch."""
        lay = self.layout
        free_idx = lay.free_idx
        col = {j: i for i, j in enumerate(free_idx)}
        Ys, Ss = [], []
        for k, seg in enumerate(self.segments):
            rel = lay.relevant[k]
            cols = np.array([col[j] for j in rel], dtype=int)
            if callable(self.settings.jacobian):
                Y, Srel = self.settings.jacobian(self.model, seg, k, lay, theta)
                Srel = np.asarray(Srel, dtype=float)
            else:
                Y, Srel = self._finite_differences(k, theta, rel)
            Ys.append(Y)
            Ss.append(Sensitivity(Srel, cols, free_idx.size))
        return Ys, Ss

    def _finite_differences(self, k: int, theta: np.ndarray, rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Segment k's outputs Y (N, n_out) at theta and their finite-difference
        sensitivities (N, n_out, len(rel)) to the parameters ``rel`` (forward, or central
        with ``jacobian="central"``; a step backwards at an upper bound). Raises
        SimulationDivergedError when a simulation diverges or runs away."""
        lay, seg = self.layout, self.segments[k]
        step = self.settings.fd_step * np.maximum(np.abs(theta[rel]), 1.0)
        up_ok = theta[rel] + step <= lay.upper[rel]
        sgn = np.where(up_ok, 1.0, -1.0)  # step backwards at an upper bound
        m = rel.size
        central = self.settings.jacobian == "central"
        B = 1 + m * (2 if central else 1)
        Theta = np.repeat(theta[None, :], B, axis=0)
        Theta[1 + np.arange(m), rel] += sgn * step
        if central:
            Theta[1 + m + np.arange(m), rel] -= sgn * step
        Yb, Xb = self._batch(k, Theta, return_states=True)
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
            bad_cols = np.flatnonzero(~np.isfinite(Srel).all(axis=(0, 1)))
            raise divergence_error(
                self.model,
                seg,
                Xb[:, :, 1 + int(bad_cols[0])],
                k,
                f"when perturbing {', '.join(lay.names[rel[i]] for i in bad_cols)}",
                DIVERGE_HINT,
            )
        return Y, Srel

    def linearise(self, theta: np.ndarray) -> OutputErrorLinearisation:
        """Everything a Gauss-Newton step needs at theta: outputs Ys, sensitivities Ss,
        residuals E, R (estimated unless fixed), its whitener L, and the information
        matrix F, gradient G and cost J, a-priori terms included; the convergence measure
        is det(R), or J when R is given, and with outputs at several rates the
        likelihood's own det: prod_j R_jj^(N_j / mean N) (det(R) itself then swings from
        one iteration to the next while the likelihood falls)."""
        Ys, Ss = self.sensitivities(theta)
        E = [seg.z - Y for seg, Y in zip(self.segments, Ys)]
        R = self.R(E)
        L = st.whitener(R)
        F, G, J = st.information_and_gradient(Ss, E, L)
        W, gp, Jp = self.prior_terms(theta[self.layout.free_idx])
        J = J + Jp
        cost = float(np.linalg.det(R))
        watched = self.likelihood_det(E) if self.R_fixed is None else J
        return OutputErrorLinearisation(Ys, Ss, E, R, L, F + W, G + gp, J, watched, {"det_R": cost, "J": J})

    def cost_to_beat(self, lin: OutputErrorLinearisation, theta: np.ndarray) -> float:
        """The cost at theta a trial step must lower: the negative log-likelihood with R at
        its optimum, or J for a fixed R."""
        return self.nll_of(lin.E, theta[self.layout.free_idx]) if self.R_fixed is None else lin.J

    def trial_cost(self, trial: np.ndarray, lin: OutputErrorLinearisation) -> float:
        """The cost at a trial vector, inf when its simulation diverges or runs away
        (counted in ``runaways``). With R estimated it is the likelihood itself, R at its
        optimum for the trial: with J at this iteration's R a full step could raise det(R)
        and the iterations zig-zag."""
        fi = self.layout.free_idx
        Et = self.residuals(self.simulate(trial))
        self.runaways += Et is None
        if self.R_fixed is None:
            return self.nll_of(Et, trial[fi]) if Et is not None else np.inf
        Jt = st.weighted_cost(Et, lin.L) if Et is not None else np.inf
        Jt += self.prior_terms(trial[fi])[2]
        return Jt

    # -- a-priori penalty -----------------------------------------------------------------
    def prior_terms(self, theta_free: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """W (n_free, n_free), W (theta* - theta), and 1/2 (theta-theta*)^T W (theta-theta*)."""
        n = theta_free.size
        W = np.zeros((n, n))
        g = np.zeros(n)
        J = 0.0
        names = self.layout.free_names
        for name, (mu, sd) in self.settings.priors.items():
            if name not in names:
                raise ModelDefinitionError(f"prior on {name!r}: not a free parameter ({names})")
            i = names.index(name)
            w = 1.0 / float(sd) ** 2
            W[i, i] = w
            g[i] = w * (float(mu) - theta_free[i])
            J += 0.5 * w * (theta_free[i] - float(mu)) ** 2
        return W, g, J

    def R(self, E: Sequence[np.ndarray]) -> np.ndarray:
        return (
            self.R_fixed if self.R_fixed is not None else st.residual_covariance(E, full=self.settings.noise == "full")
        )

    def nll(self, theta: np.ndarray) -> float:
        """Negative log-likelihood with R at its optimum: (N/2) log det R + prior penalty."""
        E = self.residuals(self.simulate(theta))
        return np.inf if E is None else self.nll_of(E, theta[self.layout.free_idx])

    def likelihood_det(self, E: Sequence[np.ndarray]) -> float:
        """det(R) for residuals ``E`` as the likelihood weighs it: prod_j R_jj^(N_j / mean_j
        N_j) for a diagonal R (det(R) when every output has every sample), det(R) for a
        full one."""
        R = self.R(E)
        if self.settings.noise == "full":
            return float(np.linalg.det(R))
        n_j = _counts(E)
        with np.errstate(divide="ignore", invalid="ignore"):
            return float(np.exp(n_j @ np.log(np.diag(R)) / np.mean(n_j)))

    def nll_of(self, E: Sequence[np.ndarray], theta_free: np.ndarray) -> float:
        """The negative log-likelihood of residuals ``E`` with R at its optimum for them:
        sum_j N_j/2 log R_jj for a diagonal R (N_j the samples of output j: multi-rate
        data), N/2 log det R for a full one, J for a fixed R; plus the prior penalty."""
        R = self.R(E)
        if self.R_fixed is not None:
            val = st.weighted_cost(E, st.whitener(R))
        elif self.settings.noise == "full":
            sign, logdet = np.linalg.slogdet(R)
            if sign <= 0 or not np.isfinite(logdet):
                return np.inf
            val = 0.5 * sum(e.shape[0] for e in E) * logdet
        else:
            d = np.diag(R)
            if not np.all(d > 0):
                return np.inf
            val = 0.5 * float(_counts(E) @ np.log(d))
        return val + self.prior_terms(theta_free)[2]

    def simplex(self, theta: np.ndarray, max_evals: int | None = None) -> np.ndarray:
        """Nelder-Mead on the free parameters (within bounds) from a poor start."""
        lay = self.layout
        fi = lay.free_idx
        x0 = theta[fi]
        scale = np.where(np.abs(x0) > SIMPLEX_SCALE_MIN, np.abs(x0), 1.0)

        def fun(xs):
            th = theta.copy()
            th[fi] = np.clip(xs * scale, lay.lower[fi], lay.upper[fi])
            return self.nll(th)

        n = fi.size
        sim0 = np.vstack([x0 / scale] + [x0 / scale + SIMPLEX_STEP * np.eye(n)[i] for i in range(n)])
        # imported on use: scipy.optimize is slow to import and only this fallback needs it
        from scipy import optimize

        res = optimize.minimize(
            fun,
            x0 / scale,
            method="Nelder-Mead",
            options={
                "maxfev": max_evals or max(SIMPLEX_MIN_EVALS, SIMPLEX_EVALS_PER_PARAMETER * n),
                "initial_simplex": sim0,
                "xatol": SIMPLEX_XATOL,
                "fatol": SIMPLEX_FATOL,
            },
        )
        out = theta.copy()
        out[fi] = np.clip(res.x * scale, lay.lower[fi], lay.upper[fi])
        self.n_simplex_evals += int(res.nfev)
        return out

    # -- failures -------------------------------------------------------------------------
    def raise_simulation_failure(self, theta: np.ndarray, what: str) -> None:
        """Raise the error of a simulation at ``theta`` that :meth:`simulate` refused: the
        first segment whose outputs run away (finite), else the one that diverged."""
        for k, seg in enumerate(self.segments):
            Yk = self._batch(k, theta[None, :])[:, :, 0]
            away = runaway(seg, Yk) if np.all(np.isfinite(Yk)) else None
            if away is not None:
                raise runaway_error(self.model, seg, k, away, what)
        k, X = self.first_diverged(theta)
        raise divergence_error(self.model, self.segments[k], X, k, what, DIVERGE_HINT)

    def first_diverged(self, theta: np.ndarray) -> tuple[int, np.ndarray]:
        """(segment index, states (N, n)) of the first segment whose states went
        non-finite at ``theta``; segment 0 when only outputs did."""
        for k in range(len(self.segments)):
            _, X = self._batch(k, theta[None, :], return_states=True)
            if not np.all(np.isfinite(X)):
                return k, X[:, :, 0]
        return 0, X[:, :, 0]  # outputs (not states) went non-finite
