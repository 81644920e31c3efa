"""Output error for unstable aircraft: stabilised output error, eigenvalue transformation,
equation decoupling.

A plain output-error simulation of an unstable model grows without bound (and
:class:`~estimators.OutputError` stops with SimulationDivergedError). Each method here
turns the problem into a bounded one and then runs the ordinary output-error machinery
(Gauss-Newton, bounds, priors, Cramér-Rao bounds) on a transformed model, so all of
OEM's options apply (``**oem_options`` go to :class:`~estimators.OutputError`):

* :class:`StabilizedOutputError` - the simulation is pulled towards the measurements,
  x' = f(x, u) + S (z - g(x, u)), with a stabilisation matrix S (n_states x n_outputs,
  per second). This is the continuous form of the sample-wise correction
  x <- x + S_d (z - y) with S_d = S h. Default S: the smallest stabilising gain, the
  Kalman gain of the start model linearised about the trim point with vanishing process
  noise (it mirrors the unstable eigenvalues into the left half plane and leaves stable
  ones alone), using only the outputs that measure states.
* :class:`EigenvalueTransformation` - data and model are weighted by exp(-sigma t):
  z~ = z e^{-sigma t}, u~ = u e^{-sigma t}, and the model matrix is shifted to
  A - sigma I (f~ = f(x~, u~) - sigma x~, with the affine part f(0, 0) and g(0, 0) scaled
  by e^{-sigma t} as well), so the transformed system is stable for sigma above the
  largest real part of the eigenvalues. Exact for linear (affine) models. Default
  sigma: the largest real eigenvalue part of the linearised start model plus 0.5 1/s.
  The predictions and residuals in the result are those of the transformed (weighted)
  problem (``extra["weights"]`` holds e^{-sigma t}). The weighted residuals have a
  variance falling as e^{-2 sigma t} while output error fits one R, so the reported std
  are the heteroscedasticity-consistent (sandwich) ones; the plain Cramér-Rao
  covariance stays a view of the result (``cov_of("crb")``).
* :class:`EquationDecoupling` - every state equation integrates only its own state; the
  other states that are measured enter it as pseudo-inputs (the measurements), so each
  equation is as stable as its diagonal term (e.g. Z_alpha, M_q for the short period).

Measurements used as pseudo-inputs follow the integrators' input convention (averaged
over each step); missing samples (NaN) in them are filled by linear interpolation.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy import linalg, signal

from estimators import statistics as st
from estimators.compile import kernel_for
from estimators.covariance.uncertainty import morelli_klein
from estimators.defaults import SIGMA_MARGIN, STABILIZER_Q_SCALES
from estimators.errors import ModelDefinitionError
from estimators.filters.linearize import linearize_batch
from estimators.layout import Layout
from estimators.model import Model, Segment
from estimators.output_error.oem import OutputError
from estimators.output_error.pseudo_input_noise import PropagationError, propagated_covariance
from estimators.results import EstimationResult
from estimators.sensitivity import add_block, as_sensitivity


def _fill(z: np.ndarray, t: np.ndarray) -> np.ndarray:
    z = np.array(z, dtype=float)
    for j in range(z.shape[1]):
        ok = np.isfinite(z[:, j])
        if not np.all(ok):
            if not np.any(ok):
                raise ModelDefinitionError("a pseudo-input channel has no valid samples")
            z[:, j] = np.interp(t, t[ok], z[ok, j])
    return z


def _numpy_only(model: Model) -> Model:
    """The transformed models call the user's Python f/g from inside f; they run on the
    integrators' numpy path (no numba compile attempt, no warning)."""
    kernel_for(model)._jit_state = "off"
    return model


def _g_with_biases(model: Model, x, u, p, c) -> list:
    """Rows of g plus the automatic per-segment output biases (as Model.eval_g adds them)."""
    rows = list(model.g(x, u, p, c))
    for o in model.output_biases:
        i = model.outputs.index(o)
        rows[i] = rows[i] + getattr(p, f"bias_{o}")
    return rows


def _on_free(cov: np.ndarray, inner: np.ndarray, C: np.ndarray) -> np.ndarray:
    """A covariance shaped as ``cov`` holding C on the rows/columns ``inner`` (the free
    parameters with a finite bound), NaN elsewhere."""
    out = np.full_like(cov, np.nan)
    out[np.ix_(inner, inner)] = C
    return out


def _linearisation(model: Model, segments: Sequence[Segment], start: Mapping[str, float] | None):
    lay = Layout.build(model, segments[:1], values=start)
    P = lay.values[lay.pidx[0]][:, None]
    x0 = lay.values[lay.x0idx[0]][:, None]
    A, B, C, D, _, _ = linearize_batch(model, P, x0, segments[0].u[0], model.constants_for(segments[0]))
    return A[0], C[0]


