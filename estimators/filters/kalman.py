"""Extended and unscented Kalman filters for parameter estimation.

The unknown parameters are appended to the state with zero dynamics (optionally a random
walk), s = [x; theta], and a filter pass over the data estimates both (passes repeated from
the last estimates until they settle, ``passes="auto"``)::

    ekf = EKF(model, process_noise={"alpha": 0.01, "q": 0.02},
              measurement_noise={"alpha": 1.7e-3, "q": 3.5e-3, ...})
    res = ekf.fit([seg1, seg2])
    res.params, res.std                    # final estimate and sqrt(diag P_theta)
    res.extra["trajectory"][0]             # parameter estimates over time (segment 0)

Discrete model used by both filters, sample k -> k+1 (step h = t_{k+1} - t_k):

    x_{k+1} = Phi_h(x_k, u, theta) + w_k,   w_k ~ N(0, Qd),  Qd = F F^T h
    theta_{k+1} = theta_k + w_theta,        w_theta ~ N(0, diag(param_noise^2) h)
    z_k = g(x_k, u_k, theta) + v_k,         v_k ~ N(0, R)

Phi_h is one step of the package's integrator (default RK4, inputs interpolated at each stage time
as in output error), so the filters predict exactly like the OEM simulation.

* :class:`EKF`: Jacobians of Phi_h and g with respect to s by forward differences, all
  perturbed columns in one vectorised model call; covariance update in Joseph form
  P = (I - K H) P (I - K H)^T + K R K^T.
* :class:`UKF`: scaled sigma points (van der Merwe: alpha, beta, kappa), sigma points
  redrawn after the prediction so Qd reaches the output statistics; ``augmented=True``
  puts the process and measurement noise into the sigma points (noise-augmented state
  [s; w; v]) instead of adding Qd and R to the covariances.

Noise settings (continuous-time process-noise std per state, measurement-noise std per
output) come from the caller or the data, and are adapted between passes by covariance
matching (``adapt_noise``); the defaults are documented on :class:`EKF`. Several
segments: the filter restarts at each segment's initial state with the parameter estimate
and its covariance carried over from the previous segment. Per-segment parameters
(``bias_az[k]``) sit in the state for every segment; they only move while their own
segment runs.

The result is an :class:`~estimators.EstimationResult`: ``predicted`` are the a-priori
(one-step-ahead) outputs g(x_k|k-1) and ``residuals`` the innovations z_k - g(x_k|k-1);
``R`` is the sample covariance of the innovations (the measurement-noise covariance the
filter used is ``extra["measurement_noise"]``); ``cov`` the final parameter block of P.
``extra`` holds ``trajectory``/``trajectory_std`` (per segment, DataFrames on t),
``states`` (a-posteriori states), ``posterior_outputs``, ``gain`` (last Kalman gain),
``process_noise`` (F) and ``cluster``: the maneuvers' scatter of the last pass
(:mod:`estimators.validation.cluster`, each segment a cluster, from what it added to the
parameters' information; :func:`_segment_scatter`), None with one segment.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from estimators import statistics as st
from estimators.compile.kernels import kernel_for
from estimators.errors import ModelDefinitionError, SimulationDivergedError
from estimators.model import Model, Segment
from estimators.results import EstimationResult, frames
from estimators.simulation.integrators import DEFAULT_INPUTS, INPUT_MODES, check_options
from estimators.simulation.simulate import Layout


# -- noise settings ---------------------------------------------------------------------------
def _vector(spec: Any, names: Sequence[str], what: str, default: np.ndarray) -> np.ndarray:
    """A per-name vector from None (default), a scalar, a mapping or a sequence."""
    out = np.array(default, dtype=float)
    if spec is None:
        return out
    if isinstance(spec, Mapping):
        bad = sorted(set(spec) - set(names))
        if bad:
            raise ModelDefinitionError(f"{what}: unknown names {bad}; expected some of {list(names)}")
        for k, v in spec.items():
            out[list(names).index(k)] = float(v)
        return out
    arr = np.asarray(spec, dtype=float)
    if arr.ndim == 0:
        return np.full(len(names), float(arr))
    if arr.shape != (len(names),):
        raise ModelDefinitionError(f"{what}: expected {len(names)} values for {list(names)}, got shape {arr.shape}")
    return arr


def named_process_noise(model: Model, names: Sequence[str], segments: Sequence[Segment]) -> np.ndarray:
    """Process-noise std (n,) for a list of state names: the data default of
    :func:`default_process_noise` on those states, 0 on the others. A named state that is
    not a measured output has no data default: that is an error saying what to give."""
    bad = sorted(set(names) - set(model.states))
    if bad:
        raise ModelDefinitionError(f"process_noise: {bad} are not states {model.states}")
    unmeasured = [s for s in names if s not in model.outputs]
    if unmeasured:
        raise ModelDefinitionError(
            f"process_noise names {unmeasured}, not measured outputs, so their level cannot "
            "come from the data: give it as {state: std} (state unit per sqrt(s))"
        )
    default = default_process_noise(model, segments)
    return np.array([default[i] if s in names else 0.0 for i, s in enumerate(model.states)])


def is_name_list(spec: Any) -> bool:
    """Whether a noise setting is a non-empty list of state names."""
    return isinstance(spec, (list, tuple)) and len(spec) > 0 and all(isinstance(v, str) for v in spec)


def process_noise_matrix(model: Model, spec: Any, segments: Sequence[Segment] = ()) -> np.ndarray:
    """F (n_states, n_states) from None (zeros), {state: std}, a (n,) vector of std, an
    (n, n) matrix, or a list of state names (their data default, :func:`named_process_noise`;
    needs ``segments``). Units: state unit per sqrt(s) (std of the continuous white noise)."""
    n = len(model.states)
    if is_name_list(spec):
        return np.diag(named_process_noise(model, spec, segments))
    if spec is not None and np.ndim(spec) == 2:
        F = np.asarray(spec, dtype=float)
        if F.shape[0] != n:
            raise ModelDefinitionError(f"process_noise matrix needs {n} rows (states {model.states})")
        return F
    return np.diag(_vector(spec, model.states, "process_noise", np.zeros(n)))


def default_process_noise(model: Model, segments: Sequence[Segment], fraction: float = 0.05) -> np.ndarray:
    """Process-noise std per state (n,) from the data: ``fraction`` sqrt(var(diff z) / h)
    for each state that is a measured output (a twentieth of the bound the sample-to-sample
    variation puts on it), 0 for unmeasured states. Units: state unit per sqrt(s); h is
    the median sample interval (s)."""
    out = np.zeros(len(model.states))
    for i, name in enumerate(model.states):
        if name in model.outputs:
            d, dt = _sample_differences(segments, model.outputs.index(name))
            if d.size >= 2:
                out[i] = fraction * np.sqrt(np.var(d) / np.median(dt))
    return out


def _sample_differences(segments: Sequence[Segment], j: int) -> tuple[np.ndarray, np.ndarray]:
    """Differences of output j between its consecutive measured samples and their time steps,
    pooled over segments ((n_d,), (n_d,)): a slower channel on a faster grid is NaN between
    its samples, so plain np.diff would hold no finite value."""
    d, dt = [], []
    for seg in segments:
        ok = np.isfinite(seg.z[:, j])
        d.append(np.diff(seg.z[ok, j]))
        dt.append(np.diff(seg.t[ok]))
    return np.concatenate(d), np.concatenate(dt)


def default_measurement_noise(model: Model, segments: Sequence[Segment]) -> np.ndarray:
    """Measurement-noise variance per output from the data: the white-noise level of the
    second differences (:func:`estimators.statistics.difference_noise_std`), pooled over
    segments; 1 for an output never measured 4 times (never used for an update). Signal
    curvature and process noise between samples count as noise, so it errs high; with
    ``adapt_noise`` (default "auto") the filter adapts it pass by pass, else pass
    ``measurement_noise`` when the sensor noise is known."""
    sd = st.difference_noise_std([seg.z for seg in segments])
    return np.where(np.isfinite(sd), np.where(sd > 0, sd**2, 1e-12), 1.0)


def measurement_noise_matrix(model: Model, spec: Any, segments: Sequence[Segment]) -> np.ndarray:
    """R (n_out, n_out) from None (data default), {output: std}, (n_out,) std or a matrix."""
    m = len(model.outputs)
    if spec is not None and np.ndim(spec) == 2:
        R = np.asarray(spec, dtype=float)
        if R.shape != (m, m):
            raise ModelDefinitionError(f"measurement_noise matrix must be {m}x{m} (outputs {model.outputs})")
        return R
    var0 = default_measurement_noise(model, segments)
    if spec is None:
        return np.diag(var0)
    sd = _vector(spec, model.outputs, "measurement_noise", np.sqrt(var0))
    return np.diag(sd**2)


# -- a pass's segments as clusters ------------------------------------------------------------
def _information(P: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P^-1, P^-1 theta) of a parameter estimate theta (m,) with covariance P (m, m): the
    information form, in which a segment's contribution to a filter pass adds up."""
    Pinv = np.linalg.pinv(0.5 * (P + P.T))
    return Pinv, Pinv @ theta


