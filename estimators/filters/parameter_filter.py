"""The shared driver of the Kalman filters that estimate parameters (:class:`ParameterFilter`,
the base of :class:`~estimators.filters.ekf.EKF` and :class:`~estimators.filters.ukf.UKF`).

The unknown parameters are appended to the state with zero dynamics (optionally a random
walk), s = [x; theta], and a filter pass over the data estimates both; passes are repeated
from the last estimates until they settle (``passes="auto"``). Discrete model, sample
k -> k+1 (step h = t_{k+1} - t_k)::

    x_{k+1} = Phi_h(x_k, u, theta) + w_k,   w_k ~ N(0, Qd),  Qd = F F^T h
    theta_{k+1} = theta_k + w_theta,        w_theta ~ N(0, diag(param_noise^2) h)
    z_k = g(x_k, u_k, theta) + v_k,         v_k ~ N(0, R)

Phi_h is one step of the package's integrator (default RK4, inputs interpolated at each
stage time as in output error), so the filters predict exactly like the output-error
simulation. Several segments: the filter restarts at each segment's initial state with the
parameter estimate and its covariance carried over from the previous segment; per-segment
parameters (``bias_az[k]``) sit in the state for every segment and only move while their
own segment runs.

Each segment runs in the model's compiled segment loop (:mod:`estimators.filters.loops`)
when the model compiles, else sample by sample in Python with the subclass's
``_predict``/``_update``. The two give the same estimates to rounding, not bit for bit
(their integrators, square roots and sums are evaluated in a different order), so both
are kept.

The result is an :class:`~estimators.EstimationResult`: ``predicted`` are the a-priori
(one-step-ahead) outputs g(x_k|k-1) and ``residuals`` the innovations z_k - g(x_k|k-1);
``R`` is the sample covariance of the innovations (the measurement-noise covariance the
filter used is ``extra["measurement_noise"]``); ``cov`` the final parameter block of P.
``extra`` holds ``trajectory``/``trajectory_std`` (per segment, DataFrames on t),
``states`` (a-posteriori states), ``posterior_outputs``, ``gain`` (last Kalman gain),
``process_noise`` (F) and ``cluster``: the maneuvers' scatter of the last pass
(:mod:`estimators.covariance.cluster`, each segment a cluster, from what it added to the
parameters' information; :func:`~estimators.filters.filter_pass.segment_scatter`), None
with one segment.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from estimators import statistics as st
from estimators.errors import ModelDefinitionError, SimulationDivergedError
from estimators.filters.augmented import AugmentedModel
from estimators.filters.filter_pass import (
    Passes,
    PassRecord,
    SegmentRun,
    SegmentStart,
    information_form,
    segment_scatter,
)
from estimators.filters.gain_sensitivity import GainSensitivity
from estimators.filters.noise import (
    ADAPT_CHOICES,
    NoiseMatch,
    matched_noise,
    measurement_noise_matrix,
    named_vector,
    process_noise_matrix,
)
from estimators.filters.update import innovation_nll
from estimators.integrators import DEFAULT_INPUTS, check_options
from estimators.layout import Layout
from estimators.model import Model, Segment
from estimators.results import EstimationResult, frames


class ParameterFilter:
    """The pass driver of the parameter-estimating Kalman filters; a subclass gives the
    filter equations (``_predict``, ``_update``) and its compiled segment loop
    (``_compiled_segment``). The keywords are documented on :class:`~estimators.EKF`."""

    method = "ekf"

    def __init__(
        self,
        model: Model,
        *,
        integrator: str = "rk4",
        process_noise: Any = None,
        measurement_noise: Any = None,
        param_std: Any = None,
        state_std: Any = None,
        param_noise: Any = None,
        rtol: float = 1e-8,
        atol: float = 1e-10,
        inputs: str = DEFAULT_INPUTS,
        passes: int | str = "auto",
        max_passes: int = 8,
        pass_tol: float = 0.2,
        adapt_noise: bool | str = "auto",
        callback: Callable[[int, float, pd.Series], None] | None = None,
        compiled: bool = True,
        gain_sensitivity: bool = False,
        gain_step: float = 1e-5,
    ) -> None:
        check_options(integrator, inputs)
        self.gain_sensitivity, self.gain_step = bool(gain_sensitivity), float(gain_step)
        self.callback = callback
        self.compiled = compiled
        if adapt_noise not in ADAPT_CHOICES:
            raise ModelDefinitionError(f"adapt_noise must be one of {ADAPT_CHOICES}, got {adapt_noise!r}")
        self.adapt_noise = adapt_noise
        if not (passes == "auto" or (isinstance(passes, int) and passes >= 1)):
            raise ModelDefinitionError(f"passes must be 'auto' or a whole number >= 1, got {passes!r}")
        if int(max_passes) < 1 or not pass_tol > 0:
            raise ModelDefinitionError("max_passes must be >= 1 and pass_tol > 0")
        self.passes, self.max_passes, self.pass_tol = passes, int(max_passes), float(pass_tol)
        self.inputs = inputs
        self.model = model
        self.integrator = integrator
        self.process_noise = process_noise
        self.measurement_noise = measurement_noise
        self.param_std = param_std
        self.state_std = state_std
        self.param_noise = param_noise
        self.rtol, self.atol = rtol, atol

    # set-up ----------------------------------------------------------------------------------
    def _initial_param_cov(self, lay: Layout) -> np.ndarray:
        fi = lay.free_idx
        v = lay.values[fi]
        names = lay.free_names
        default = np.where(np.abs(v) > 0, 0.5 * np.abs(v), 1.0)
        if self.param_std is None:
            sd = default
        elif np.ndim(self.param_std) == 0 and not isinstance(self.param_std, Mapping):
            sd = np.where(np.abs(v) > 0, float(self.param_std) * np.abs(v), 1.0)
        else:
            spec = dict(self.param_std) if isinstance(self.param_std, Mapping) else self.param_std
            if isinstance(spec, dict):
                # a model parameter name applies to all its per-segment copies
                spec = {n: spec.get(n, spec.get(n.split("[")[0], None)) for n in names}
                spec = {n: s for n, s in spec.items() if s is not None}
            sd = named_vector(spec, names, "param_std", default)
        return np.diag(sd**2)

    def _param_noise(self, lay: Layout) -> np.ndarray:
        names = lay.free_names
        if isinstance(self.param_noise, Mapping):
            spec = {n: self.param_noise.get(n, self.param_noise.get(n.split("[")[0])) for n in names}
            spec = {n: s for n, s in spec.items() if s is not None}
        else:
            spec = self.param_noise
        return named_vector(spec, names, "param_noise", np.zeros(len(names)))

    def _initial_state_cov(self, R: np.ndarray, aug: AugmentedModel, s: np.ndarray, F: np.ndarray) -> np.ndarray:
        """Initial state covariance (n, n) of a segment from the augmented start s:
        ``state_std`` where given; else an output's measurement std; else, for a state
        driven by process noise (a gust state), the stationary spread of its own
        dynamics, (F F^T)_ii h / (1 - Phi_ii^2) (Phi_ii the state's own one-step gain at
        the start; F sqrt(tau / 2) for a first-order gust of time constant tau: the gust
        at a segment start is unknown, not 0); else 1e-3 max(|x0|, 1)."""
        m, n = self.model, aug.n
        x0 = s[:n]
        default = np.array(
            [
                np.sqrt(R[m.outputs.index(st), m.outputs.index(st)]) if st in m.outputs else 1e-3 * max(abs(x0[i]), 1.0)
                for i, st in enumerate(m.states)
            ]
        )
        q = np.diag(F @ F.T)
        noisy = np.flatnonzero([st not in m.outputs and q[i] > 0 for i, st in enumerate(m.states)])
        if noisy.size and aug.seg.n > 1:
            h = aug.seg.t[1] - aug.seg.t[0]
            d = 1e-6 * np.maximum(np.abs(x0[noisy]), 1.0)
            S = np.repeat(s[:, None], noisy.size + 1, axis=1)
            S[noisy, 1 + np.arange(noisy.size)] += d
            X = aug.step(S, 0)
            phi = (X[noisy, 1 + np.arange(noisy.size)] - X[noisy, 0]) / d
            ok = np.isfinite(phi) & (np.abs(phi) < 1.0)
            default[noisy[ok]] = np.sqrt(q[noisy[ok]] * h / (1.0 - phi[ok] ** 2))
        sd = named_vector(self.state_std, m.states, "state_std", default)
        return np.diag(sd**2)

    def _adapted(self, F: np.ndarray) -> tuple[bool, bool]:
        """(adapt R, adapt Q) for this fit, from ``adapt_noise``."""
        a = self.adapt_noise
        adapt_r = a in (True, "R") or (a == "auto" and self.measurement_noise is None)
        adapt_q = a in (True, "Q")
        if adapt_q and not np.any(np.diag(F)):
            raise ModelDefinitionError(
                "adapt_noise: the process noise is adapted for the states that have some; "
                "give process_noise (e.g. {'alpha': 0.01, 'q': 0.02}) to start from"
            )
        if adapt_q and np.any(F - np.diag(np.diag(F))):
            raise ModelDefinitionError(
                "adapt_noise: process-noise adaptation needs a diagonal process_noise (a std per state), not a full matrix"
            )
        return adapt_r, adapt_q

    # the fit ---------------------------------------------------------------------------------
    def fit(
        self,
        segments: Segment | Sequence[Segment],
        estimate_x0: bool | str | Sequence[str] = "auto",
        start: Mapping[str, float] | None = None,
    ) -> EstimationResult:
        """Run the filter over the segments in order, in passes; returns the final estimates.
        With no free parameter it is a state estimator (``extra["states"]``; the
        proof of match of :func:`estimators.validation.predict_ahead` uses it so).

        estimate_x0 : taken so that the call reads as OutputError's and FilterError's
            (every method interchangeable); the filter estimates every state at every
            sample, the first included, from the segment's x0 (or first finite sample) and
            ``state_std``, whatever it says. State names are checked.
        start : start values by expanded name, overriding the model's.

        Passes: each pass starts from the previous pass's estimates, with the initial
        parameter covariance set again from them (``param_std``), so the reported std is
        that of one pass over the data. ``passes="auto"`` repeats until a pass moves no
        free parameter by more than ``pass_tol`` times its std (at most ``max_passes``;
        ``converged`` False when it does not settle): one pass from a start far off leaves
        the estimates where the shrinking covariance froze them. ``extra["pass_moves"]``
        holds the largest move per pass in std, ``extra["not_settled"]`` the reason when
        they did not settle.
        """
        segments = [segments] if isinstance(segments, Segment) else list(segments)
        if not segments:
            raise ModelDefinitionError("fit() needs at least one segment")
        if not isinstance(estimate_x0, (bool, str)):
            bad = sorted(set(estimate_x0) - set(self.model.states))
            if bad:
                raise ModelDefinitionError(f"estimate_x0 names {bad} are not states {self.model.states}")
        lay = Layout.build(self.model, segments, False, values=start)
        F = process_noise_matrix(self.model, self.process_noise, segments)
        R = measurement_noise_matrix(self.model, self.measurement_noise, segments)
        adapt_r, adapt_q = self._adapted(F)
        passes = Passes()
        res = self._run_passes(segments, lay, F, R, (adapt_r, adapt_q), passes)
        return self._finish(res, lay, passes, adapt_r, adapt_q)

    def _run_passes(
        self,
        segments: list[Segment],
        lay: Layout,
        F: np.ndarray,
        R: np.ndarray,
        adapt: tuple[bool, bool],
        passes: Passes,
    ) -> EstimationResult:
        """The filter passes from the start values in ``lay`` (updated to each pass's
        estimates), with the noise adapted between passes as ``adapt`` (R, Q) says; the
        result of the last pass, or of the best one when a later pass left it."""
        adapt_r, adapt_q = adapt
        fi = lay.free_idx
        n_max = self.max_passes if self.passes == "auto" else self.passes
        moves = passes.moves
        best: tuple[float, int, EstimationResult, np.ndarray] | None = None
        for k in range(n_max):
            before = lay.values[fi].copy()
            res, match = self._one_pass(segments, lay, F, R, adapt_r or adapt_q)
            nll, n_obs = res.extra["innovation_nll"], res.extra["innovation_count"]
            if self.callback:
                self.callback(k, nll, pd.Series(res.values[fi], index=lay.free_names))
            # passes are compared by their innovations' likelihood unless the noise is
            # adapted (R and Q move between passes) or a parameter was projected onto a
            # bound (the projection leaves the filter's covariance inconsistent)
            comparable = not (adapt_r or adapt_q or res.extra["bound_hits"])
            band = 3.0 * np.sqrt(n_obs / 2)
            if comparable and best is not None and nll > best[0] + band:
                # the filter left the estimates: this pass's innovations are less likely than
                # the best pass's by more than 3 std of their negative log-likelihood (sum of
                # chi-square halves: std sqrt(n_obs / 2) when the filter is consistent); the
                # best pass is kept
                passes.left = (
                    f"pass {k + 1} raised the innovations' negative log-likelihood by "
                    f"{nll - best[0]:.4g} (> 3 std = {band:.4g}): the filter "
                    f"wandered off, the estimates of pass {best[1]} (the most likely) are kept; "
                    "check the process noise and the start values"
                )
                moves.append(np.inf)
                _, _, res, kept = best
                lay.values[fi] = kept
                break
            after = res.values[fi]
            std = np.sqrt(np.maximum(np.diag(res.cov), 0.0))
            move = np.abs(after - before) / np.where(std > 0, std, np.inf)
            moves.append(float(move.max(initial=0.0)))
            passes.history += [{"pass": k + 1, **row} for row in res.history.to_dict("records")]
            lay.values[fi] = after
            if comparable and (best is None or nll < best[0]):
                best = (nll, k + 1, res, after.copy())
            if adapt_r or adapt_q:
                F, R, nm = matched_noise(F, R, match, adapt_r, adapt_q)
                passes.noise_moves.append(nm)
            if self.passes == "auto" and moves[-1] <= self.pass_tol:
                break
        return res

    def _finish(
        self, res: EstimationResult, lay: Layout, passes: Passes, adapt_r: bool, adapt_q: bool
    ) -> EstimationResult:
        """The fit's result from its last pass's: parameters held by a bound, the passes'
        history, whether they settled, and the message saying so."""
        moves, left = passes.moves, passes.left
        settled = not left and (self.passes != "auto" or moves[-1] <= self.pass_tol)
        n_done = len(moves)
        at_bounds, cov = self._bounds_held(res, lay)
        extra = {"pass_moves": moves}
        adapted = [w for w, on in (("measurement_noise", adapt_r), ("process_noise", adapt_q)) if on]
        what = f"{n_done} filter pass{'es' if n_done > 1 else ''}"
        if adapted:
            # extra's noise is the one the last pass ran with; the adaptation's relative
            # moves per pass
            extra.update(noise_moves=passes.noise_moves, adapted=adapted)
            what += f"; {' and '.join(w.replace('_', ' ') for w in adapted)} adapted"
        if left:
            extra["not_settled"] = left
        elif not settled:
            extra["not_settled"] = (
                f"the last of {n_done} passes still moved a parameter by {moves[-1]:.2g} std "
                f"(> {self.pass_tol:g}): raise max_passes, start closer or check the model"
            )
        if "not_settled" in extra:
            what += "; not settled: " + extra["not_settled"]
        if at_bounds:
            what += f"; at a bound (std NaN): {', '.join(at_bounds)}"
        return res.replace(
            history=pd.DataFrame(passes.history),
            iterations=n_done,
            converged=settled,
            at_bounds=at_bounds,
            cov=cov,
            covariances={},
            extra={**res.extra, **extra},
            message=what + "; residuals are the innovations (a-priori)",
        )

    @staticmethod
    def _bounds_held(res: EstimationResult, lay: Layout) -> tuple[list[str], np.ndarray]:
        """Free parameters held by a bound: projected onto it during the last pass
        (``extra["bound_hits"]``: updates per parameter) and ending within 3 std of it, and
        the covariance with their rows and columns NaN: as in output error, the bound, not
        the data, holds them there."""
        fi = lay.free_idx
        v, lo, hi = res.values[fi], lay.lower[fi], lay.upper[fi]
        sd = np.sqrt(np.maximum(np.diag(res.cov), 0.0))
        hit = np.array([n in res.extra.get("bound_hits", {}) for n in lay.free_names], dtype=bool)
        on = hit & ((v - lo <= 3.0 * sd) | (hi - v <= 3.0 * sd))
        if not np.any(on):
            return [], res.cov
        cov = res.cov.copy()
        cov[on, :] = np.nan
        cov[:, on] = np.nan
        return [lay.free_names[i] for i in np.flatnonzero(on)], cov

    # one filter pass -----------------------------------------------------------------------
    def _one_pass(
        self, segments: list[Segment], lay: Layout, F: np.ndarray, R: np.ndarray, matching: bool = False
    ) -> tuple[EstimationResult, NoiseMatch | None]:
        """One pass of the filter over the segments from the start values in ``lay``, with
        process noise F (n, n) and measurement-noise covariance R (n_out, n_out): the
        pass's result and, with ``matching``, its covariance-matching sums (else None)."""
        model = self.model
        fi = lay.free_idx
        n, m = len(model.states), fi.size
        theta = lay.values[fi].copy()
        Pth = self._initial_param_cov(lay)
        qth = self._param_noise(lay) ** 2
        rec = PassRecord(hits=np.zeros(m, dtype=int))
        match = NoiseMatch(n, R.shape[0]) if matching else None
        before = information_form(Pth, theta)
        for k, seg in enumerate(segments):
            aug = AugmentedModel(model, lay, seg, k, self.integrator, self.rtol, self.atol, self.inputs)
            x0 = lay.values[lay.x0idx[k]]
            s = np.concatenate([x0, theta])
            P = np.zeros((n + m, n + m))
            P[:n, :n] = self._initial_state_cov(R, aug, s, F)
            P[n:, n:] = Pth
            run = self._run_segment(SegmentStart(aug, s, P, F, R, qth, match))
            if run.fail >= 0:
                raise SimulationDivergedError(
                    f"the {self.method.upper()} prediction of segment {seg.name or k} became "
                    f"non-finite at t={seg.t[run.fail]:.4g} s: reduce param_std/state_std, "
                    "start closer, or use a smaller sample interval",
                    segment=k,
                    time=float(seg.t[run.fail]),
                )
            rec.nll, rec.n_obs, rec.hits = rec.nll + run.nll, rec.n_obs + run.n_obs, rec.hits + run.hits
            rec.K = rec.K if run.K is None else run.K
            theta = run.s[n:].copy()
            Pth = run.P[n:, n:].copy()
            after = information_form(Pth, theta)
            rec.info.append((after[0] - before[0], after[1] - before[1]))
            before = after  # the next segment starts where this one ended
            rec.add(seg, run, aug, lay, model)
            rec.history.append({"segment": k, **dict(zip(lay.free_names, theta))})
        return self._pass_result(segments, lay, theta, Pth, F, R, rec), match

    def _pass_result(
        self,
        segments: list[Segment],
        lay: Layout,
        theta: np.ndarray,
        Pth: np.ndarray,
        F: np.ndarray,
        R: np.ndarray,
        rec: PassRecord,
    ) -> EstimationResult:
        """The result of one pass ending with the free parameters theta (m,) of covariance
        Pth (m, m), run with the noise F, R."""
        model = self.model
        fi = lay.free_idx
        values = lay.values.copy()
        values[fi] = theta
        free = lay.free.copy()
        E = rec.innov
        Rinn = st.residual_covariance(E, full=False)
        hits = rec.hits
        return EstimationResult(
            method=self.method,
            model=model,
            names=list(lay.names),
            values=values,
            free=free,
            cov=0.5 * (Pth + Pth.T),
            R=Rinn,
            converged=True,
            iterations=1,
            history=pd.DataFrame(rec.history),
            segments=segments,
            predicted=frames([s.t for s in segments], rec.pred, model.outputs),
            residuals=frames([s.t for s in segments], E, model.outputs),
            message="one filter pass; residuals are the innovations (a-priori)",
            settings=self._settings(),
            cov_type="filter-covariance",
            extra={
                "trajectory": rec.traj,
                "trajectory_std": rec.traj_std,
                "states": rec.states,
                "posterior_outputs": rec.post,
                "gain": rec.K,
                "measurement_noise": R,
                "process_noise": F,
                "residuals_are": "innovations",
                "innovation_nll": rec.nll,
                "innovation_count": rec.n_obs,
                "cluster": segment_scatter(rec.info, Pth, theta, lay.free_names),
                "bound_hits": {lay.free_names[j]: int(hits[j]) for j in np.flatnonzero(hits)},
            },
        )

    def _settings(self) -> dict[str, Any]:
        return {
            "integrator": self.integrator,
            "optimizer": "recursive",
            "inputs": self.inputs,
            "passes": self.passes,
            "max_passes": self.max_passes,
            "pass_tol": self.pass_tol,
            "adapt_noise": self.adapt_noise,
            "gain_sensitivity": self.gain_sensitivity,
        }

    # one segment of a pass -----------------------------------------------------------------
    def _run_segment(self, start: SegmentStart) -> SegmentRun:
        """One segment's run: compiled where the subclass has a compiled loop and the model
        compiles (Ljung's modification runs in Python only), else sample by sample."""
        run = self._compiled_segment(start) if self.compiled and not self.gain_sensitivity else None
        if run is None:
            run = self._python_segment(start)
        return run

    def _python_segment(self, start: SegmentStart) -> SegmentRun:
        """One segment's pass, sample by sample with :meth:`_predict` / :meth:`_update`; the
        covariance-matching sums go into ``start.match``."""
        aug, s, P, F, R, qth, match = start.aug, start.s, start.P, start.F, start.R, start.qth, start.match
        lo, hi = aug.lay.lower[aug.fi], aug.lay.upper[aug.fi]
        n, seg = aug.n, aug.seg
        L, N = s.size, seg.n
        Ypred = np.full((N, len(self.model.outputs)), np.nan)
        Spost = np.empty((N, L))
        Pdiag = np.empty((N, L))
        hits = np.zeros(L - n, dtype=int)
        K, nll, n_obs = None, 0.0, 0
        sens = GainSensitivity(n, s, P[:n, :n], self.gain_step, 1e-6) if self.gain_sensitivity and L > n else None
        for i in range(N):
            if i > 0:
                h = seg.t[i] - seg.t[i - 1]
                Q = np.zeros((L, L))
                Q[:n, :n] = F @ F.T * h
                Q[n:, n:] = np.diag(qth * h)
                if sens is not None:
                    sens.predict(aug, s, Q[:n, :n], i - 1)
                s, P = self._predict(aug, s, P, Q, i - 1)
                if not np.all(np.isfinite(s)) or not np.all(np.isfinite(P)):
                    return SegmentRun(s, P, Ypred, Spost, Pdiag, K, nll, n_obs, hits, i)
            z = seg.z[i]
            ok = np.isfinite(z)
            s_prior = s
            s, P, yp, Ki, Sinn = self._update(aug, s, P, z, ok, R, i)
            if sens is not None and Sinn is not None:
                P = sens.apply(P, sens.update(aug, s_prior, ok, R, z[ok] - yp[ok], i), n)
            th = np.clip(s[n:], lo, hi)  # bounds: the estimate projected on them
            hits += th != s[n:]
            s[n:] = th
            if Sinn is not None:  # some output measured (K too)
                K = Ki
                nu = z[ok] - yp[ok]
                nll += innovation_nll(nu, Sinn)
                n_obs += nu.size
                if match is not None:
                    match.add(nu, Sinn, Ki[:n], R, ok, seg.t[i] - seg.t[i - 1] if i else 0.0)
            Ypred[i] = yp
            Spost[i] = s
            Pdiag[i] = np.diag(P)
        return SegmentRun(s, P, Ypred, Spost, Pdiag, K, nll, n_obs, hits, -1)

    def _compiled_segment(self, start: SegmentStart) -> SegmentRun | None:
        """:meth:`_python_segment` in compiled code (:func:`estimators.filters.loops.ekf_segment`,
        :func:`~estimators.filters.loops.ukf_segment`), or None where there is none: the
        Python loop runs."""
        return None

    # filter equations, per subclass
    def _predict(self, aug, s, P, Q, i):  # pragma: no cover - abstract
        raise NotImplementedError

    def _update(self, aug, s, P, z, ok, R, i):  # pragma: no cover - abstract
        """Measurement update at sample i: (s, P, predicted outputs, gain K (n+m, n_ok),
        innovation covariance (n_ok, n_ok)); K and S None when no output is finite."""
        raise NotImplementedError