STD_METHODS = ("propagated", "morelli-klein", "crb")


class _TransformedOEM:
    method = "oem"

    def __init__(self, model: Model, integrator: str = "rk4", std: str = "propagated", **oem_options) -> None:
        if std not in STD_METHODS:
            raise ModelDefinitionError(f"std must be one of {', '.join(STD_METHODS)}, not {std!r}")
        self.model = model
        self.integrator = integrator
        self.std_method = std
        self.oem_options = oem_options

    def _transform(self, segments: list[Segment], start) -> tuple[Model, list[Segment], dict]:
        raise NotImplementedError  # pragma: no cover

    def fit(
        self,
        segments: Segment | Sequence[Segment],
        estimate_x0: bool | Sequence[str] = False,
        R: np.ndarray | None = None,
        start: Mapping[str, float] | None = None,
    ) -> EstimationResult:
        """As :meth:`OutputError.fit`, on the transformed (bounded) problem."""
        segments = [segments] if isinstance(segments, Segment) else list(segments)
        if not segments:
            raise ModelDefinitionError("fit() needs at least one segment")
        for s in segments:
            s.check_against(self.model)
        model_t, segs_t, info = self._transform(segments, start)
        oem = OutputError(model_t, self.integrator, **self.oem_options)
        oem._check_follow = False  # its note would recommend these methods themselves
        res = oem.fit(segs_t, estimate_x0=estimate_x0, R=R, start=start)
        if info.get("pseudo_outputs"):
            res = self._fed_measurement_std(res, model_t, segs_t, info)
        res = res.replace(
            method=self.method,
            model=self.model,
            segments=segments,
            settings={**res.settings, **{k: v for k, v in info.items() if isinstance(v, (str, int, float, bool))}},
            extra={**res.extra, **{k: v for k, v in info.items() if k != "pseudo"}},
        )
        return self._finish(res)

    def _finish(self, res: EstimationResult) -> EstimationResult:
        return res

    def _fed_measurement_std(
        self, res: EstimationResult, model_t: Model, segs_t: list[Segment], info: dict
    ) -> EstimationResult:
        """Report instead of the Cramér-Rao covariance, which assumes white residuals, one that
        carries the measurement noise fed back through the pseudo-inputs: ``std`` =
        "propagated" (:mod:`estimators.output_error.pseudo_input_noise`; falls back to Morelli-Klein when
        the pseudo-inputs are smoothed or the fed model diverges over a segment),
        "morelli-klein" (coloured residuals, all lags, Bartlett window) or "crb" (kept).
        The Cramér-Rao covariance stays a view ("crb")."""
        inner = np.flatnonzero(np.isfinite(np.diag(res.cov)))
        if self.std_method == "crb" or res.sensitivities is None or not inner.size:
            return res
        S = [as_sensitivity(s).take(inner) for s in res.sensitivities]
        E = [r.to_numpy() for r in res.residuals]
        M = res.information[np.ix_(inner, inner)]
        W = res.extra.get("prior_information")
        W = None if W is None else W[np.ix_(inner, inner)]
        how, why = self.std_method, ""
        if how == "propagated" and info.get("smooth_hz"):
            how, why = "morelli-klein", " (smoothed pseudo-inputs are not propagated)"
        if how == "propagated":
            try:
                C, s2 = propagated_covariance(
                    model_t,
                    segs_t,
                    res.params.to_dict(),
                    S,
                    E,
                    res.R,
                    M,
                    info["pseudo_outputs"],
                    info.get("pseudo"),
                    prior_info=W,
                )
                res = res.with_extra(noise_std=dict(zip(model_t.outputs, np.sqrt(s2).tolist())))
                note = "std: measurement noise propagated through the fed-back measurements"
            except PropagationError as exc:
                how, why = "morelli-klein", f" ({exc})"
        if how == "morelli-klein":
            C = morelli_klein(S, E, R=res.R, info=M, max_lag=None, prior_info=W).cov
            note = "std: Morelli-Klein (coloured residuals from the fed-back measurements)" + why
        return res.with_cov(_on_free(res.cov, inner, C), how, note)