def _segment_scatter(info: list[tuple[np.ndarray, np.ndarray]], P: np.ndarray, theta: np.ndarray, names: Sequence[str]):
    """The maneuvers' scatter of one filter pass (:mod:`estimators.validation.cluster`,
    each segment a cluster), or None with fewer than 2 segments or a failed inversion.

    A segment j adds A_j = P_after^-1 - P_before^-1 to the parameters' information and
    b_j = P_after^-1 theta_after - P_before^-1 theta_before = A_j theta_j to its weighted
    estimate (exact for a linear model with Gaussian noise, each segment's states started
    anew: theta_j is what the segment alone says); its part of the gradient at the pass's
    estimate theta is s_j = b_j - A_j theta, and M = P^-1 (the initial covariance's prior
    included). When the segments disagree more than their information allows, the
    cluster covariance grows beyond P, as filter error's does (pipeline.validation.validate.
    widen_by_scatter then reports it as the std)."""
    if len(info) < 2:
        return None
    from estimators.validation.cluster import cluster_covariance

    try:
        M = np.linalg.pinv(0.5 * (P + P.T))
        return cluster_covariance(
            [0.5 * (A + A.T) for A, _ in info], [b - A @ theta for A, b in info], 0.5 * (M + M.T), names=list(names)
        )
    except (ValueError, np.linalg.LinAlgError):
        return None


# -- the augmented model ----------------------------------------------------------------------
class AugmentedModel:
    """Batched evaluation of the parameter-augmented system for one segment.

    Columns of S (n + m, B) are augmented states [x; theta_free]; ``step`` advances the
    x part over one sample interval with the package integrator, ``outputs`` evaluates g.
    """

    def __init__(
        self,
        model: Model,
        layout: Layout,
        seg: Segment,
        k: int,
        integrator: str,
        rtol: float = 1e-8,
        atol: float = 1e-10,
        inputs: str = DEFAULT_INPUTS,
    ) -> None:
        self.model, self.lay, self.seg, self.k = model, layout, seg, k
        self.integrator = integrator
        self.n = len(model.states)
        self.fi = layout.free_idx
        self.lo, self.hi = layout.lower[self.fi][:, None], layout.upper[self.fi][:, None]
        self.c = model.constants_for(seg)
        self.kernel = kernel_for(model)
        self.rtol, self.atol = rtol, atol
        self.inputs = inputs
        # g compiled when the model allows (the filter-error kernels' gout), else numpy
        from estimators.filters.filter_error import output_kernel  # fem imports this module

        gk = output_kernel(model) if self.kernel.prepare() else None
        self._gout = None if gk is None else gk.gout
        self._cj = None if gk is None else self.kernel._c_jit(self.c)
        self._u = np.ascontiguousarray(seg.u, dtype=float)

    def params(self, S: np.ndarray) -> np.ndarray:
        """Model parameter matrix P (n_params, B) for augmented columns S, the free
        parameters held to their bounds (a sigma point or a difference step beyond a bound
        sees the model at the bound)."""
        B = S.shape[1]
        Theta = np.repeat(self.lay.values[:, None], B, axis=1)
        Theta[self.fi] = np.clip(S[self.n :], self.lo, self.hi)
        return Theta[self.lay.pidx[self.k]]

    def step(self, S: np.ndarray, i: int) -> np.ndarray:
        """x part of S advanced from sample i to i+1 (n, B); theta unchanged."""
        seg = self.seg
        X = self.kernel.integrate(
            self.integrator,
            S[: self.n],
            seg.u[i : i + 2],
            seg.t[i : i + 2],
            self.params(S),
            self.c,
            rtol=self.rtol,
            atol=self.atol,
            inputs=self.inputs,
        )
        return X[1]

    def outputs(self, S: np.ndarray, i: int) -> np.ndarray:
        """g at sample i for the augmented columns S: (n_out, B)."""
        if self._gout is not None:
            Y = np.empty((len(self.model.outputs), S.shape[1]))
            self._gout(np.ascontiguousarray(S[: self.n]), self._u[i], self.params(S), self._cj, Y)
            return Y
        u = self.seg.u[i][:, None, None]
        with np.errstate(all="ignore"):
            Y = self.model.eval_g(S[: self.n, None, :], u, self.params(S), self.c)
        return Y[:, 0, :]

    def outputs_along(self, S: np.ndarray) -> np.ndarray:
        """g along a trajectory of augmented states S (N, n+m): (N, n_out)."""
        P = self.params(S.T)  # (n_p, N)
        X = S[:, : self.n].T[:, None, :]  # (n, 1, N)
        U = self.seg.u.T[:, None, :]  # (n_in, 1, N)
        with np.errstate(all="ignore"):
            return self.model.eval_g(X, U, P, self.c)[:, 0, :].T


def _innovation_nll(nu: np.ndarray, S: np.ndarray) -> float:
    """0.5 (nu^T S^-1 nu + ln det S) of one update's innovations nu (m,), covariance S."""
    sign, logdet = np.linalg.slogdet(S)
    if sign <= 0:
        return np.inf
    return 0.5 * (nu @ np.linalg.solve(S, nu) + logdet)


def _column_params(S, values, fi, pidx, lo, hi, n, th, Pm):
    """Model parameters Pm (n_p, B) of augmented columns S (L, B): the layout's values with
    the free ones from S's parameter rows, held to their bounds (AugmentedModel.params);
    ``th`` a work copy of the values."""
    m = fi.shape[0]
    for b in range(S.shape[1]):
        for j in range(m):
            th[fi[j]] = min(max(S[n + j, b], lo[j]), hi[j])
        for r in range(pidx.shape[0]):
            Pm[r, b] = th[pidx[r]]


def _measured(z):
    """Indices of the finite entries of z."""
    k = 0
    for a in range(z.shape[0]):
        if np.isfinite(z[a]):
            k += 1
    idx = np.empty(k, dtype=np.int64)
    k = 0
    for a in range(z.shape[0]):
        if np.isfinite(z[a]):
            idx[k] = a
            k += 1
    return idx


