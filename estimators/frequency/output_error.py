"""Output error in the frequency domain on an estimators Model (Klein & Morelli, *Aircraft
System Identification*, 2006, ch. 7).

The model is linearised about a reference point (x_ref, u_ref; default zeros, exact for
linear f and g): x' = A x + B u, y = C x + D u. The measured inputs and outputs of each
segment are transformed once (:func:`~estimators.frequency.transform.fourier_transform`) at
the frequencies w, and the fit works on n_f << N complex numbers per channel:

    v_k = Z(w_k) - [C (j w_k I - A)^-1 B + D] U(w_k)
    S = (1/n_f) sum_k v_k v_k^H            (re-estimated each iteration)
    cost = 1/2 sum_k v_k^H S^-1 v_k        (complex-Gaussian maximum likelihood)
    M = sum_k Re(dv_k^H S^-1 dv_k)         (Cramér-Rao bounds: the "crb" covariance)

The reference implementation weights with the conjugate of S, which is the same for one
output but not the likelihood for several (up to 30 % more scatter under correlated
noise). Trim values, biases and initial conditions drop out of the band once the ends are
detrended, so a per-segment parameter is held at its start and said so. The result also
carries the "sandwich" covariance measured from the residuals
(:mod:`estimators.frequency.covariance`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from estimators.covariance.cluster import ClusterResult, cluster_covariance
from estimators.errors import ModelDefinitionError
from estimators.filters.linearize import linearize_batch
from estimators.frequency.covariance import frequency_covariances
from estimators.frequency.transform import fourier_transform
from estimators.model import Model, Segment
from estimators.results import EstimationResult

#: iterations, and the relative change of det(S) or the step (in std) that end them
MAX_ITER = 50
DET_RTOL = 1e-8
STEP_STD_TOL = 1e-3
#: the residuals' weighting: the complex-Gaussian likelihood's S^-1, or the reference's conj(S)^-1
WEIGHTINGS = ("likelihood", "conjugate")
#: relative step of the parameter sensitivities (central differences)
PARAM_STEP = 1e-5
#: a parameter whose sensitivity is below this fraction of the largest is not in the band
NULL_SENSITIVITY = 1e-9


class FrequencyOutputError:
    """Frequency-domain output error (module docstring).

    model : the Model (its linearisation is fitted).
    w : (n_f,) frequencies (rad/s), the same for every segment.
    detrend : of the transforms ("ends", "linear", "none").
    weighting : "likelihood" (S^-1, default) or "conjugate" (conj(S)^-1, the reference
        implementation's; for comparison).
    x_ref, u_ref : the linearisation point (default zeros); x_ref="initial" linearises
        each segment about its own initial state and first input sample (a nonlinear
        model flown from several trims).
    """

    method = "fdoe"

    def __init__(
        self,
        model: Model,
        w: np.ndarray,
        detrend: str = "ends",
        x_ref: Sequence[float] | None = None,
        u_ref: Sequence[float] | None = None,
        max_iter: int = MAX_ITER,
        weighting: str = "likelihood",
    ) -> None:
        self.model = model
        self.w = np.asarray(w, dtype=float).ravel()
        if self.w.size == 0 or not np.all(np.isfinite(self.w)):
            raise ModelDefinitionError("FrequencyOutputError needs finite frequencies w (rad/s)")
        self.detrend = detrend
        n, m = len(model.states), len(model.inputs)
        self.per_segment = isinstance(x_ref, str)
        if self.per_segment and x_ref != "initial":
            raise ModelDefinitionError(f"x_ref={x_ref!r}: give values or 'initial'")
        self.x_ref = np.zeros(n) if x_ref is None or self.per_segment else np.asarray(x_ref, dtype=float).ravel()
        self.u_ref = np.zeros(m) if u_ref is None else np.asarray(u_ref, dtype=float).ravel()
        if self.x_ref.size != n or self.u_ref.size != m:
            raise ModelDefinitionError(f"x_ref needs {n} values {model.states}, u_ref {m} {model.inputs}")
        self.max_iter = int(max_iter)
        if weighting not in WEIGHTINGS:
            raise ModelDefinitionError(f"weighting={weighting!r}: use one of {', '.join(WEIGHTINGS)}")
        self.weighting = weighting

    # -- the model's response ----------------------------------------------------------------
    def responses(
        self,
        P: np.ndarray,
        constants: Mapping[str, float],
        x_ref: np.ndarray | None = None,
        u_ref: np.ndarray | None = None,
    ) -> np.ndarray:
        """H (B, n_f, n_y, n_u) of the parameter columns P (n_p, B), linearised about
        (x_ref, u_ref) (default this object's)."""
        Bc = P.shape[1]
        xr = np.repeat((self.x_ref if x_ref is None else x_ref)[:, None], Bc, axis=1)
        ur = self.u_ref if u_ref is None else u_ref
        A, Bu, C, D, _, _ = linearize_batch(self.model, P, xr, ur, constants)
        n = A.shape[1]
        jw = 1j * self.w[None, :, None, None] * np.eye(n)[None, None]
        X = np.linalg.solve(jw - A[:, None], np.broadcast_to(Bu[:, None], (Bc, self.w.size, *Bu.shape[1:])))
        return np.einsum("byn,bfnu->bfyu", C, X) + D[:, None]

    def fit(self, segments: Segment | Sequence[Segment], start: Mapping[str, float] | None = None) -> EstimationResult:
        """Estimate the free shared parameters from ``segments`` (uniformly sampled, complete
        outputs), starting from the model's values or ``start``."""
        segs = [segments] if isinstance(segments, Segment) else list(segments)
        data = self._transformed(segs)
        model, names = self.model, self.model.parameter_names
        theta = np.array([float((start or {}).get(p.name, p.value)) for p in model.parameters])
        shared = np.array([not p.per_segment for p in model.parameters])
        free = np.array([p.free for p in model.parameters]) & shared
        bounds = np.array([p.bounds for p in model.parameters], dtype=float).reshape(-1, 2)
        notes = []
        if np.any(~shared):
            notes.append(
                "per-segment parameters held at their start (they drop out of the band): "
                + ", ".join(n for n, s in zip(names, shared) if not s)
            )
        idx = np.flatnonzero(free)
        v, J = data.residuals(theta, idx)
        norms = np.sqrt(np.sum(np.abs(J) ** 2, axis=(0, 1)))
        null = norms <= NULL_SENSITIVITY * max(norms.max(initial=0.0), 1e-300)
        if np.any(null):
            notes.append("not in the band (no sensitivity), held: " + ", ".join(names[i] for i in idx[null]))
            free[idx[null]] = False
        idx = np.flatnonzero(free)
        if idx.size == 0:
            raise ModelDefinitionError("FrequencyOutputError: no free parameter moves the model's response")
        theta, v, J, converged, history = self._iterate(data, theta, idx, bounds, (v, J[:, :, ~null]))
        if not converged:
            notes.append(f"stopped at max_iter={self.max_iter}")
        return self._result(segs, data, theta, idx, free, shared, bounds, v, J, converged, history, notes)

    def _transformed(self, segs: list[Segment]) -> _Transformed:
        """The segments' input and output transforms, constants and linearisation points."""
        if not segs:
            raise ModelDefinitionError("fit() needs at least one segment")
        model = self.model
        for s in segs:
            s.check_against(model)
            if not np.all(np.isfinite(s.z)):
                raise ModelDefinitionError(
                    f"segment {s.name!r}: the outputs have missing samples; the frequency domain needs complete records"
                )
        refs = (
            [(s.initial_state(model), s.u[0].astype(float)) for s in segs]
            if self.per_segment
            else [(self.x_ref, self.u_ref)] * len(segs)
        )
        return _Transformed(
            self,
            [fourier_transform(s.t, s.u, self.w, self.detrend) for s in segs],
            [fourier_transform(s.t, s.z, self.w, self.detrend) for s in segs],
            [model.constants_for(s) for s in segs],
            refs,
        )

    def _iterate(
        self,
        data: _Transformed,
        theta: np.ndarray,
        idx: np.ndarray,
        bounds: np.ndarray,
        first: tuple[np.ndarray, np.ndarray],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool, list[dict]]:
        """Gauss-Newton on the free parameters ``idx`` with S re-estimated each iteration
        and step halving, projected onto the bounds; (theta, v, J, converged, history)."""
        names = self.model.parameter_names
        lo, hi = bounds[idx, 0], bounds[idx, 1]
        v, J = first
        history: list[dict] = []
        det_old = np.inf
        for it in range(1, self.max_iter + 1):
            S = (v.T @ v.conj()) / v.shape[0]  # sum_k v_k v_k^H / n_f
            Si = self._weight(S)
            det = float(np.real(np.linalg.det(S)))

            def cost(vv: np.ndarray, Si=Si) -> float:
                return 0.5 * float(np.real(np.einsum("fy,yz,fz->", vv.conj(), Si, vv)))

            M = np.real(np.einsum("fyp,yz,fzq->pq", J.conj(), Si, J))
            step = -np.linalg.lstsq(M, np.real(np.einsum("fyp,yz,fz->p", J.conj(), Si, v)), rcond=None)[0]
            c0, alpha = cost(v), 1.0
            history.append({"iteration": it, "det_S": det, "cost": c0, **{names[i]: theta[i] for i in idx}})
            settled = abs(det_old - det) <= DET_RTOL * abs(det)
            if settled or np.all(np.abs(step) <= STEP_STD_TOL * np.sqrt(np.abs(np.diag(np.linalg.pinv(M))))):
                return theta, v, J, True, history
            det_old = det
            while True:
                trial = theta.copy()
                trial[idx] = np.clip(theta[idx] + alpha * step, lo, hi)
                v_t, J_t = data.residuals(trial, idx)
                if cost(v_t) <= c0 or alpha < 1e-4:
                    break
                alpha /= 2
            theta, v, J = trial, v_t, J_t
        return theta, v, J, False, history

    def _result(
        self,
        segs: list[Segment],
        data: _Transformed,
        theta: np.ndarray,
        idx: np.ndarray,
        free: np.ndarray,
        shared: np.ndarray,
        bounds: np.ndarray,
        v: np.ndarray,
        J: np.ndarray,
        converged: bool,
        history: list[dict],
        notes: list[str],
    ) -> EstimationResult:
        """The result: covariance views ("crb", "sandwich"; NaN for a parameter on a bound),
        the maneuvers' scatter, predictions and residuals per segment on f (Hz)."""
        model, names = self.model, self.model.parameter_names
        S = (v.T @ v.conj()) / v.shape[0]
        Si = self._weight(S)
        covs = frequency_covariances(J, v, Si)
        cluster = self._maneuver_scatter(J, v, Si, len(segs), [names[i] for i in idx])
        on = (theta[idx] <= bounds[idx, 0]) | (theta[idx] >= bounds[idx, 1])
        for k in covs if np.any(on) else ():
            covs[k] = covs[k].copy()
            covs[k][on, :] = np.nan
            covs[k][:, on] = np.nan
        f = pd.Index(self.w / (2 * np.pi), name="f_hz")
        parts = np.split(v, len(segs))
        return EstimationResult(
            method=self.method,
            model=model,
            names=self._expanded(names, shared, len(segs)),
            values=self._expanded_values(theta, shared, len(segs)),
            free=self._expanded_values(free.astype(float), shared, len(segs)).astype(bool),
            cov=covs["crb"],
            covariances=covs,
            R=np.real(S),
            converged=converged,
            iterations=len(history),
            history=pd.DataFrame(history),
            predicted=[pd.DataFrame(Zf - vv, index=f, columns=model.outputs) for Zf, vv in zip(data.Z, parts)],
            residuals=[pd.DataFrame(vv, index=f, columns=model.outputs) for vv in parts],
            segments=segs,
            at_bounds=[names[i] for i in idx[on]],
            message="; ".join(notes),
            settings={"detrend": self.detrend, "n_frequencies": int(self.w.size), "domain": "frequency"},
            extra={
                "w": self.w,
                "S": S,
                "U_f": data.U,
                "Z_f": data.Z,
                "x_ref": self.x_ref,
                "u_ref": self.u_ref,
                **({"cluster": cluster} if cluster is not None else {}),
            },
        )

    def _weight(self, S: np.ndarray) -> np.ndarray:
        """The residuals' weighting matrix: S^-1, or conj(S)^-1 (the reference's)."""
        return np.linalg.pinv(S if self.weighting == "likelihood" else S.conj(), hermitian=True)

    def _maneuver_scatter(
        self, J: np.ndarray, v: np.ndarray, Si: np.ndarray, n_seg: int, names: list[str]
    ) -> ClusterResult | None:
        """The maneuver-cluster covariance (:func:`estimators.covariance.cluster.cluster_covariance`)
        from each segment's information and score over its frequencies: how much the
        maneuvers disagree beyond the bounds (None for one segment or a singular one)."""
        if n_seg < 2:
            return None
        nf = self.w.size
        M_parts, scores = [], []
        for k in range(n_seg):
            Jk, vk = J[k * nf : (k + 1) * nf], v[k * nf : (k + 1) * nf]
            M_parts.append(np.real(np.einsum("fyp,yz,fzq->pq", Jk.conj(), Si, Jk)))
            scores.append(np.real(np.einsum("fyp,yz,fz->p", Jk.conj(), Si, vk)))
        try:
            return cluster_covariance(M_parts, scores, names=names)
        except (ValueError, np.linalg.LinAlgError):
            return None

    @staticmethod
    def _expanded(names: list[str], shared: np.ndarray, n_seg: int) -> list[str]:
        out = []
        for n, s in zip(names, shared):
            out += [n] if s else [f"{n}[{k}]" for k in range(n_seg)]
        return out

    @staticmethod
    def _expanded_values(values: np.ndarray, shared: np.ndarray, n_seg: int) -> np.ndarray:
        out = []
        for v, s in zip(values, shared):
            out += [v] if s else [v] * n_seg
        return np.asarray(out, dtype=float)


@dataclass(frozen=True)
class _Transformed:
    """The segments of one fit in the frequency domain: the inputs' and outputs'
    transforms U, Z (per segment (n_f, n_u), (n_f, n_y)), their constants and
    linearisation points (x_ref, u_ref)."""

    fdoe: FrequencyOutputError
    U: list[np.ndarray]
    Z: list[np.ndarray]
    constants: list[Mapping[str, float]]
    refs: list[tuple[np.ndarray, np.ndarray]]

    def residuals(self, theta: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """v (n_tot, n_y) at theta, and dv/dtheta (n_tot, n_y, len(idx)) by central
        differences, every parameter column in one linearisation per segment."""
        h = PARAM_STEP * np.maximum(np.abs(theta[idx]), 1e-3)
        P = np.repeat(theta[:, None], 1 + 2 * idx.size, axis=1)
        P[idx, 1 + np.arange(idx.size)] += h
        P[idx, 1 + idx.size + np.arange(idx.size)] -= h
        vs, Js = [], []
        for Uf, Zf, c, (xr, ur) in zip(self.U, self.Z, self.constants, self.refs):
            H = self.fdoe.responses(P, c, xr, ur)  # (B, n_f, n_y, n_u)
            V = Zf[None] - np.einsum("bfyu,fu->bfy", H, Uf)
            vs.append(V[0])
            Js.append((V[1 : 1 + idx.size] - V[1 + idx.size :]).transpose(1, 2, 0) / (2 * h))
        return np.concatenate(vs), np.concatenate(Js)