class StabilizedOutputError(_TransformedOEM):
    """Stabilised output error: x' = f(x, u) + S (z - g(x, u)).

    S : (n_states, n_outputs) stabilisation matrix in 1/s, {state: {output: gain}}, or None
        for the default (see module docstring). Outputs without a gain are not fed back.
    std : the reported covariance (the Cramér-Rao one stays a view, ``cov_of("crb")``):
        "propagated" (default) carries the measurement noise fed back into the model
        (:mod:`estimators.output_error.pseudo_input_noise`; the noise std it finds per output in
        ``extra["noise_std"]``), falling back to "morelli-klein" (coloured residuals,
        all lags) when the fed model diverges over a segment; "crb" keeps the
        Cramér-Rao bounds, which assume white residuals and are several times too small
        here.
    integrator, **oem_options : as :class:`~estimators.OutputError`.
    """

    method = "oem-stabilized"

    def __init__(
        self,
        model: Model,
        S: Any = None,
        integrator: str = "rk4",
        feedback: Sequence[str] | None = None,
        std: str = "propagated",
        **oem_options,
    ) -> None:
        super().__init__(model, integrator, std, **oem_options)
        self.S = S
        self.feedback = None if feedback is None else list(feedback)

    def default_S(self, segments: Sequence[Segment], start=None) -> np.ndarray:
        """The default S; ``feedback`` (constructor) limits it to the measurements of those
        states (e.g. alpha and q for a short-period instability: feeding back the noisy
        airspeed and attitude too ties the drag and lift terms to the measurements)."""
        m = self.model
        A, C = _linearisation(m, segments, start)
        meas = [j for j, o in enumerate(m.outputs) if o in m.states and (self.feedback is None or o in self.feedback)]
        if not meas:
            raise ModelDefinitionError("no output measures a state: give S explicitly")
        Cm = C[meas]
        z = np.concatenate([s.z[:, meas] for s in segments])
        Rm = np.diag(np.maximum(0.5 * np.nanvar(np.diff(z, axis=0), axis=0), 1e-12))
        n = A.shape[0]
        # vanishing process noise; when the Riccati solver reports the pencil too
        # ill-conditioned for so small a Q (seen with a phugoid near the imaginary axis next
        # to an unstable short period), raise Q by decades until it solves
        P = None
        for scale in STABILIZER_Q_SCALES:
            Q = scale * np.eye(n) * max(float(np.max(np.abs(Rm))), 1e-12)
            try:
                P = linalg.solve_continuous_are(A.T, Cm.T, Q, Rm)
                break
            except (ValueError, np.linalg.LinAlgError):
                continue
        if P is None:
            raise ModelDefinitionError(
                "no stabilising S from the linearised start model (the Riccati equation has no solution): give S explicitly"
            )
        S = np.zeros((n, len(m.outputs)))
        S[:, meas] = P @ Cm.T @ np.linalg.inv(Rm)
        return S

    def _matrix(self, segments, start) -> np.ndarray:
        m = self.model
        n, r = len(m.states), len(m.outputs)
        if self.S is None:
            return self.default_S(segments, start)
        if isinstance(self.S, Mapping):
            S = np.zeros((n, r))
            for s, row in self.S.items():
                if s not in m.states:
                    raise ModelDefinitionError(f"S: {s!r} is not a state {m.states}")
                for o, v in row.items():
                    if o not in m.outputs:
                        raise ModelDefinitionError(f"S: {o!r} is not an output {m.outputs}")
                    S[m.states.index(s), m.outputs.index(o)] = float(v)
            return S
        S = np.asarray(self.S, dtype=float)
        if S.shape != (n, r):
            raise ModelDefinitionError(f"S must be {n}x{r} (states x outputs), got {S.shape}")
        return S

    def _transform(self, segments, start):
        m = self.model
        S = self._matrix(segments, start)
        used = np.flatnonzero(np.any(S != 0, axis=0))
        ni, n = len(m.inputs), len(m.states)
        Su = S[:, used]

        def f(x, u, p, c):
            uu = u[:ni]
            zz = u[ni:]
            d = list(m.f(x, uu, p, c))
            y = _g_with_biases(m, x, uu, p, c)
            for i in range(n):
                for jj, j in enumerate(used):
                    if Su[i, jj] != 0.0:
                        d[i] = d[i] + Su[i, jj] * (zz[jj] - y[j])
            return tuple(d)

        mt = _numpy_only(
            Model(
                m.states,
                list(m.inputs) + [f"z_{m.outputs[j]}" for j in used],
                m.outputs,
                m.parameters,
                f,
                _g_of(m, ni),
                m.constants,
                [],
                m.name + " (stabilised)",
            )
        )
        segs = [
            Segment(
                t=s.t,
                u=np.column_stack([s.u, _fill(s.z[:, used], s.t)]),
                z=s.z,
                x0=s.x0,
                constants=s.constants,
                name=s.name,
            )
            for s in segments
        ]
        return mt, segs, {"S": S, "pseudo_outputs": [m.outputs[j] for j in used]}