def _book_update(K, Sinn, Rk, nu, idx, n, dt, acc, gain, last_ok):
    """The bookkeeping of an update on the outputs ``idx`` (gain K (L, k), innovations nu
    (k,) with covariance Sinn, the filter's Rk on them, step dt s, 0 at a segment start):
    the gain kept in ``gain`` (L, n_out) / ``last_ok``, and added into the flat work array
    acc = [nll, n_obs, r (n_out), r_post (n_out), nr (n_out), q_obs (n), q_exp (n)]: the
    innovations' negative log-likelihood and count (_innovation_nll) and the
    covariance-matching sums (_NoiseMatch.add)."""
    k = idx.shape[0]
    n_out = gain.shape[1]
    sign, logdet = np.linalg.slogdet(Sinn)
    acc[0] += np.inf if sign <= 0 else 0.5 * (nu @ np.linalg.solve(Sinn, nu) + logdet)
    acc[1] += k
    gain[:, :] = 0.0
    last_ok[:] = False
    for a in range(k):
        gain[:, idx[a]] = K[:, a]
        last_ok[idx[a]] = True
    RSi = np.linalg.solve(Sinn, Rk).T
    rp = RSi @ nu
    for a in range(k):
        o = idx[a]
        acc[2 + o] += nu[a] ** 2 - Sinn[a, a] + Rk[a, a]
        v = 0.0
        for b in range(k):
            v += RSi[a, b] * Rk[b, a]
        acc[2 + n_out + o] += rp[a] ** 2 + Rk[a, a] - v
        acc[2 + 2 * n_out + o] += 1.0
    if dt > 0:
        Kx = K[:n]
        kn = Kx @ nu
        KS = Kx @ Sinn
        base = 2 + 3 * n_out
        for r in range(n):
            acc[base + r] += kn[r] ** 2 / dt
            v = 0.0
            for a in range(k):
                v += KS[r, a] * Kx[r, a]
            acc[base + n + r] += v / dt


def _project(s, lo, hi, n, hits, i, P, Spost, Pdiag):
    """The end of sample i: the parameter rows of s held to their bounds (projections
    counted in hits), s and diag(P) kept in row i of Spost, Pdiag."""
    for j in range(hits.shape[0]):
        v = min(max(s[n + j], lo[j]), hi[j])
        if v != s[n + j]:
            hits[j] += 1
        s[n + j] = v
    Spost[i] = s
    for j in range(s.shape[0]):
        Pdiag[i, j] = P[j, j]


def _add_process_noise(P, FFt, qth, dt, n):
    """P (L, L) + the process noise of a step of dt s (FFt dt on the states, qth dt on the
    parameters), made symmetric, in place."""
    for r in range(n):
        for j in range(n):
            P[r, j] += FFt[r, j] * dt
    for j in range(qth.shape[0]):
        P[n + j, n + j] += qth[j] * dt
    for r in range(P.shape[0]):
        for j in range(r + 1, P.shape[0]):
            v = 0.5 * (P[r, j] + P[j, r])
            P[r, j] = v
            P[j, r] = v


def _segment_arrays(N, L, n_out, n):
    """The outputs of a segment loop: Ypred (N, n_out) NaN, Spost and Pdiag (N, L), gain
    (L, n_out), last_ok (n_out,), hits (L - n,), acc (see :func:`_book_update`)."""
    return (
        np.full((N, n_out), np.nan),
        np.empty((N, L)),
        np.empty((N, L)),
        np.zeros((L, n_out)),
        np.zeros(n_out, dtype=np.bool_),
        np.zeros(L - n, dtype=np.int64),
        np.zeros(2 + 3 * n_out + 2 * n),
    )


def _ekf_segment(scheme, gout, s, P, t, U, Z, R, FFt, qth, values, fi, pidx, lo, hi, c, fd_step, rtol, atol, mode, n):
    """The EKF over one segment, compiled with the model's rhs and g (the kernel module of
    :func:`estimators.filters.filter_error.output_kernel` binds ``scheme`` and ``gout``; the helpers above
    are compiled into it too): the same equations as :meth:`EKF._predict` /
    :meth:`EKF._update` and the pass loop of :meth:`_ParameterFilter._one_pass` (bounds,
    innovations' likelihood, covariance-matching sums), without Python's per-sample
    overhead. s (L,) = [x0; theta], P (L, L); t (N,), U (N, n_in), Z (N, n_out) with NaN =
    not measured; R (n_out, n_out); FFt (n, n) and qth (m,) the process noise per second;
    values, fi, pidx, lo, hi the layout's values, free indices, the segment's parameter
    rows and the free parameters' bounds.
    Returns (s, P, Ypred (N, n_out), Spost (N, L), Pdiag (N, L), gain (L, n_out) of the
    last update (zero columns: not measured), its measured mask, hits (m,), acc (see
    :func:`_book_update`), the sample where the prediction became non-finite or -1)."""
    N = t.shape[0]
    L = s.shape[0]
    n_out = Z.shape[1]
    Ypred, Spost, Pdiag, gain, last_ok, hits, acc = _segment_arrays(N, L, n_out, n)
    S = np.empty((L, L + 1))
    Pm = np.empty((pidx.shape[0], L + 1))
    th = values.copy()
    Y = np.empty((n_out, L + 1))
    h = np.empty(L)
    eye = np.eye(L)
    for i in range(N):
        dt = 0.0
        for pred in range(2 if i > 0 else 1):
            # the difference columns s + h_j e_j and their model parameters
            for j in range(L):
                h[j] = fd_step * max(abs(s[j]), 1.0)
                for b in range(L + 1):
                    S[j, b] = s[j]
                S[j, j + 1] += h[j]
            _column_params(S, values, fi, pidx, lo, hi, n, th, Pm)
            if pred == 0 and i > 0:
                # prediction over [t_(i-1), t_i]
                dt = t[i] - t[i - 1]
                X = scheme(S[:n].copy(), U[i - 1 : i + 1], t[i - 1 : i + 1], Pm, c, rtol, atol, mode)
                Phi = eye.copy()
                for r in range(n):
                    for j in range(L):
                        Phi[r, j] = (X[1, r, j + 1] - X[1, r, 0]) / h[j]
                    s[r] = X[1, r, 0]
                P = Phi @ P @ Phi.T
                _add_process_noise(P, FFt, qth, dt, n)
                if not (np.all(np.isfinite(s)) and np.all(np.isfinite(P))):
                    return s, P, Ypred, Spost, Pdiag, gain, last_ok, hits, acc, i
        # measurement update at t_i (the columns set again about the predicted s)
        gout(S[:n].copy(), U[i], Pm, c, Y)
        for a in range(n_out):
            Ypred[i, a] = Y[a, 0]
        idx = _measured(Z[i])
        k = idx.shape[0]
        if k > 0:
            H = np.empty((k, L))
            nu = np.empty(k)
            Rk = np.empty((k, k))
            for a in range(k):
                nu[a] = Z[i, idx[a]] - Y[idx[a], 0]
                for j in range(L):
                    H[a, j] = (Y[idx[a], j + 1] - Y[idx[a], 0]) / h[j]
                for b in range(k):
                    Rk[a, b] = R[idx[a], idx[b]]
            Sinn = H @ P @ H.T + Rk
            K = np.linalg.solve(Sinn, H @ P).T
            s = s + K @ nu
            IKH = eye - K @ H
            P = IKH @ P @ IKH.T + K @ Rk @ K.T
            P = 0.5 * (P + P.T)
            _book_update(K, Sinn, Rk, nu, idx, n, dt, acc, gain, last_ok)
        _project(s, lo, hi, n, hits, i, P, Spost, Pdiag)
    return s, P, Ypred, Spost, Pdiag, gain, last_ok, hits, acc, -1


def _sigma_points(s, P, cfac):
    """The UKF's 2L + 1 sigma points (L, 2L + 1): s, s +- columns of sqrt(cfac P)
    (Cholesky, else the symmetric square root of the eigen-decomposition: _sqrt_psd)."""
    L = s.shape[0]
    A = cfac * P
    try:
        F = np.linalg.cholesky(A)
    except Exception:  # noqa: BLE001 - numba raises a plain LinAlgError
        w, V = np.linalg.eigh(0.5 * (A + A.T))
        F = V * np.sqrt(np.maximum(w, 0.0))
    S = np.empty((L, 2 * L + 1))
    for j in range(L):
        S[j, 0] = s[j]
        for b in range(L):
            S[j, 1 + b] = s[j] + F[j, b]
            S[j, 1 + L + b] = s[j] - F[j, b]
    return S


def _ukf_segment(
    scheme, gout, s, P, t, U, Z, R, FFt, qth, values, fi, pidx, lo, hi, c, Wm, Wc, cfac, rtol, atol, mode, n
):
    """The UKF (sigma points not noise-augmented) over one segment, compiled as
    :func:`_ekf_segment` is, with the equations of :meth:`UKF._predict` /
    :meth:`UKF._update`; Wm, Wc (2L + 1,) the weights and cfac = L + lambda. Returns what
    :func:`_ekf_segment` returns."""
    N = t.shape[0]
    L = s.shape[0]
    n_out = Z.shape[1]
    B = 2 * L + 1
    Ypred, Spost, Pdiag, gain, last_ok, hits, acc = _segment_arrays(N, L, n_out, n)
    Pm = np.empty((pidx.shape[0], B))
    th = values.copy()
    Y = np.empty((n_out, B))
    for i in range(N):
        dt = 0.0
        if i > 0:
            dt = t[i] - t[i - 1]
            S = _sigma_points(s, P, cfac)
            _column_params(S, values, fi, pidx, lo, hi, n, th, Pm)
            X = scheme(S[:n].copy(), U[i - 1 : i + 1], t[i - 1 : i + 1], Pm, c, rtol, atol, mode)
            S[:n] = X[1]
            mean = S @ Wm
            D = S - mean.reshape(L, 1)
            P = (D * Wc) @ D.T
            _add_process_noise(P, FFt, qth, dt, n)
            s = mean
            if not (np.all(np.isfinite(s)) and np.all(np.isfinite(P))):
                return s, P, Ypred, Spost, Pdiag, gain, last_ok, hits, acc, i
        S = _sigma_points(s, P, cfac)
        _column_params(S, values, fi, pidx, lo, hi, n, th, Pm)
        gout(S[:n].copy(), U[i], Pm, c, Y)
        y = Y @ Wm
        for a in range(n_out):
            Ypred[i, a] = y[a]
        idx = _measured(Z[i])
        k = idx.shape[0]
        if k > 0:
            Dy = Y - y.reshape(n_out, 1)
            Ds = S - s.reshape(L, 1)
            Syy_all = (Dy * Wc) @ Dy.T + R
            Ssy_all = (Ds * Wc) @ Dy.T
            Syy = np.empty((k, k))
            Ssy = np.empty((L, k))
            Rk = np.empty((k, k))
            nu = np.empty(k)
            for a in range(k):
                nu[a] = Z[i, idx[a]] - y[idx[a]]
                for b in range(k):
                    Syy[a, b] = Syy_all[idx[a], idx[b]]
                    Rk[a, b] = R[idx[a], idx[b]]
                for j in range(L):
                    Ssy[j, a] = Ssy_all[j, idx[a]]
            K = np.linalg.solve(Syy, Ssy.T).T
            s = s + K @ nu
            P = P - K @ Syy @ K.T
            P = 0.5 * (P + P.T)
            _book_update(K, Syy, Rk, nu, idx, n, dt, acc, gain, last_ok)
        _project(s, lo, hi, n, hits, i, P, Spost, Pdiag)
    return s, P, Ypred, Spost, Pdiag, gain, last_ok, hits, acc, -1


#: the compiled helpers of the segment loops (source copied into the kernel module)
SEGMENT_HELPERS = (
    _column_params,
    _measured,
    _book_update,
    _project,
    _segment_arrays,
    _add_process_noise,
    _sigma_points,
)


# -- noise adaptation (covariance matching) -----------------------------------------------------
#: adapt_noise values: "auto" adapts R when measurement_noise is not given
ADAPT_CHOICES = ("auto", True, False, "R", "Q")


class _NoiseMatch:
    """Sums over one filter pass for covariance matching (Myers and Tapley).

    Measurement noise from the innovations nu and the a-priori output covariance
    H P- H^T = S - R: R_ii = mean(nu_i^2 - (S - R)_ii) (Mehra; one pass lands near the
    fixed point), and where that is not positive from the a-posteriori residuals
    r+ = R S^-1 nu and output covariance H P+ H^T = R - R S^-1 R:
    mean(r+_i^2 + (R - R S^-1 R)_ii) (Myers and Tapley; positive, but a small R only grows
    by a fraction of the mismatch per pass). Samples where output i is finite.
    Process noise, per state: the observed spread of the state corrections K_x nu against
    the spread the filter expects, K_x S K_x^T, per second of sample interval.
    """

    def __init__(self, n: int, n_out: int) -> None:
        self.r = np.zeros(n_out)
        self.r_post = np.zeros(n_out)
        self.nr = np.zeros(n_out)
        self.q_obs = np.zeros(n)
        self.q_exp = np.zeros(n)

    def add(self, nu: np.ndarray, S: np.ndarray, Kx: np.ndarray, R: np.ndarray, ok: np.ndarray, h: float) -> None:
        """One update: innovations nu (n_ok,), their covariance S, the state rows of the
        gain Kx (n, n_ok), the filter's R (n_out, n_out), finite mask ok, step h s (0 at
        a segment's first sample: no prediction preceded it)."""
        Rk = R[np.ix_(ok, ok)]
        RSi = np.linalg.solve(S, Rk).T  # R S^-1 (S, R symmetric)
        self.r[ok] += nu**2 - np.diag(S) + np.diag(Rk)
        self.r_post[ok] += (RSi @ nu) ** 2 + np.diag(Rk) - np.einsum("ij,ji->i", RSi, Rk)
        self.nr[ok] += 1.0
        if h > 0:
            self.q_obs += (Kx @ nu) ** 2 / h
            self.q_exp += np.einsum("ij,jk,ik->i", Kx, S, Kx) / h

    def add_sums(self, acc: np.ndarray, n_out: int) -> None:
        """A segment's sums as a compiled segment loop summed them: acc = [r, r_post, nr
        (n_out each), q_obs, q_exp (n each)] (:func:`_book_update`)."""
        r, r_post, nr, rest = np.split(acc, [n_out, 2 * n_out, 3 * n_out])
        q_obs, q_exp = np.split(rest, 2)
        self.r += r
        self.r_post += r_post
        self.nr += nr
        self.q_obs += q_obs
        self.q_exp += q_exp