def _g_of(m: Model, ni: int):
    """g of the original model on the leading ni inputs (pseudo-inputs dropped)."""

    def g(x, u, p, c):
        return _g_with_biases(m, x, u[:ni], p, c)

    return g


class EigenvalueTransformation(_TransformedOEM):
    """Output error on data and model weighted by exp(-sigma (t - t0)).

    sigma : shift in 1/s; None = largest real eigenvalue part of the linearised start
        model + SIGMA_MARGIN (0.5, see module docstring).
    """

    method = "oem-eigenvalue-transform"

    def __init__(self, model: Model, sigma: float | None = None, integrator: str = "rk4", **oem_options) -> None:
        super().__init__(model, integrator, **oem_options)
        self.sigma = sigma

    def default_sigma(self, segments, start=None) -> float:
        A, _ = _linearisation(self.model, segments, start)
        return max(float(np.max(np.linalg.eigvals(A).real)), 0.0) + SIGMA_MARGIN

    def _transform(self, segments, start):
        m = self.model
        sigma = float(self.sigma if self.sigma is not None else self.default_sigma(segments, start))
        ni, n = len(m.inputs), len(m.states)

        def zeros_like_rows(x, k):
            z = 0.0 * x[0]
            return [z] * k

        def f(x, u, p, c):
            uu = u[:ni]
            w = u[ni]
            d = list(m.f(x, uu, p, c))
            d0 = list(m.f(zeros_like_rows(x, n), zeros_like_rows(x, ni), p, c))
            return tuple(d[i] - sigma * x[i] - (1.0 - w) * d0[i] for i in range(n))

        def g(x, u, p, c):
            uu = u[:ni]
            w = u[ni]
            y = _g_with_biases(m, x, uu, p, c)
            y0 = _g_with_biases(m, zeros_like_rows(x, n), zeros_like_rows(x, ni), p, c)
            return tuple(y[j] - (1.0 - w) * y0[j] for j in range(len(y)))

        mt = _numpy_only(
            Model(
                m.states,
                list(m.inputs) + ["exp_weight"],
                m.outputs,
                m.parameters,
                f,
                g,
                m.constants,
                [],
                m.name + " (eigenvalue-transformed)",
            )
        )
        segs, weights = [], []
        for s in segments:
            wt = np.exp(-sigma * (s.t - s.t[0]))
            segs.append(
                Segment(
                    t=s.t,
                    u=np.column_stack([s.u * wt[:, None], wt]),
                    z=s.z * wt[:, None],
                    x0=s.x0,
                    constants=s.constants,
                    name=s.name,
                )
            )
            weights.append(wt)
        return mt, segs, {"sigma": sigma, "weights": weights}

    def _finish(self, res: EstimationResult) -> EstimationResult:
        """Replace the Cramér-Rao covariance (which assumes one R for residuals whose
        variance falls as exp(-2 sigma t)) by the heteroscedasticity-consistent one."""
        inner = np.flatnonzero(np.isfinite(np.diag(res.cov)))
        if res.sensitivities is not None and inner.size:
            S = [as_sensitivity(s).take(inner) for s in res.sensitivities]
            E = [r.to_numpy() for r in res.residuals]
            C = sandwich_covariance(S, E, res.R, res.information[np.ix_(inner, inner)])
            return res.with_cov(
                _on_free(res.cov, inner, C),
                "sandwich",
                "std: heteroscedasticity-consistent (sandwich) covariance of the weighted residuals",
            )
        return res


def sandwich_covariance(
    S_list: Sequence[np.ndarray], E_list: Sequence[np.ndarray], R: np.ndarray, info: np.ndarray
) -> np.ndarray:
    """Heteroscedasticity-consistent (White) covariance M^-1 (sum g_k g_k^T) M^-1 with
    g_k = S_k^T R^-1 e_k: correct when the residual variance changes over time, as the
    exp(-sigma t)-weighted residuals of the eigenvalue transformation do, while the fit
    assumed one R. S (N, n_out, n_p) or a :class:`Sensitivity`, e (N, n_out) per segment;
    NaN residuals skipped."""
    Rinv = np.linalg.inv(R)
    mid = np.zeros_like(info)
    for S, E in zip(S_list, E_list):
        b = as_sensitivity(S)
        E = np.where(np.isfinite(E), E, 0.0)
        g = np.einsum("top,oq,tq->tp", b.values, Rinv, E, optimize=True)
        add_block(mid, b.cols, g.T @ g)
    Minv = st.covariance(info)
    C = Minv @ mid @ Minv
    return 0.5 * (C + C.T)