def _adapt(
    F: np.ndarray, R: np.ndarray, match: _NoiseMatch, adapt_r: bool, adapt_q: bool
) -> tuple[np.ndarray, np.ndarray, float]:
    """The noise for the next pass from one pass's sums: (F, R, largest relative change
    of a noise std). R's diagonal set to the matched variances (outputs never finite
    keep theirs); F's non-zero diagonal scaled by sqrt(observed / expected correction
    spread), the ratio held to [0.1, 10] per pass."""
    moves = [0.0]
    if adapt_r:
        d = np.diag(R).copy()
        seen = match.nr > 0
        cnt = np.maximum(match.nr, 1.0)
        new = np.where(match.r > 0, match.r, match.r_post) / cnt
        new = np.where(seen, np.maximum(new, 1e-12 * np.maximum(d, 1e-30)), d)
        moves += list(np.abs(np.sqrt(new[seen] / d[seen]) - 1.0))
        R = np.diag(new)
    if adapt_q:
        f = np.diag(F).copy()
        on = (f != 0) & (match.q_exp > 0)
        ratio = np.clip(match.q_obs[on] / match.q_exp[on], 0.1, 10.0)
        f[on] = f[on] * np.sqrt(ratio)
        moves += list(np.abs(np.sqrt(ratio) - 1.0))
        F = np.diag(f)
    return F, R, float(max(moves))


def _joseph_update(P: np.ndarray, H: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kalman measurement update of the covariance P (..., L, L) with output Jacobian H
    (..., k, L) and noise R (k, k), stacked over leading axes: (P in Joseph form
    (I - K H) P (I - K H)^T + K R K^T, made symmetric; gain K = P H^T S^-1 (..., L, k);
    innovation covariance S = H P H^T + R)."""
    T = lambda A: np.swapaxes(A, -1, -2)  # noqa: E731
    S = H @ P @ T(H) + R
    K = T(np.linalg.solve(S, H @ P))  # S symmetric
    IKH = np.eye(P.shape[-1]) - K @ H
    P = IKH @ P @ T(IKH) + K @ R @ T(K)
    return 0.5 * (P + T(P)), K, S


# -- Ljung's modification: the gain's dependence on the parameters ------------------------------
class _GainSensitivity:
    """The state-only Kalman filters of one segment at the current parameter estimate
    theta and at theta + d_j e_j (j = 1..m), for Ljung's modification of the
    parameter-in-the-state filters (Ljung 1979, IEEE TAC 24(1)).

    The filters' state correction K_x(theta) nu depends on the parameters through the gain;
    the plain EKF/UKF neglect that dependence, so their x-theta cross-covariance misses the
    term (dK_x/dtheta) nu and the parameter estimates are biased wherever the gain is large
    (an unmeasured gust state corrected through a derivative). Here the gain K_j of the
    state-only filter (P_j (n, n), linearised at the filter's state) is carried along at
    each parameter perturbation, and after each update the augmented covariance is mapped
    by J = [[I, M], [0, I]], M[:, j] = (K_j - K_0) nu / d_j (n, m): the Jacobian of the
    update x+ = x- + K(theta) nu with respect to theta."""

    def __init__(self, n: int, s: np.ndarray, Px: np.ndarray, step: float, fd_step: float) -> None:
        m = s.size - n
        self.n, self.m = n, m
        self.P = np.repeat(Px[None], m + 1, axis=0)  # (m + 1, n, n)
        self.d = step * np.maximum(np.abs(s[n:]), 1.0)  # (m,)
        self.fd = fd_step

    def _columns(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Augmented columns (L, (m + 1)(n + 1)): per parameter set j (nominal first) the
        state and its n forward-difference steps; the state steps h (n,)."""
        n, m = self.n, self.m
        h = self.fd * np.maximum(np.abs(s[:n]), 1.0)
        base = np.repeat(s[:, None], m + 1, axis=1)
        base[n + np.arange(m), 1 + np.arange(m)] += self.d
        S = np.repeat(base[:, :, None], n + 1, axis=2)  # (L, m + 1, n + 1)
        S[np.arange(n), :, 1 + np.arange(n)] += h[:, None]
        return S.reshape(s.size, -1), h

    def _jacobian(self, Y: np.ndarray, h: np.ndarray) -> np.ndarray:
        """(m + 1, rows, n) forward-difference Jacobians from evaluations Y (rows, cols)."""
        Y = Y.reshape(Y.shape[0], self.m + 1, self.n + 1)
        return np.transpose((Y[:, :, 1:] - Y[:, :, :1]) / h, (1, 0, 2))

    def predict(self, aug: AugmentedModel, s: np.ndarray, Qx: np.ndarray, i: int) -> None:
        """Each P_j over the step from sample i, linearised about the posterior s."""
        S, h = self._columns(s)
        Phi = self._jacobian(aug.step(S, i), h)
        self.P = Phi @ self.P @ np.transpose(Phi, (0, 2, 1)) + Qx

    def update(
        self, aug: AugmentedModel, s: np.ndarray, ok: np.ndarray, R: np.ndarray, nu: np.ndarray, i: int
    ) -> np.ndarray:
        """Each P_j updated on the outputs ``ok`` about the predicted s; returns M (n, m)
        for the innovations nu (on ``ok``)."""
        S, h = self._columns(s)
        H = self._jacobian(aug.outputs(S, i), h)[:, ok]  # (m + 1, k, n)
        self.P, K, _ = _joseph_update(self.P, H, R[np.ix_(ok, ok)])
        return ((K[1:] - K[:1]) @ nu).T / self.d  # (n, m)

    @staticmethod
    def apply(P: np.ndarray, M: np.ndarray, n: int) -> np.ndarray:
        """J P J^T with J = [[I, M], [0, I]] (P (L, L) the posterior covariance)."""
        P = P.copy()
        P[:n] += M @ P[n:]
        P[:, :n] += P[:, n:] @ M.T
        return 0.5 * (P + P.T)


# -- the filters --------------------------------------------------------------------------------
class _ParameterFilter:
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
            sd = _vector(spec, names, "param_std", default)
        return np.diag(sd**2)

    def _param_noise(self, lay: Layout) -> np.ndarray:
        names = lay.free_names
        if isinstance(self.param_noise, Mapping):
            spec = {n: self.param_noise.get(n, self.param_noise.get(n.split("[")[0])) for n in names}
            spec = {n: s for n, s in spec.items() if s is not None}
        else:
            spec = self.param_noise
        return _vector(spec, names, "param_noise", np.zeros(len(names)))

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
        sd = _vector(self.state_std, m.states, "state_std", default)
        return np.diag(sd**2)

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
        the estimates where the shrinking covariance froze them (the HFB-320 test-case-4
        model of tests/test_user_model_api.py from 2-80 % off: Cm0, CmV 4.3-4.6 std off
        after one pass, within 0.5 after four). ``extra["pass_moves"]`` holds the largest
        move per pass in std, ``extra["not_settled"]`` the reason when they did not settle.
        """
        segments = [segments] if isinstance(segments, Segment) else list(segments)
        if not segments:
            raise ModelDefinitionError("fit() needs at least one segment")
        if not isinstance(estimate_x0, (bool, str)):
            bad = sorted(set(estimate_x0) - set(self.model.states))
            if bad:
                raise ModelDefinitionError(f"estimate_x0 names {bad} are not states {self.model.states}")
        lay = Layout.build(self.model, segments, False, values=start)
        fi = lay.free_idx
        n_max = self.max_passes if self.passes == "auto" else self.passes
        moves: list[float] = []
        history: list[dict] = []
        F = process_noise_matrix(self.model, self.process_noise, segments)
        R = measurement_noise_matrix(self.model, self.measurement_noise, segments)
        adapt_r, adapt_q = self._adapted(F)
        noise_moves: list[float] = []
        best: tuple[float, int, EstimationResult, np.ndarray] | None = None
        left = ""
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
                left = (
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
            history += [{"pass": k + 1, **row} for row in res.history.to_dict("records")]
            lay.values[fi] = after
            if comparable and (best is None or nll < best[0]):
                best = (nll, k + 1, res, after.copy())
            if adapt_r or adapt_q:
                F, R, nm = _adapt(F, R, match, adapt_r, adapt_q)
                noise_moves.append(nm)
            if self.passes == "auto" and moves[-1] <= self.pass_tol:
                break
        settled = not left and (self.passes != "auto" or moves[-1] <= self.pass_tol)
        n_done = len(moves)
        self._mark_bounds(res, lay)
        res.history = pd.DataFrame(history)
        res.iterations = n_done
        res.converged = settled
        res.extra["pass_moves"] = moves
        res.extra["std_method"] = "filter-covariance"
        adapted = [w for w, on in (("measurement_noise", adapt_r), ("process_noise", adapt_q)) if on]
        what = f"{n_done} filter pass{'es' if n_done > 1 else ''}"
        if adapted:
            # extra's noise is the one the last pass ran with; the adaptation's relative
            # moves per pass
            res.extra["noise_moves"] = noise_moves
            res.extra["adapted"] = adapted
            what += f"; {' and '.join(w.replace('_', ' ') for w in adapted)} adapted"
        if left:
            res.extra["not_settled"] = left
            what += "; not settled: " + left
        elif not settled:
            res.extra["not_settled"] = (
                f"the last of {n_done} passes still moved a parameter by {moves[-1]:.2g} std "
                f"(> {self.pass_tol:g}): raise max_passes, start closer or check the model"
            )
            what += "; not settled: " + res.extra["not_settled"]
        if res.at_bounds:
            what += f"; at a bound (std NaN): {', '.join(res.at_bounds)}"
        res.message = what + "; residuals are the innovations (a-priori)"
        return res

    # one filter pass -----------------------------------------------------------------------
    def _one_pass(
        self, segments: list[Segment], lay: Layout, F: np.ndarray, R: np.ndarray, matching: bool = False
    ) -> tuple[EstimationResult, _NoiseMatch | None]:
        """One pass of the filter over the segments from the start values in ``lay``, with
        process noise F (n, n) and measurement-noise covariance R (n_out, n_out): the
        pass's result and, with ``matching``, its covariance-matching sums (else None)."""
        model = self.model
        fi = lay.free_idx
        n, m = len(model.states), fi.size
        theta = lay.values[fi].copy()
        Pth = self._initial_param_cov(lay)
        qth = self._param_noise(lay) ** 2
        out = {"pred": [], "innov": [], "traj": [], "traj_std": [], "states": [], "post": []}
        history = []
        K = None
        match = _NoiseMatch(n, R.shape[0]) if matching else None
        lo, hi = lay.lower[fi], lay.upper[fi]
        hits = np.zeros(m, dtype=int)
        nll, n_obs = 0.0, 0  # innovations' negative log-likelihood (+ const)
        info = []  # per segment: what it adds to P_theta^-1 (and x P^-1 theta)
        before = _information(Pth, theta)
        for k, seg in enumerate(segments):
            aug = AugmentedModel(model, lay, seg, k, self.integrator, self.rtol, self.atol, self.inputs)
            x0 = lay.values[lay.x0idx[k]]
            s = np.concatenate([x0, theta])
            P = np.zeros((n + m, n + m))
            P[:n, :n] = self._initial_state_cov(R, aug, s, F)
            P[n:, n:] = Pth
            run = (
                self._compiled_segment(aug, s, P, F, R, qth, lay, k, match)
                if self.compiled and not self.gain_sensitivity
                else None
            )
            if run is None:
                run = self._python_segment(aug, s, P, F, R, qth, lo, hi, match)
            s, P, Ypred, Spost, Pdiag, K_seg, nll_k, n_k, hits_k, fail = run
            if fail >= 0:
                raise SimulationDivergedError(
                    f"the {self.method.upper()} prediction of segment {seg.name or k} became "
                    f"non-finite at t={seg.t[fail]:.4g} s: reduce param_std/state_std, "
                    "start closer, or use a smaller sample interval",
                    segment=k,
                    time=float(seg.t[fail]),
                )
            nll, n_obs, hits = nll + nll_k, n_obs + n_k, hits + hits_k
            K = K if K_seg is None else K_seg
            theta = s[n:].copy()
            Pth = P[n:, n:].copy()
            after = _information(Pth, theta)
            info.append((after[0] - before[0], after[1] - before[1]))
            before = after  # the next segment starts where this one ended
            idx = pd.Index(seg.t, name="t")
            out["pred"].append(Ypred)
            out["innov"].append(seg.z - Ypred)
            out["traj"].append(pd.DataFrame(Spost[:, n:], index=idx, columns=lay.free_names))
            out["traj_std"].append(
                pd.DataFrame(np.sqrt(np.maximum(Pdiag[:, n:], 0)), index=idx, columns=lay.free_names)
            )
            out["states"].append(pd.DataFrame(Spost[:, :n], index=idx, columns=model.states))
            out["post"].append(pd.DataFrame(aug.outputs_along(Spost), index=idx, columns=model.outputs))
            history.append({"segment": k, **dict(zip(lay.free_names, theta))})
        values = lay.values.copy()
        values[fi] = theta
        free = lay.free.copy()
        E = out["innov"]
        Rinn = st.residual_covariance(E, full=False)
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
            history=pd.DataFrame(history),
            segments=segments,
            predicted=frames([s.t for s in segments], out["pred"], model.outputs),
            residuals=frames([s.t for s in segments], E, model.outputs),
            message="one filter pass; residuals are the innovations (a-priori)",
            settings=self._settings(),
            extra={
                "trajectory": out["traj"],
                "trajectory_std": out["traj_std"],
                "states": out["states"],
                "posterior_outputs": out["post"],
                "gain": K,
                "measurement_noise": R,
                "process_noise": F,
                "residuals_are": "innovations",
                "innovation_nll": nll,
                "innovation_count": n_obs,
                "cluster": _segment_scatter(info, Pth, theta, lay.free_names),
                "bound_hits": {lay.free_names[j]: int(hits[j]) for j in np.flatnonzero(hits)},
            },
        ), match

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
    def _python_segment(self, aug, s, P, F, R, qth, lo, hi, match):
        """One segment's pass, sample by sample with :meth:`_predict` / :meth:`_update`:
        (s, P, Ypred (N, n_out), Spost (N, L), Pdiag (N, L), the last gain (L, n_ok) or None,
        the innovations' negative log-likelihood and count, bound projections (m,), the
        sample where the prediction became non-finite or -1); the covariance-matching sums
        go into ``match``."""
        n, seg = aug.n, aug.seg
        L, N = s.size, seg.n
        Ypred = np.full((N, len(self.model.outputs)), np.nan)
        Spost = np.empty((N, L))
        Pdiag = np.empty((N, L))
        hits = np.zeros(L - n, dtype=int)
        K, nll, n_obs = None, 0.0, 0
        sens = _GainSensitivity(n, s, P[:n, :n], self.gain_step, 1e-6) if self.gain_sensitivity and L > n else None
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
                    return s, P, Ypred, Spost, Pdiag, K, nll, n_obs, hits, i
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
                nll += _innovation_nll(nu, Sinn)
                n_obs += nu.size
                if match is not None:
                    match.add(nu, Sinn, Ki[:n], R, ok, seg.t[i] - seg.t[i - 1] if i else 0.0)
            Ypred[i] = yp
            Spost[i] = s
            Pdiag[i] = np.diag(P)
        return s, P, Ypred, Spost, Pdiag, K, nll, n_obs, hits, -1

    def _compiled_segment(self, aug, s, P, F, R, qth, lay, k, match):
        """:meth:`_python_segment` in compiled code (:func:`_ekf_segment`,
        :func:`_ukf_segment`), or None where there is none: the Python loop runs."""
        return None

    def _run_compiled(self, which: str, aug, s, P, F, R, qth, lay, k, match, *extra):
        """Run ``<which>_segment_<integrator>`` of the model's filter kernel module (None
        when g or f did not compile) with the segment's arguments, ``extra`` before rtol;
        its result as :meth:`_python_segment` gives it."""
        if aug._gout is None:  # g (or f) did not compile
            return None
        from estimators.filters.filter_error import output_kernel  # fem imports this module

        fn = getattr(output_kernel(self.model), f"{which}_segment_{self.integrator}", None)
        if fn is None:
            return None
        seg = aug.seg
        f64 = lambda a: np.ascontiguousarray(a, dtype=float)  # noqa: E731
        i64 = lambda a: np.ascontiguousarray(a, dtype=np.int64)  # noqa: E731
        s, P, Ypred, Spost, Pdiag, gain, last_ok, hits, acc, fail = fn(
            f64(s).copy(),
            f64(P).copy(),
            f64(seg.t),
            aug._u,
            f64(seg.z),
            f64(R),
            f64(F @ F.T),
            f64(qth),
            f64(lay.values),
            i64(lay.free_idx),
            i64(lay.pidx[k]),
            f64(aug.lo[:, 0]),
            f64(aug.hi[:, 0]),
            aug._cj,
            *extra,
            float(self.rtol),
            float(self.atol),
            INPUT_MODES[self.inputs],
            aug.n,
        )
        if match is not None:
            match.add_sums(acc[2:], len(self.model.outputs))
        K = gain[:, last_ok] if np.any(last_ok) else None
        return s, P, Ypred, Spost, Pdiag, K, float(acc[0]), int(acc[1]), hits, int(fail)

    # filter equations, per subclass
    def _predict(self, aug, s, P, Q, i):  # pragma: no cover - abstract
        raise NotImplementedError

    def _update(self, aug, s, P, z, ok, R, i):  # pragma: no cover - abstract
        """Measurement update at sample i: (s, P, predicted outputs, gain K (n+m, n_ok),
        innovation covariance (n_ok, n_ok)); K and S None when no output is finite."""
        raise NotImplementedError

    @staticmethod
    def _mark_bounds(res: EstimationResult, lay: Layout) -> None:
        """Free parameters held by a bound: projected onto it during the last pass
        (``extra["bound_hits"]``: updates per parameter) and ending within 3 std of it.
        They go to ``res.at_bounds`` with their std NaN, as in output error: the bound, not
        the data, holds them there."""
        fi = lay.free_idx
        v, lo, hi = res.values[fi], lay.lower[fi], lay.upper[fi]
        sd = np.sqrt(np.maximum(np.diag(res.cov), 0.0))
        hit = np.array([n in res.extra.get("bound_hits", {}) for n in lay.free_names], dtype=bool)
        on = hit & ((v - lo <= 3.0 * sd) | (hi - v <= 3.0 * sd))
        if np.any(on):
            res.at_bounds = [lay.free_names[i] for i in np.flatnonzero(on)]
            res.cov = res.cov.copy()
            res.cov[on, :] = np.nan
            res.cov[:, on] = np.nan

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


class EKF(_ParameterFilter):
    """Extended Kalman filter with the parameters in the state (Joseph-form update).

    Parameters
    ----------
    model : the :class:`~estimators.Model` (free parameters are estimated).
    integrator : one-step predictor, "euler" ... "rk4" (default) or "rkf45".
    process_noise : F: {state: std}, (n,) std or an (n, n) matrix; continuous white noise
        in state units per sqrt(s), Qd = F F^T dt. Default 0 (calm air).
    measurement_noise : {output: std}, (n_out,) std or an (n_out, n_out) covariance.
        Default: the white-noise level of each output's second differences (errs high:
        signal curvature and process noise count as noise), adapted pass by pass.
    adapt_noise : covariance matching between passes (Mehra; Myers and Tapley): "auto"
        (default) adapts R when ``measurement_noise`` is not given, True adapts R and the
        process noise of the states that have some (diagonal ``process_noise``), "R" or
        "Q" one of them, False none. R's diagonal is set to the innovations' spread less
        the filter's predicted output spread; F is scaled by sqrt(observed / expected
        spread of the state corrections K nu). The next pass runs with them;
        ``extra["measurement_noise"]``/``["process_noise"]`` are those of the last pass,
        ``extra["noise_moves"]`` the largest relative change of a noise std per pass. On the
        HFB-320 flight with process noise of tests/test_user_model_api.py (true F given,
        benchmarks/filter_noise_adaptation_mc.py, 16 noise draws): R held at the
        second-difference default biased Cmal 6.9 empirical std and put a derivative 8.6
        std off; adapted, every derivative within 3.0 std and the std honest
        (empirical/reported 0.76-1.26), as with the true R given (0.82-1.20). Adapting F
        suits process noise that is white; where it stands in for coloured gusts it finds
        too little (ad-hoc, the pipeline's EKF on longitudinal_3211_turbulence from the
        Dryden level: Cmalpha 4.8 std off the truth held, 6.8 adapted; at twice the level,
        held, the pipeline's setting, within 2.5 std).
    param_std : initial std of the parameters: {name: std}, a fraction of |start| (float),
        default 0.5 |start| (1.0 where the start is 0 - give biases explicitly).
    state_std : initial std of the states, {state: std} or (n,); default the measurement
        std of states that are outputs; for a state that is not an output but has process
        noise (a gust state) the stationary spread of its own dynamics at each segment
        start (F sqrt(tau/2) for a first-order gust); 1e-3 max(|x0|, 1) otherwise.
        With the roll gust started at 1e-3 rad/s, as before, the pipeline put Clp 24 (UKF)
        and 32 (EKF) std off the truth on multiaxis_multisine_turbulence (seed 31); from
        its stationary spread, 6.5 and 18.7. On data the lateral gust model itself makes
        (benchmarks/lateral_gust_filters_mc.py) the UKF is as good or better, the EKF better
        with the pipeline's process noise but worse with the true one (its linearisation
        at a segment start with the gust uncertain); ``state_std={"p_g": 1e-3}`` gives the
        old start.
    param_noise : random-walk std of the parameters per sqrt(s) (default 0: constant).
    inputs : input variation over a sample interval in the prediction step, as
        OutputError: "linear" (default) or "hold".
    passes : "auto" (default: repeat the pass from the last estimates until no free
        parameter moves by more than ``pass_tol`` (0.2) of its std, at most ``max_passes``
        (8)) or a fixed number of passes (see :meth:`fit`). A pass whose innovations'
        negative log-likelihood (``extra["innovation_nll"]``) is more than 3 std of it,
        sqrt(n_obs / 2), above the best pass's ends the passes: the best pass's result is
        kept and ``converged`` is False (``extra["not_settled"]`` says so). Not checked
        while the noise is adapted or in a pass that projected a parameter onto a bound.
        (The lateral multiaxis EKF with the turbulence in the aircraft's axes had flipped
        Clp's sign in its 6th pass and ended 139 std off; now pass 5 is kept, 15 std.)
    fd_step : relative forward-difference step of the Jacobians,
        h_j = fd_step * max(|s_j|, 1).
    callback : called as callback(pass, innovations' negative log-likelihood, params
        Series) after each pass (pass counts from 0), as OutputError's after each iteration.
    gain_sensitivity : Ljung's modification (default False): the state correction K_x nu
        depends on the parameters through the gain, which the plain filter neglects; with
        True, state-only filters at each parameter perturbation (relative step
        ``gain_step``, 1e-5) carry dK_x/dtheta, and after each update the covariance gets
        the term (dK_x/dtheta) nu in its state-parameter coupling (see
        :class:`_GainSensitivity`). With the noise known it makes the filter a recursive
        prediction-error estimator: on a roll axis whose gust acts through the damping
        (benchmarks/gain_sensitivity_mc.py) the std went from 1.2-1.5x too small to honest,
        and the empirical std of the damping down 24 %. With the noise wrong it is biased as
        any prediction-error method: on multiaxis_multisine_turbulence's lateral axis with
        the pipeline's twice-the-level process noise it ended further off than the plain
        filter (ad hoc), so the pipeline does not use it. It runs the Python loop only
        (``compiled`` is ignored; ~10x slower on the lateral gust model, ad hoc).

    Parameter bounds (``Parameter(bounds=...)``) hold: every update is projected onto
    them, and a sigma point or difference step beyond a bound evaluates the model at the
    bound. A parameter projected in the last pass and ending within 3 std of its bound is
    reported in ``at_bounds`` with its std NaN (``extra["bound_hits"]``: projections per
    parameter in the last pass).
    """

    method = "ekf"

    def __init__(self, model: Model, *, fd_step: float = 1e-6, **kw) -> None:
        super().__init__(model, **kw)
        self.fd_step = fd_step

    def _compiled_segment(self, aug, s, P, F, R, qth, lay, k, match):
        return self._run_compiled("ekf", aug, s, P, F, R, qth, lay, k, match, float(self.fd_step))

    def _columns(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = self.fd_step * np.maximum(np.abs(s), 1.0)
        S = np.repeat(s[:, None], s.size + 1, axis=1)
        S[np.arange(s.size), 1 + np.arange(s.size)] += h
        return S, h

    def _predict(self, aug, s, P, Q, i):
        n = aug.n
        S, h = self._columns(s)
        Xn = aug.step(S, i)
        Phi = np.eye(s.size)
        Phi[:n, :] = (Xn[:, 1:] - Xn[:, :1]) / h
        s_new = s.copy()
        s_new[:n] = Xn[:, 0]
        P = Phi @ P @ Phi.T + Q
        return s_new, 0.5 * (P + P.T)

    def _update(self, aug, s, P, z, ok, R, i):
        S, h = self._columns(s)
        Y = aug.outputs(S, i)
        y = Y[:, 0]
        if not np.any(ok):
            return s, P, y, None, None
        H = ((Y[:, 1:] - Y[:, :1]) / h)[ok]
        P, K, Sinn = _joseph_update(P, H, R[np.ix_(ok, ok)])
        return s + K @ (z[ok] - y[ok]), P, y, K, Sinn

    def _settings(self) -> dict[str, Any]:
        return {**super()._settings(), "fd_step": self.fd_step}


def _sqrt_psd(A: np.ndarray) -> np.ndarray:
    """A lower factor L with L L^T = A for a symmetric positive semi-definite A."""
    try:
        return np.linalg.cholesky(A)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(0.5 * (A + A.T))
        return V * np.sqrt(np.maximum(w, 0.0))


class UKF(_ParameterFilter):
    """Unscented Kalman filter with the parameters in the state.

    Scaled sigma points (van der Merwe): lambda = alpha^2 (L + kappa) - L, points
    s +- columns of sqrt((L + lambda) P), weights Wm0 = lambda / (L + lambda),
    Wc0 = Wm0 + 1 - alpha^2 + beta, Wi = 1 / (2 (L + lambda)). Defaults alpha = 1,
    beta = 2, kappa = 0 (Wm0 = 0: no negative weights, so P stays positive).

    augmented : False (default) adds Qd and R to the predicted covariances; True draws the
        sigma points from the noise-augmented state [s; w; v] (process noise w ~ N(0, Qd)
        added after the step, measurement noise v ~ N(0, R) added to g).
    Other keywords as :class:`EKF` (process_noise, measurement_noise, param_std, ...).
    """

    method = "ukf"

    def __init__(
        self, model: Model, *, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0, augmented: bool = False, **kw
    ) -> None:
        super().__init__(model, **kw)
        self.alpha, self.beta, self.kappa = float(alpha), float(beta), float(kappa)
        self.augmented = augmented
        if augmented:
            self.method = "ukf-aug"

    def _weights(self, L: int) -> tuple[np.ndarray, np.ndarray, float]:
        lam = self.alpha**2 * (L + self.kappa) - L
        Wm = np.full(2 * L + 1, 0.5 / (L + lam))
        Wc = Wm.copy()
        Wm[0] = lam / (L + lam)
        Wc[0] = Wm[0] + 1.0 - self.alpha**2 + self.beta
        return Wm, Wc, L + lam

    def _compiled_segment(self, aug, s, P, F, R, qth, lay, k, match):
        if self.augmented:  # noise-augmented sigma points: Python
            return None
        Wm, Wc, cfac = self._weights(s.size)
        return self._run_compiled("ukf", aug, s, P, F, R, qth, lay, k, match, Wm, Wc, float(cfac))

    def _sigmas(self, s: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        L = s.size
        Wm, Wc, c = self._weights(L)
        A = _sqrt_psd(c * P)
        S = np.concatenate([s[:, None], s[:, None] + A, s[:, None] - A], axis=1)
        return S, Wm, Wc

    def _predict(self, aug, s, P, Q, i):
        n, L = aug.n, s.size
        if self.augmented:
            Pa = np.zeros((2 * L, 2 * L))
            Pa[:L, :L] = P
            Pa[L:, L:] = Q
            Sa, Wm, Wc = self._sigmas(np.concatenate([s, np.zeros(L)]), Pa)
            S = Sa[:L].copy()
            S[:n] = aug.step(S, i)
            S = S + Sa[L:]
            mean = S @ Wm
            D = S - mean[:, None]
            P = (D * Wc) @ D.T
        else:
            S, Wm, Wc = self._sigmas(s, P)
            S = S.copy()
            S[:n] = aug.step(S, i)
            mean = S @ Wm
            D = S - mean[:, None]
            P = (D * Wc) @ D.T + Q
        return mean, 0.5 * (P + P.T)

    def _update(self, aug, s, P, z, ok, R, i):
        L = s.size
        if self.augmented:
            r = R.shape[0]
            Pa = np.zeros((L + r, L + r))
            Pa[:L, :L] = P
            Pa[L:, L:] = R
            Sa, Wm, Wc = self._sigmas(np.concatenate([s, np.zeros(r)]), Pa)
            S = Sa[:L]
            Y = aug.outputs(S, i) + Sa[L:]
            Rk = 0.0
        else:
            S, Wm, Wc = self._sigmas(s, P)
            Y = aug.outputs(S, i)
            Rk = R
        y = Y @ Wm
        if not np.any(ok):
            return s, P, y, None, None
        Dy = Y - y[:, None]
        Ds = S - s[:, None]
        Syy = (Dy * Wc) @ Dy.T + Rk
        Ssy = (Ds * Wc) @ Dy.T
        Syy, Ssy = Syy[np.ix_(ok, ok)], Ssy[:, ok]
        K = np.linalg.solve(Syy, Ssy.T).T
        s = s + K @ (z[ok] - y[ok])
        P = P - K @ Syy @ K.T
        return s, 0.5 * (P + P.T), y, K, Syy

    def _settings(self) -> dict[str, Any]:
        return {
            **super()._settings(),
            "alpha": self.alpha,
            "beta": self.beta,
            "kappa": self.kappa,
            "augmented": self.augmented,
        }