class EquationDecoupling(_TransformedOEM):
    """Output error with decoupled state equations: in the equation of state i, every other
    measured state j is replaced by its measurement z_j (a pseudo-input).

    states : the states whose measurements replace them in the other equations (default:
        every state that is also an output).
    smooth : cut-off frequency in Hz of a zero-phase low-pass filter (4th-order
        Butterworth, forward-backward) applied to the pseudo-inputs, or None. Measurement
        noise in a pseudo-input acts like process noise on the other equations and biases
        the estimates (errors in variables); a cut-off a few times above the fastest mode
        removes most of it. Default None (the measurements as recorded).
    pseudo : None (the measurements, as recorded) or a callable ``pseudo(segment, states)``
        returning the pseudo-input values (N, len(states)) - e.g. the measured angle of
        attack moved from the nose-boom vane to the CG (alpha_vane differs by about
        q x_vane / V, which a decoupled pitch equation would otherwise book on Cmq).
        Missing samples are filled and ``smooth`` is applied afterwards as usual.
    std : as :class:`StabilizedOutputError`: the measurement noise of a pseudo-input
        passes through the dynamics of the other equations like process noise and colours
        the residuals, so the plain Cramér-Rao bounds are too small. Smoothed pseudo-inputs
        (``smooth``) get the Morelli-Klein std.

    Decouple as little as needed: replacing only the destabilising coupling (for a
    statically unstable short period, alpha in the pitch equation: ``states=["alpha"]``)
    keeps the errors-in-variables effect of noisy pseudo-inputs smallest.
    """

    method = "oem-decoupled"

    def __init__(
        self,
        model: Model,
        states: Sequence[str] | None = None,
        integrator: str = "rk4",
        smooth: float | None = None,
        std: str = "propagated",
        pseudo=None,
        **oem_options,
    ) -> None:
        super().__init__(model, integrator, std, **oem_options)
        self.states = None if states is None else list(states)
        self.smooth = smooth
        self.pseudo = pseudo

    def _pseudo(self, seg: Segment, cols: Sequence[int]) -> np.ndarray:
        if self.pseudo is not None:
            states = [self.model.outputs[j] for j in cols]
            z = np.asarray(self.pseudo(seg, states), dtype=float).reshape(seg.n, len(cols))
            z = _fill(z, seg.t)
        else:
            z = _fill(seg.z[:, cols], seg.t)
        if self.smooth is None:
            return z
        fs = 1.0 / float(np.median(np.diff(seg.t)))
        if not 0 < self.smooth < 0.5 * fs:
            raise ModelDefinitionError(
                f"smooth={self.smooth} Hz must lie between 0 and the Nyquist frequency {0.5 * fs:g} Hz"
            )
        b, a = signal.butter(4, self.smooth / (0.5 * fs))
        return signal.filtfilt(b, a, z, axis=0)

    def _transform(self, segments, start):
        m = self.model
        dec = self.states if self.states is not None else [s for s in m.states if s in m.outputs]
        bad = [s for s in dec if s not in m.states or s not in m.outputs]
        if bad or not dec:
            raise ModelDefinitionError(
                f"equation decoupling needs measured states (states that are outputs); {bad or 'none'} cannot be used"
            )
        ni, n = len(m.inputs), len(m.states)
        si = [m.states.index(s) for s in dec]
        oi = [m.outputs.index(s) for s in dec]

        def f(x, u, p, c):
            uu = u[:ni]
            zz = u[ni:]
            out = []
            for i in range(n):
                xi = list(x)
                for jj, j in enumerate(si):
                    if j != i:
                        xi[j] = zz[jj] + 0.0 * x[i]
                out.append(m.f(xi, uu, p, c)[i])
            return tuple(out)

        mt = _numpy_only(
            Model(
                m.states,
                list(m.inputs) + [f"z_{s}" for s in dec],
                m.outputs,
                m.parameters,
                f,
                _g_of(m, ni),
                m.constants,
                [],
                m.name + " (decoupled)",
            )
        )
        segs = [
            Segment(
                t=s.t, u=np.column_stack([s.u, self._pseudo(s, oi)]), z=s.z, x0=s.x0, constants=s.constants, name=s.name
            )
            for s in segments
        ]
        return (
            mt,
            segs,
            {"decoupled_states": dec, "smooth_hz": self.smooth or 0.0, "pseudo_outputs": dec, "pseudo": self.pseudo},
        )
