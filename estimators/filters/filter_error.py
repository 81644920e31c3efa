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
  covariance and h the sample interval (Potter's method, :func:`continuous_gain`);
  K = P C^T R^-1.
* ``form="linear"``: prediction x~_{k+1} = Phi x^_k + Gamma0 (B u_k + f_0)
  + Gamma1 B (u_k+1 - u_k) (exact for inputs interpolated linearly between samples,
  :func:`input_integrals`; Gamma1 is left out for held inputs); ``form="nonlinear"``:
  prediction by one integrator step of the nonlinear f from x^_k (default RK4), outputs
  g(x~_k) of the nonlinear g, and the constant gain of the linearisation at the trim point.
* Correction x^_k = x~_k + K (z_k - y~_k). A sample where only the outputs o are measured
  (NaN = missing: multi-rate data) is corrected with the gain of those outputs,
  K_o = P C_o^T R_oo^-1 (``output_patterns``, ``pattern_gains``).

Estimation, by relaxation:

1. R, the diagonal covariance of the innovations, in closed form: R = diag(1/N sum nu nu^T)
   (at the start from the start model run without a gain, or the given std).
2. For that R, Gauss-Newton on phi = [theta, F]: M = sum S^T R^-1 S, g = sum S^T R^-1 nu,
   with S = d y~/d phi from forward differences (they include the gain's gradients
   dK/dphi), all perturbed parameter sets filtered in one batch; the step respects
   diag(C K) <= 1 (the implied measurement noise R - C P C^T stays non-negative), step
   halving on det(R), then Levenberg-Marquardt damping.
3. From the ``r_update_from``-th iteration on, R is re-estimated after each step and F
   compensated for the change (Maine and Iliff, :meth:`FilterError._compensate`).

R is full by default (``full_R``; the reference keeps its diagonal), and the sampled
filter's P solves the discrete equation of :func:`discrete_gain` (the reference's
continuous form is its start). The Cramér-Rao bounds are those of phi with R estimated
too (:meth:`FilterError._marginal_information`).

The cost is det(R), the likelihood with R concentrated out; the fit has converged when its
relative change and R's have settled. R is never a free parameter of the Gauss-Newton
step, so it cannot collapse to zero.

Result: an :class:`~estimators.EstimationResult`; ``predicted`` are the one-step
predictions y~_k, ``residuals`` the innovations, ``R`` their sample covariance;
``extra`` holds ``gain`` (K per segment), ``F`` (n, n), ``innovation_cov`` (the R the gain
used, per segment), ``measurement_noise`` (R - C P C^T, diagonal), ``P``, ``A/B/C/D``
(linearisation per segment) and ``filtered_states``.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd
from scipy import linalg

from estimators import statistics as st
from estimators.compile.kernels import (
    adapter_source,
    bound_source,
    compile_user_function,
    first_line,
    kernel_for,
    load_kernels,
    probe_point,
)
from estimators.errors import ModelDefinitionError, SimulationDivergedError
from estimators.filters.kalman import (
    SEGMENT_HELPERS,
    _ekf_segment,
    _ukf_segment,
    default_process_noise,
    is_name_list,
    named_process_noise,
)
from estimators.model import Model, Segment, check_outputs_measured
from estimators.results import EstimationResult, frames
from estimators.sensitivity import Sensitivity, add_block
from estimators.simulation.integrators import DEFAULT_INPUTS, INTEGRATORS, check_options
from estimators.simulation.simulate import Layout

try:
    import numba
except ImportError:  # pragma: no cover
    numba = None


def _coloured_innovation_cov(M: np.ndarray, M_S: np.ndarray, parts: list) -> tuple[np.ndarray, list[int]]:
    """Covariance of the filter-error estimates when the innovations are not white
    (Morelli-Klein on the innovations): M^-1 (M - M_S + M_S~) M^-1, where M_S = sum S^T
    B^-1 S is the part of the information M carried by the innovation sensitivities S (as
    FilterError._scoring summed it) and M_S~ the same sum with the innovations' own
    autocorrelation in place of B
    (:func:`estimators.validation.uncertainty.coloured_information`). The part of M from
    the innovation covariance's dependence on the parameters (dB/dtheta) is kept as it is.
    White innovations give M^-1 back; a filter model that misses some of the process
    (coloured innovations) gets wider bounds. parts: per segment (S (N, m, n_p), E (N, m),
    B^-1 (m, m), rows used (N,)). Returns ((n_p, n_p), lag per segment)."""
    from estimators.validation.uncertainty import coloured_information

    mid, lags = coloured_information(
        [p[0] for p in parts],
        [p[1] for p in parts],
        [p[2] for p in parts],
        [np.repeat(p[3][:, None], p[1].shape[1], axis=1) for p in parts],
    )
    Minv = st.covariance(M)
    cov = Minv @ (M - M_S + mid) @ Minv
    return 0.5 * (cov + cov.T), lags


def _kf_loop(Phi, K, pat, C, drive, offset, Z, x0):
    """Steady-state Kalman filter over a batch of linear systems.

    Phi (B, n, n), K (B, n_pat, n, m) the gain per pattern of measured outputs (zero
    columns for the missing ones, :func:`pattern_gains`), pat (N,) the pattern of each
    sample, C (B, m, n), drive (B, N, n) = Gamma (B u + f0), offset (B, N, m) = D u + y0,
    Z (N, m) with NaN = missing, x0 (B, n).
    Returns predicted outputs Y (B, N, m) and a-posteriori states X (B, N, n).
    """
    Bn, n, _ = Phi.shape
    N, m = Z.shape
    Y = np.empty((Bn, N, m))
    X = np.empty((Bn, N, n))
    nu = np.empty(m)
    xh = np.empty(n)
    for b in range(Bn):
        x = x0[b].copy()
        for k in range(N):
            for j in range(m):
                y = offset[b, k, j]
                for i in range(n):
                    y += C[b, j, i] * x[i]
                Y[b, k, j] = y
                d = Z[k, j] - y
                nu[j] = d if np.isfinite(d) else 0.0
            pk = pat[k]
            for i in range(n):
                v = x[i]
                for j in range(m):
                    v += K[b, pk, i, j] * nu[j]
                xh[i] = v
                X[b, k, i] = v
            if k + 1 < N:
                for i in range(n):
                    v = drive[b, k, i]
                    for j in range(n):
                        v += Phi[b, i, j] * xh[j]
                    x[i] = v
    return Y, X


if numba is not None:
    _kf_loop_jit = numba.njit(cache=True)(_kf_loop)
else:  # pragma: no cover
    _kf_loop_jit = _kf_loop


def linearize_batch(
    model: Model, P: np.ndarray, xr: np.ndarray, ur: np.ndarray, constants: Mapping[str, float], rel_step: float = 1e-5
):
    """A (B, n, n), Bu (B, n, ni), C (B, m, n), D (B, m, ni), f0 (B, n), y0 (B, m) of the
    affine approximation f ~ A x + Bu u + f0, g ~ C x + D u + y0 about (xr (n, B), ur (ni,))
    for the parameter columns P (n_p, B); central differences, all columns in one call."""
    n, Bc = xr.shape
    ni = ur.size
    L = n + ni
    v0 = np.concatenate([xr, np.repeat(ur[:, None], Bc, axis=1)], axis=0)  # (L, B)
    h = rel_step * np.maximum(np.abs(v0), 1.0)  # (L, B)
    V = np.repeat(v0[:, :, None], 1 + 2 * L, axis=2)  # (L, B, E)
    idx = np.arange(L)
    V[idx, :, 1 + idx] += h
    V[idx, :, 1 + L + idx] -= h
    Vf = V.reshape(L, -1)
    Pf = np.repeat(P[:, :, None], 1 + 2 * L, axis=2).reshape(P.shape[0], -1)
    with np.errstate(all="ignore"):
        fv = model.eval_f(Vf[:n], Vf[n:], Pf, constants).reshape(n, Bc, -1)
        gv = model.eval_g(Vf[:n][:, None, :], Vf[n:][:, None, :], Pf, constants)[:, 0, :]
    gv = gv.reshape(len(model.outputs), Bc, -1)
    Jf = (fv[:, :, 1 : 1 + L] - fv[:, :, 1 + L :]) / (2 * h.T[None, :, :])  # (n, B, L)
    Jg = (gv[:, :, 1 : 1 + L] - gv[:, :, 1 + L :]) / (2 * h.T[None, :, :])
    Jf = Jf.transpose(1, 0, 2)
    Jg = Jg.transpose(1, 0, 2)
    A, Bu = Jf[:, :, :n], Jf[:, :, n:]
    C, D = Jg[:, :, :n], Jg[:, :, n:]
    x_r = xr.T
    f0 = fv[:, :, 0].T - np.einsum("bij,bj->bi", A, x_r) - Bu @ ur
    y0 = gv[:, :, 0].T - np.einsum("bij,bj->bi", C, x_r) - D @ ur
    return A, Bu, C, D, f0, y0


def is_affine(model: Model, segments: Sequence[Segment], layout: Layout, rtol: float = 1e-6) -> bool:
    """Whether f and g are affine in (x, u) over the data: the linearisation (A, B, C, D)
    about each segment's start equals the one about a point moved by the data's range
    (measured states by their range in z, the others by 10 % of |x0| + 0.1, inputs by
    their range in u), within ``rtol`` of the largest entry; parameters and initial
    states are the layout's values."""
    values = layout.values
    for k, seg in enumerate(segments):
        P = values[layout.pidx[k]][:, None]
        x0 = values[layout.x0idx[k]]
        dx = 0.1 * np.abs(x0) + 0.1
        for i, s in enumerate(model.states):
            z = seg.z[:, model.outputs.index(s)] if s in model.outputs else np.array([np.nan])
            if np.any(np.isfinite(z)) and np.nanmax(z) > np.nanmin(z):
                dx[i] = np.nanmax(z) - np.nanmin(z)
        du = np.ptp(seg.u, axis=0)
        du = np.where(du > 0, du, 0.1 * np.abs(seg.u[0]) + 0.1)
        c = model.constants_for(seg)
        a = linearize_batch(model, P, x0[:, None], seg.u[0], c)[:4]
        b = linearize_batch(model, P, (x0 + 0.5 * dx)[:, None], seg.u[0] + 0.5 * du, c)[:4]
        for ma, mb in zip(a, b):
            scale = max(np.max(np.abs(ma)), np.max(np.abs(mb)), 1e-12)
            if not np.all(np.isfinite(ma)) or not np.all(np.isfinite(mb)) or np.max(np.abs(ma - mb)) > rtol * scale:
                return False
    return True


def _mm(A, B):
    """A @ B as plain loops (small matrices, compiled)."""
    n, k = A.shape
    m = B.shape[1]
    out = np.zeros((n, m))
    for i in range(n):
        for l in range(k):
            a = A[i, l]
            if a != 0.0:
                for j in range(m):
                    out[i, j] += a * B[l, j]
    return out


if numba is not None:
    _mm = numba.njit(cache=True)(_mm)


def _expm_small(M):
    """e^M by scaling and squaring with a degree-16 Taylor polynomial, written as plain
    loops so that small matrices (n <= ~20) do not go through threaded BLAS/LAPACK (whose
    start-up cost dominates, and which stalls when the cores are busy)."""
    n = M.shape[0]
    norm = 0.0
    for i in range(n):
        r = 0.0
        for j in range(n):
            r += abs(M[i, j])
        norm = max(norm, r)
    s = 0
    while norm > 0.25:
        norm *= 0.5
        s += 1
    A = M / (2.0**s)
    E = np.eye(n)
    T = np.eye(n)
    for k in range(1, 17):
        T = _mm(T, A) / k
        E += T
    for _ in range(s):
        E = _mm(E, E)
    return E


if numba is not None:
    _expm_small = numba.njit(cache=True)(_expm_small)


def expm(M: np.ndarray) -> np.ndarray:
    """Matrix exponential: compiled Taylor scaling-and-squaring for small matrices,
    scipy.linalg.expm otherwise (and for non-finite input)."""
    if M.shape[0] <= 24 and np.all(np.isfinite(M)):
        return _expm_small(np.ascontiguousarray(M, dtype=float))
    return linalg.expm(M)


def discretize(A: np.ndarray, FFt: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Phi = e^{A h}, Gamma = int_0^h e^{As} ds, Qd = int_0^h e^{As} F F^T e^{A^T s} ds (van
    Loan) for one system: A (n, n), FFt (n, n), h (s)."""
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = A
    M[:n, n:] = np.eye(n)
    E = expm(M * h)
    Phi, Gam = E[:n, :n], E[:n, n:]
    if not np.any(FFt):
        return Phi, Gam, np.zeros((n, n))
    V = np.zeros((2 * n, 2 * n))
    V[:n, :n] = -A
    V[:n, n:] = FFt
    V[n:, n:] = A.T
    W = expm(V * h)
    Qd = Phi @ W[:n, n:]
    return Phi, Gam, 0.5 * (Qd + Qd.T)


def input_integrals(A: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Phi = e^{A h}, Gamma0 = int_0^h e^{As} ds and Gamma1 = int_0^h e^{A(h-s)} s ds / h for
    one system A (n, n): over a sample interval the input enters as Gamma0 B u_k for a held
    input plus Gamma1 B (u_k+1 - u_k) for one interpolated linearly (first-order hold, the
    exact counterpart of the integrators' stage-time interpolation)."""
    n = A.shape[0]
    M = np.zeros((3 * n, 3 * n))
    M[:n, :n] = A * h
    M[:n, n : 2 * n] = np.eye(n) * h
    M[n : 2 * n, 2 * n :] = np.eye(n)
    E = expm(M)
    return E[:n, :n], E[:n, n : 2 * n], E[:n, 2 * n :]


def continuous_gain(
    A: np.ndarray, C: np.ndarray, FFt: np.ndarray, R: np.ndarray, h: float
) -> tuple[np.ndarray, np.ndarray]:
    """Steady-state P (B, n, n) and gain K = P C^T R^-1 (B, n, m) of the filter-error method
    for a batch of linearisations A (B, n, n), C (B, m, n) and process noise FFt (B, n, n),
    with R (m, m) the innovation covariance and h the sample interval (s).

    P solves A P + P A^T - P C^T (R h)^-1 C P + F F^T = 0 (the reference software's
    continuous form of the Riccati equation with the innovation covariance in place of the
    measurement noise), by Potter's method: the eigenvectors of the Hamiltonian
    [[A, -F F^T], [-C^T R^-1 C / h, -A^T]] for its eigenvalues of positive real part give
    P = -E11 E21^-1, all columns in one batched eigen-decomposition. A column where that
    fails (an eigenvalue on the imaginary axis) is solved by scipy's Schur method; NaN
    where neither has a stabilising solution. Columns without process noise get P = 0."""
    Bc, n, _ = A.shape
    Ri = np.linalg.inv(R)
    P = np.zeros((Bc, n, n))
    noisy = np.any(FFt.reshape(Bc, -1) != 0.0, axis=1)
    if np.any(noisy):
        a, c, q = A[noisy], C[noisy], FFt[noisy]
        H = np.block([[a, -q], [-np.einsum("bji,jk,bkl->bil", c, Ri, c) / h, -a.transpose(0, 2, 1)]])
        with np.errstate(all="ignore"):
            ok = np.all(np.isfinite(H.reshape(H.shape[0], -1)), axis=1)
            Pn = np.full((H.shape[0], n, n), np.nan)
            if np.any(ok):
                w, V = np.linalg.eig(H[ok])
                order = np.argsort(w.real, axis=1)[:, n:]
                E = np.take_along_axis(V, order[:, None, :], axis=2)
                wr = np.take_along_axis(w.real, order, axis=1)
                sol = -E[:, :n] @ np.linalg.pinv(E[:, n:])
                good = (np.min(wr, axis=1) > 1e-9 * np.max(np.abs(w), axis=1, initial=1.0)) & np.all(
                    np.abs(sol.imag) <= 1e-8 * (1.0 + np.abs(sol.real)), axis=(1, 2)
                )
                Pn[ok] = np.where(good[:, None, None], sol.real, np.nan)
        for b in np.flatnonzero(~np.all(np.isfinite(Pn.reshape(Pn.shape[0], -1)), axis=1)):
            try:
                Pn[b] = linalg.solve_continuous_are(a[b].T, c[b].T, q[b], R * h)
            except (np.linalg.LinAlgError, ValueError):
                Pn[b] = np.nan
        P[noisy] = 0.5 * (Pn + Pn.transpose(0, 2, 1))
    K = np.einsum("bij,bkj,kl->bil", P, C, Ri)
    return P, K


def discrete_gain(
    A: np.ndarray, C: np.ndarray, FFt: np.ndarray, R: np.ndarray, h: float, max_iter: int = 12
) -> tuple[np.ndarray, np.ndarray]:
    """Steady-state a-priori P (B, n, n) and gain K = P C^T R^-1 (B, n, m) of the sampled
    filter for a batch of linearisations A (B, n, n), C (B, m, n), process noise FFt
    (B, n, n), the innovation covariance R (m, m) and the sample interval h (s).

    P solves P = Phi (P - P C^T R^-1 C P) Phi^T + Qd (Phi, Qd of :func:`discretize`): the
    Kalman filter's prediction of its own a-posteriori covariance when R is the innovation
    covariance. Newton's method from the continuous form's solution
    (:func:`continuous_gain`, the reference software's, which it approaches as h -> 0),
    batched over columns; the continuous solution is kept for a column where Newton does
    not settle. NaN where neither exists."""
    Bc, n, _ = A.shape
    P, K = continuous_gain(A, C, FFt, R, h)
    noisy = np.any(FFt.reshape(Bc, -1) != 0.0, axis=1) & np.all(np.isfinite(P.reshape(Bc, -1)), axis=1)
    if not np.any(noisy):
        return P, K
    idx = np.flatnonzero(noisy)
    Ri = np.linalg.inv(R)
    Phi = np.empty((idx.size, n, n))
    Q = np.empty((idx.size, n, n))
    for j, b in enumerate(idx):
        Phi[j], _, Q[j] = discretize(A[b], FFt[b], h)
    Mm = np.einsum("bji,jk,bkl->bil", C[idx], Ri, C[idx])
    X = P[idx].copy()
    eye = np.eye(n * n)
    scale = np.abs(Q).reshape(idx.size, -1).max(axis=1) + 1e-300
    done = np.zeros(idx.size, dtype=bool)
    with np.errstate(all="ignore"):
        for _ in range(max_iter):
            XM = X @ Mm
            f = Phi @ (X - XM @ X) @ Phi.transpose(0, 2, 1) + Q - X
            err = np.abs(f).reshape(idx.size, -1).max(axis=1) / scale
            done = np.isfinite(err) & (err < 1e-12)
            if np.all(done | ~np.isfinite(err)):
                break
            PXM = Phi @ XM
            J = (
                np.einsum("bij,bkl->bikjl", Phi, Phi)
                - np.einsum("bij,bkl->bikjl", Phi, PXM)
                - np.einsum("bij,bkl->bikjl", PXM, Phi)
            ).reshape(idx.size, n * n, n * n) - eye
            try:
                dX = np.linalg.solve(J, -f.reshape(idx.size, n * n, 1)).reshape(idx.size, n, n)
            except np.linalg.LinAlgError:
                break
            X = X + np.where(done[:, None, None], 0.0, dX)
            X = 0.5 * (X + X.transpose(0, 2, 1))
    good = done & np.all(np.isfinite(X.reshape(idx.size, -1)), axis=1)
    P[idx[good]] = X[good]
    K = np.einsum("bij,bkj,kl->bil", P, C, Ri)
    return P, K


# -- compiled nonlinear filter loop ----------------------------------------------------------
_OUT_KERNELS: dict = {}


def output_kernel(model: Model):
    """The model's compiled filter kernels (a module, kept on disk by
    :func:`estimators.compile.kernels.load_kernels`): ``gout(x (n, B), u (n_in,), P (n_p, B), c,
    out (n_out, B))``, g in the integrators' calling convention (output biases added), and
    ``nl_loop_<integrator>(x0, U, t, P, c, K, pat, Z, rtol, atol, mode)``, :func:`_nl_loop`
    with the model's rhs and gout; None when g does not compile or disagrees with the numpy
    evaluation."""
    # f too: the module's filter loops call the model's rhs
    key = (
        model.f,
        model.g,
        tuple(model.states),
        tuple(model.inputs),
        tuple(model.parameter_names),
        tuple(model.outputs),
        tuple(model.output_biases),
        tuple(sorted(model.constants)),
    )
    if key in _OUT_KERNELS:
        return _OUT_KERNELS[key]
    mod, why = None, ""
    kern = kernel_for(model)
    for helpers in (False, True) if numba is not None and kern.prepare() else ():
        mod, why = _output_kernel(model, kern, helpers)
        if mod is not None:
            break
    if mod is None and why:
        # f compiled (else it has said so itself) but g did not
        warnings.warn(
            f"model {model.name!r}: g could not be compiled with numba ({why}); the filter "
            "loop runs with numpy, which is slower. Write g with numpy functions and "
            "arithmetic on the unpacked rows to get the compiled path.",
            RuntimeWarning,
            stacklevel=3,
        )
    _OUT_KERNELS[key] = mod
    return mod


def _output_kernel(model: Model, kern, helpers: bool):
    """The compiled output kernel module of :func:`output_kernel`, g as written (``helpers``
    False) or with the plain helper functions it calls compiled too, and "" - or None and
    why, when it fails or disagrees with the numpy evaluation."""
    try:
        n, ni, m = len(model.states), len(model.inputs), len(model.outputs)
        names = model.parameter_names
        # g, or for a model with outputs selected (Model.select_outputs) the full g and the
        # rows to keep
        g_full, rows = getattr(model.g, "selects", (model.g, tuple(range(m))))
        bias = [(model.outputs.index(o), names.index(f"bias_{o}")) for o in model.output_biases]
        # one filter loop per integrator, with the rhs module's integrate_<scheme> and this
        # module's gout called as globals (estimators.compile.kernels.bound_source)
        loops = [
            bound_source(
                _nl_loop,
                "scheme, rhs, gout, ",
                {"def _nl_loop(": f"def nl_loop_{s}(", "scheme(rhs, ": f"_integrate_{s}("},
            )
            + f"nl_loop_{s} = numba.njit(error_model='numpy', cache=CACHE)(nl_loop_{s})"
            for s in INTEGRATORS
        ]
        # the EKF's and UKF's segment loops (estimators.filters.kalman) on the same rhs and g
        loops += [
            bound_source(h, "") + f"{h.__name__} = numba.njit(error_model='numpy', cache=CACHE)({h.__name__})"
            for h in SEGMENT_HELPERS
        ]
        loops += [
            bound_source(
                fn, "scheme, gout, ", {f"def _{w}_segment(": f"def {w}_segment_{s}(", "scheme(": f"_integrate_{s}("}
            )
            + f"{w}_segment_{s} = numba.njit(error_model='numpy', cache=CACHE)({w}_segment_{s})"
            for w, fn in (("ekf", _ekf_segment), ("ukf", _ukf_segment))
            for s in INTEGRATORS
        ]
        src = "\n".join(
            [
                f"# fsid compiled filter loop of model {model.name!r} (generated by estimators.filters.filter_error; safe to delete)",
                f"# g: {getattr(g_full, '__module__', '?')}.{getattr(g_full, '__qualname__', '?')}, "
                f"helpers compiled: {helpers}; rhs: {getattr(kern.module, '__name__', 'in memory')}",
                "from collections import namedtuple",
                "import numba",
                "import numpy as np",
                f"Params = namedtuple('Params', {list(names)!r})",
                *adapter_source("gout", "_g", n, ni, len(names), rows, [f"    out[{j}, :] += P[{i}]" for j, i in bias]),
                *loops,
                "",
            ]
        )
        gj = compile_user_function(g_full) if helpers else numba.njit(error_model="numpy")(g_full)
        steps = {f"_integrate_{s}": getattr(kern.module, f"integrate_{s}") for s in INTEGRATORS}
        mod = load_kernels(
            src, {"_g": gj, **steps}, [g_full, model.f], "fsid_filter", package=("filters/filter_error.py",)
        )
        # check once against numpy
        x, u, P = probe_point(model)
        a = np.empty((m, 2))
        mod.gout(x, u, P, kern._c_jit(model.constants), a)
        with np.errstate(all="ignore"):
            b = model.eval_g(x[:, None, :], u[:, None, None], P, model.constants)[:, 0, :]
        if np.allclose(a, b, rtol=1e-9, atol=1e-12, equal_nan=True):
            return mod, ""
        return None, "compiled and numpy outputs differ"
    except Exception as exc:  # the numpy loop is used instead
        return None, first_line(exc)


def _nl_loop(scheme, rhs, gout, x0, U, t, P, c, K, pat, Z, rtol, atol, mode):
    """Constant-gain filter with integrator prediction, batched over parameter columns:
    x0 (n, B), P (n_p, B), K (B, n_pat, n, m) per pattern of measured outputs, pat (N,),
    Z (N, m). Returns Y (B, N, m), X (B, N, n)."""
    n, Bc = x0.shape
    N, m = Z.shape
    Y = np.full((Bc, N, m), np.nan)
    X = np.full((Bc, N, n), np.nan)
    x = x0.copy()
    y = np.empty((m, Bc))
    xh = np.empty((n, Bc))
    nu = np.empty(m)
    alive = np.ones(Bc, dtype=np.bool_)
    for i in range(N):
        gout(x, U[i], P, c, y)
        for b in range(Bc):
            for j in range(m):
                d = Z[i, j] - y[j, b]
                nu[j] = d if np.isfinite(d) else 0.0
                Y[b, i, j] = y[j, b]
            for r in range(n):
                v = x[r, b]
                for j in range(m):
                    v += K[b, pat[i], r, j] * nu[j]
                xh[r, b] = v
                X[b, i, r] = v
        if i + 1 < N:
            # the integrators stop a whole batch when any column becomes non-finite; a
            # diverging perturbed or trial column must not take the others with it, so
            # only live columns are stepped and a failed batch step is redone per column
            idx = np.flatnonzero(alive)
            if idx.size == 0:
                break
            Xs = scheme(rhs, xh[:, idx], U[i : i + 2], t[i : i + 2], P[:, idx], c, rtol, atol, mode)
            ok_all = True
            for r in range(n):
                for jj in range(idx.size):
                    if not np.isfinite(Xs[1, r, jj]):
                        ok_all = False
            if ok_all:
                for r in range(n):
                    for jj in range(idx.size):
                        x[r, idx[jj]] = Xs[1, r, jj]
            else:
                for jj in range(idx.size):
                    b = idx[jj]
                    Xb = scheme(
                        rhs,
                        xh[:, b : b + 1].copy(),
                        U[i : i + 2],
                        t[i : i + 2],
                        P[:, b : b + 1].copy(),
                        c,
                        rtol,
                        atol,
                        mode,
                    )
                    fin = True
                    for r in range(n):
                        if not np.isfinite(Xb[1, r, 0]):
                            fin = False
                    if fin:
                        for r in range(n):
                            x[r, b] = Xb[1, r, 0]
                    else:
                        alive[b] = False
                        for r in range(n):
                            x[r, b] = np.nan
    return Y, X


def output_patterns(Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The patterns of measured (finite) outputs in Z (N, m): (masks (n_pat, m) bool, the
    pattern index of each sample (N,)). One pattern when every output is measured at
    every sample; multi-rate data (a 10 Hz airspeed on a 50 Hz grid) have several."""
    masks, pat = np.unique(np.isfinite(Z), axis=0, return_inverse=True)
    return masks, np.ascontiguousarray(pat.reshape(-1), dtype=np.int64)


def pattern_gains(Pp: np.ndarray, C: np.ndarray, B: np.ndarray, K: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """Steady-state gains per pattern of measured outputs, (Bc, n_pat, n, m): for the
    outputs o measured, K_o = P C_o^T B_oo^-1 (P the a-priori covariance, B = C P C^T + R)
    in their columns, zero in the others; the full gain K where every output is measured.
    (The full K's columns are not the subset's gain: B^-1 couples the outputs.)"""
    Bc, n, m = K.shape
    out = np.zeros((Bc, masks.shape[0], n, m))
    for p, o in enumerate(masks):
        if o.all():
            out[:, p] = K
        elif o.any():
            PCt = np.einsum("bij,bkj->bik", Pp, C[:, o, :])  # (Bc, n, m_o)
            with np.errstate(all="ignore"):
                out[:, p][:, :, o] = np.linalg.solve(B[:, o][:, :, o], PCt.transpose(0, 2, 1)).transpose(0, 2, 1)
    return np.nan_to_num(out)


#: relative change of the innovation covariance's diagonal under which the relaxation has
#: settled (with det(R) settled too, the fit has converged)
R_SETTLED = 1e-2

#: largest deviation of a sample interval from the segment's median interval (relative)
#: that the filter-error method accepts: the steady-state gain, and in the linear form the
#: transition matrices, are those of the median interval
JITTER_TOL = 0.05


def sample_interval(seg: Segment, k: int = 0) -> float:
    """The segment's sample interval h (s): the median of its intervals, which may deviate
    from it by up to JITTER_TOL (timestamp jitter of a logger); larger deviations (gaps,
    rate changes, time going backwards) raise ModelDefinitionError saying where."""
    dt = np.diff(seg.t)
    h = float(np.median(dt))
    dev = np.abs(dt - h) / h if h > 0 else np.full(dt.shape, np.inf)
    if dt.size and dev.max() > JITTER_TOL:
        i = int(np.argmax(dev))
        raise ModelDefinitionError(
            f"segment {seg.name or k}: the filter-error method needs a constant sample interval; "
            f"at t={seg.t[i]:.6g} s the step is {dt[i]:.6g} s against a median of {h:.6g} s "
            f"({dev[i]:.0%} off, {JITTER_TOL:.0%} accepted): resample the data to a constant "
            f"rate, or split the segment there (Segment.split_at_gaps(factor={1 + JITTER_TOL:g})) "
            "and fit the pieces as a list of segments"
        )
    return h


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
    form : "auto" (default: "linear" when f and g are affine in x and u over the data,
        :func:`is_affine`, else "nonlinear"), "linear" (transition matrix of the
        linearisation at each segment's start: exact for linear models only) or
        "nonlinear" (integrator prediction, gain of the linearisation at the trim point).
    integrator : the one-step predictor of the nonlinear form.
    max_iter, tol : Gauss-Newton iterations; stop when the relative change of det(R) is
        below ``tol`` after an iteration that updated R.
    fd_step : relative forward-difference step of the sensitivities.
    step_halvings : maximum halvings of a step that does not lower det(R).
    r_update_from : first iteration after which R is re-estimated and F compensated (the
        reference software waits until its third; from the first, a start R far from the
        innovations - the output-error residuals of a start in turbulence - weights the
        early steps less wrongly).
    full_R : estimate the full innovation covariance (default; the likelihood's) or only
        its diagonal (the reference software's): a diagonal R ignores the correlation the
        process noise puts between the innovations, and the F that makes up for it is
        biased.
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
        form: str = "auto",
        integrator: str = "rk4",
        max_iter: int = 40,
        tol: float = 1e-4,
        fd_step: float = 1e-6,
        step_halvings: int = 10,
        r_update_from: int = 1,
        inputs: str = DEFAULT_INPUTS,
        compiled: bool = True,
        full_R: bool = True,
        callback=None,
    ) -> None:
        if form not in ("auto", "linear", "nonlinear"):
            raise ModelDefinitionError(f"form must be 'auto', 'linear' or 'nonlinear', not {form!r}")
        check_options(integrator, inputs)
        self.model = model
        self.process_noise = process_noise
        self.estimate_F = estimate_F
        self.measurement_noise = measurement_noise
        self.form_requested = form
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

    # -- parameter vector phi = [layout free, F_i] -----------------------------------------------
    def _noise_setup(self, segments: Sequence[Segment]) -> tuple[list[int], np.ndarray]:
        m = self.model
        n = len(m.states)
        spec = self.process_noise
        if spec is None:
            f0 = default_process_noise(m, segments)
        elif is_name_list(spec):
            f0 = named_process_noise(m, spec, segments)
        elif isinstance(spec, Mapping):
            bad = sorted(set(spec) - set(m.states))
            if bad:
                raise ModelDefinitionError(f"process_noise: {bad} are not states {m.states}")
            f0 = np.array([float(spec.get(s, 0.0)) for s in m.states])
        else:
            f0 = np.asarray(spec, dtype=float).ravel()
            if f0.size != n:
                raise ModelDefinitionError(f"process_noise needs {n} entries (states {m.states})")
        noisy = [i for i in range(n) if f0[i] > 0]
        return noisy, f0

    def _unpack(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """theta (n_all,) and F (n, n) from phi (free vector)."""
        theta = self._lay.values.copy()
        nf = self._lay.free_idx.size
        theta[self._lay.free_idx] = phi[:nf]
        fvec = self._f_fixed.copy()
        if self.estimate_F:
            fvec[self._noisy] = np.maximum(phi[nf : nf + len(self._noisy)], 0.0)
        return theta, np.diag(fvec)

    # -- filtering a batch of parameter vectors ------------------------------------------------
    def _filter(
        self, Phis: np.ndarray, R: np.ndarray, rows: Sequence[np.ndarray] | None = None, gain: bool = True
    ) -> list[dict[str, Any]]:
        """For parameter columns Phis (Bc, n_phi) and innovation covariance R (m, m): per
        segment the predicted outputs Y (Bc_k, N, m), gain K (Bc_k, n, m), P, diag(C K)
        (Bc_k, m), filtered states and the linearisation of column 0. ``rows``: per segment
        the columns of Phis to run (column 0 first; default all): a sensitivity batch needs
        only the parameters the segment depends on (:meth:`_segment_rows`). ``gain`` False
        runs without a gain (K = 0: the output-error simulation)."""
        model = self.model
        n, m = len(model.states), len(model.outputs)
        unpacked = [self._unpack(p) for p in Phis]
        Theta_all = np.stack([u[0] for u in unpacked])
        FF_all = np.stack([u[1] @ u[1].T for u in unpacked])
        if not gain:
            FF_all[:] = 0.0
        out = []
        for k, seg in enumerate(self._segments):
            idx = np.arange(Phis.shape[0]) if rows is None else rows[k]
            Bc = idx.size
            Theta = Theta_all[idx]
            lay = self._lay
            P = np.ascontiguousarray(Theta[:, lay.pidx[k]].T)
            X0 = np.ascontiguousarray(Theta[:, lay.x0idx[k]].T)
            c = model.constants_for(seg)
            A, Bu, C, D, f0, y0 = linearize_batch(model, P, X0, seg.u[0], c)
            h = self._h[k]
            with np.errstate(all="ignore"):
                Pp, Kg = discrete_gain(A, C, FF_all[idx], R, h)
            ok = np.all(np.isfinite(Kg.reshape(Bc, -1)), axis=1)
            Z = np.ascontiguousarray(seg.z)
            masks, pat = self._patterns[k]
            Kp = pattern_gains(Pp, C, np.repeat(R[None], Bc, axis=0), Kg, masks)
            if self.form == "linear":
                Y = np.full((Bc, seg.n, m), np.nan)
                Xf = np.full((Bc, seg.n, n), np.nan)
                drive = np.empty((Bc, seg.n, n))
                Phi = np.empty((Bc, n, n))
                du = np.vstack([np.diff(seg.u, axis=0), np.zeros((1, seg.u.shape[1]))])
                for b in range(Bc):
                    Phi[b], G0, G1 = input_integrals(A[b], h)
                    drive[b] = (Bu[b] @ seg.u.T + f0[b][:, None]).T @ G0.T
                    if self.inputs == "linear":
                        drive[b] += (Bu[b] @ du.T).T @ G1.T
                offset = np.einsum("bij,nj->bni", D, seg.u) + y0[:, None, :]
                if np.any(ok):
                    Y[ok], Xf[ok] = _kf_loop_jit(
                        np.ascontiguousarray(Phi[ok]),
                        np.ascontiguousarray(Kp[ok]),
                        pat,
                        np.ascontiguousarray(C[ok]),
                        np.ascontiguousarray(drive[ok]),
                        np.ascontiguousarray(offset[ok]),
                        Z,
                        np.ascontiguousarray(X0.T[ok]),
                    )
            else:
                Y, Xf = self._nonlinear_loop(seg, k, P, X0, Kg, Kp, pat, c)
            CK = np.einsum("bij,bji->bi", C, Kg)
            out.append({"Y": Y, "K": Kg, "P": Pp, "X": Xf, "CK": CK, "C": C, "lin": (A[0], Bu[0], C[0], D[0])})
        return out

    def _nonlinear_loop(
        self,
        seg: Segment,
        k: int,
        P: np.ndarray,
        X0: np.ndarray,
        Kg: np.ndarray,
        Kp: np.ndarray,
        pat: np.ndarray,
        c: Mapping[str, float],
    ):
        """Integrator prediction and nonlinear outputs, constant gain per pattern of measured
        outputs (Kp (Bc, n_pat, n, m), pat (N,); Kg the full gain, NaN where the Riccati
        equation failed), batched over columns."""
        model = self.model
        kern = kernel_for(model)
        N, m = seg.n, len(model.outputs)
        n, Bc = X0.shape
        kmod = output_kernel(model) if self.compiled else None
        if kmod is not None:
            from estimators.simulation import integrators as _integ

            Y, Xf = getattr(kmod, f"nl_loop_{self.integrator}")(
                np.ascontiguousarray(X0, dtype=float),
                np.ascontiguousarray(seg.u),
                seg.t,
                np.ascontiguousarray(P, dtype=float),
                kern._c_jit(c),
                np.ascontiguousarray(Kp),
                pat,
                np.ascontiguousarray(seg.z),
                1e-8,
                1e-10,
                _integ.INPUT_MODES[self.inputs],
            )
            # a diverging column is not an error here: its non-finite predictions make the
            # cost infinite, so a trial step that causes it is rejected
            bad = ~np.all(np.isfinite(Kg.reshape(Bc, -1)), axis=1)
            Y[bad] = np.nan
            return Y, Xf
        Y = np.full((Bc, N, m), np.nan)
        Xf = np.full((Bc, N, n), np.nan)
        x = X0.copy()
        alive = np.ones(Bc, dtype=bool)
        for i in range(N):
            with np.errstate(all="ignore"):
                y = model.eval_g(x[:, None, :], seg.u[i][:, None, None], P, c)[:, 0, :]  # (m, Bc)
            nu = seg.z[i][:, None] - y
            nu = np.where(np.isfinite(nu), nu, 0.0)
            xh = x + np.einsum("bij,jb->ib", Kp[:, pat[i]], nu)
            Y[:, i, :] = y.T
            Xf[:, i, :] = xh.T
            if i + 1 < N:
                # the integrators stop a whole batch when any column becomes non-finite; a
                # diverging perturbed or trial column must not take the others with it
                idx = np.flatnonzero(alive)
                if idx.size == 0:
                    break  # every column diverged: the rest stays NaN
                x = np.full_like(xh, np.nan)
                with np.errstate(all="ignore"):
                    xs = kern.integrate(
                        self.integrator,
                        xh[:, idx],
                        seg.u[i : i + 2],
                        seg.t[i : i + 2],
                        P[:, idx],
                        c,
                        inputs=self.inputs,
                    )[1]
                    if np.all(np.isfinite(xs)):
                        x[:, idx] = xs
                    else:
                        for b in idx:
                            xb = kern.integrate(
                                self.integrator,
                                xh[:, b : b + 1],
                                seg.u[i : i + 2],
                                seg.t[i : i + 2],
                                P[:, b : b + 1],
                                c,
                                inputs=self.inputs,
                            )[1]
                            if np.all(np.isfinite(xb)):
                                x[:, b] = xb[:, 0]
                            else:
                                alive[b] = False
        bad = ~np.all(np.isfinite(Kg.reshape(Bc, -1)), axis=1)
        Y[bad] = np.nan
        return Y, Xf

    # -- cost pieces ---------------------------------------------------------------------------
    def _innovations(self, res) -> list[np.ndarray]:
        return [seg.z - r["Y"][0] for seg, r in zip(self._segments, res)]

    def _cost(self, res) -> tuple[float, np.ndarray]:
        """(det R^, R^): the innovations' diagonal covariance R^ over every segment and its
        determinant, the cost with R concentrated out; inf when a measured output's
        prediction is not finite (a diverged filter must not shorten the sums)."""
        E = self._innovations(res)
        for seg, e in zip(self._segments, E):
            if np.any(np.isfinite(seg.z) & ~np.isfinite(e)):
                return np.inf, np.full((e.shape[1], e.shape[1]), np.nan)
        Rh = st.residual_covariance(E, full=self.full_R)
        if not np.all(np.isfinite(Rh)):
            return np.inf, Rh
        sign, logdet = np.linalg.slogdet(Rh)
        if sign <= 0:
            return np.inf, Rh
        return float(np.exp(logdet)), Rh

    def _weighted(self, res, R: np.ndarray) -> float:
        """J = 1/2 sum nu^T R^-1 nu over every sample on its measured outputs: the cost the
        Gauss-Newton step lowers for a fixed R; inf when a measured output's prediction is
        not finite."""
        J = 0.0
        for k, (seg, r) in enumerate(zip(self._segments, res)):
            E = seg.z - r["Y"][0]
            masks, pat = self._patterns[k]
            for p, o in enumerate(masks):
                if not o.any():
                    continue
                Eo = E[pat == p][:, o]
                if not np.all(np.isfinite(Eo)):
                    return np.inf
                J += 0.5 * float(np.sum(Eo.T * np.linalg.solve(R[np.ix_(o, o)], Eo.T)))
        return J if np.isfinite(J) else np.inf

    def _marginal_information(
        self,
        M: np.ndarray,
        phi: np.ndarray,
        batch,
        R: np.ndarray,
        S: Sequence[np.ndarray],
        rows: Sequence[np.ndarray],
        rel_step: float = 1e-4,
    ) -> np.ndarray:
        """The information on phi with R estimated too: the Schur complement
        M - M_pr M_rr^-1 M_rp of the joint Fisher information over phi and the entries r of
        R (its diagonal, and the off-diagonal ones when R is full). R enters the gain
        (sensitivities S_r of the innovations, by forward differences) and the likelihood
        directly (N/2 tr(R^-1 E_r R^-1 E_s)); leaving it out, as the reference software
        does, understates the std of F, which trades against R. ``S`` and ``rows``: per
        segment the innovation sensitivities of :meth:`_scoring` and their batch columns."""
        m = R.shape[0]
        pairs = [(i, j) for i in range(m) for j in range(i, m) if i == j or self.full_R]
        nphi = phi.size
        nr = len(pairs)
        Mpr = np.zeros((nphi, nr))
        Mrr = np.zeros((nr, nr))
        Es = []
        for i, j in pairs:
            E = np.zeros((m, m))
            E[i, j] = E[j, i] = 1.0
            Es.append(E)
        for k, (seg, r) in enumerate(zip(self._segments, batch)):
            Y0 = r["Y"][0]
            S_phi = np.zeros((nphi, seg.n, m))
            S_phi[rows[k][1:] - 1] = S[k]
            S_r = np.zeros((nr, seg.n, m))
            for a, (i, j) in enumerate(pairs):
                d = rel_step * np.sqrt(R[i, i] * R[j, j])
                rr = self._filter(phi[None, :], R + d * Es[a])
                if self._constraint_ok(rr):  # else its gain over-corrects: no gradient
                    S_r[a] = (rr[k]["Y"][0] - Y0) / d
            S_r = np.where(np.isfinite(S_r), S_r, 0.0)
            masks, pat = self._patterns[k]
            E = seg.z - Y0
            for p_, o in enumerate(masks):
                used = (pat == p_) & np.all(np.isfinite(np.where(o, E, 0.0)), axis=1)
                if not (o.any() and used.any()):
                    continue
                Ri = np.linalg.inv(R[np.ix_(o, o)])
                Lw = np.linalg.cholesky(Ri)
                A = np.einsum("pnm,mk->pnk", S_phi[:, used][:, :, o], Lw).reshape(nphi, -1)
                Bm = np.einsum("pnm,mk->pnk", S_r[:, used][:, :, o], Lw).reshape(nr, -1)
                Mpr += A @ Bm.T
                T = np.array([Ri @ Ea[np.ix_(o, o)] for Ea in Es])
                Mrr += Bm @ Bm.T + 0.5 * used.sum() * np.einsum("aij,bji->ab", T, T)
        with np.errstate(all="ignore"):
            try:
                out = M - Mpr @ np.linalg.solve(Mrr, Mpr.T)
            except np.linalg.LinAlgError:
                return M
        out = 0.5 * (out + out.T)
        # a valid Schur complement lies between 0 and M; anything else is a failed gradient
        d = np.diag(out)
        if not np.all(np.isfinite(out)) or np.any(d <= 0) or np.any(d > np.diag(M) * (1 + 1e-9)):
            return M
        return out

    def _constraint_ok(self, res) -> bool:
        """diag(C K) <= 1 on every segment: the measurement noise R - C P C^T implied by the
        gain keeps non-negative variances."""
        return all(np.all(r["CK"][0] <= 1.0 + 1e-9) for r in res)

    def _segment_rows(self, nphi: int) -> list[np.ndarray]:
        """Per segment the columns of a sensitivity batch (:meth:`_batch`) it needs: 0 (the
        base) and 1 + the phi it depends on - the model parameters of ``Layout.relevant``
        (shared ones and its own initial states) and every process-noise parameter."""
        fi = self._lay.free_idx
        noise = np.arange(fi.size, nphi)
        return [np.r_[0, 1 + np.searchsorted(fi, rel), 1 + noise] for rel in self._lay.relevant]

    def _scoring(self, res, R: np.ndarray, hsteps: np.ndarray, rows: Sequence[np.ndarray], keep: list | None = None):
        """Information M = sum S^T R^-1 S and gradient g = sum S^T R^-1 nu (of -J) for the
        fixed innovation covariance R, plus the gradient of diag(C K) per segment
        (list of (m, nphi)), from a batch (column 0 = base). Each sample counts on the outputs
        measured there. ``keep`` receives per segment (innovation sensitivities as a
        :class:`Sensitivity`, innovations, R^-1, rows used, the segment's part of M, of M
        again, of g) for the coloured-innovation and maneuver-scatter covariances. Returns
        (M, g, dCK, per segment S (n_cols, N, m) on its batch columns)."""
        nphi = hsteps.size
        M = np.zeros((nphi, nphi))
        g = np.zeros(nphi)
        dCK = []
        sens = []
        for k, (seg, r) in enumerate(zip(self._segments, res)):
            cols = rows[k][1:] - 1
            npk = cols.size
            Y = r["Y"]
            E = seg.z - Y[0]
            S = (Y[1:] - Y[:1]) / hsteps[cols, None, None]  # (npk, N, m)
            S = np.where(np.isfinite(S), S, 0.0)
            sens.append(S)
            G = np.zeros((r["CK"].shape[1], nphi))
            G[:, cols] = ((r["CK"][1:] - r["CK"][:1]) / hsteps[cols, None]).T
            dCK.append(np.where(np.isfinite(G), G, 0.0))
            masks, pat = self._patterns[k]
            Mk = np.zeros((nphi, nphi))
            gk = np.zeros(nphi)
            full = np.zeros(seg.n, dtype=bool)
            M_full = np.zeros((nphi, nphi))
            for p, o in enumerate(masks):
                used = (pat == p) & np.all(np.isfinite(np.where(o, E, 0.0)), axis=1)
                if not (o.any() and used.any()):
                    continue
                Lw = np.linalg.cholesky(np.linalg.inv(R[np.ix_(o, o)]))
                Sw = np.einsum("pnm,mk->pnk", S[:, used][:, :, o], Lw).reshape(npk, -1)
                add_block(Mk, cols, Sw @ Sw.T)
                add_block(gk, cols, Sw @ (E[used][:, o] @ Lw).ravel())
                if o.all():
                    full = used
                    M_full = np.zeros((nphi, nphi))
                    add_block(M_full, cols, Sw @ Sw.T)
            M += Mk
            g += gk
            if keep is not None:
                keep.append(
                    (
                        Sensitivity(np.where(full[:, None, None], np.moveaxis(S, 0, 2), 0.0), cols, nphi),
                        np.where(full[:, None], E, 0.0),
                        np.linalg.inv(R),
                        full,
                        M_full,
                        Mk,
                        gk,
                    )
                )
        return M, g, dCK, sens

    def _step(self, M: np.ndarray, g: np.ndarray, active: np.ndarray, res, dCK: list, lam: float = 0.0) -> np.ndarray:
        """Gauss-Newton (or, with ``lam``, Levenberg-Marquardt) step on the active
        parameters under the linearised constraints diag(C K) + dCK delta <= 1 (active-set:
        the violated ones are made equalities, as the reference software's KC <= 1 check)."""
        nphi = g.size
        a = np.flatnonzero(active)
        delta = np.zeros(nphi)
        if a.size == 0:
            return delta
        Ma, ga = M[np.ix_(a, a)], g[a]
        delta[a] = st.solve_step(Ma, ga, lam)
        ck = np.concatenate([r["CK"][0] for r in res])
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

    def _cap_noise_step(self, phi: np.ndarray, delta: np.ndarray, factor: float = 10.0) -> np.ndarray:
        """delta scaled so that no process-noise entry grows more than ``factor``-fold in
        one step: F's information can start out negligible (a small start gain), and an
        unbounded Gauss-Newton step then throws F far beyond the data."""
        sl = self._fslice()
        f, d = phi[sl], delta[sl]
        grow = (d > 0) & (f > 0)
        if not np.any(grow):
            return delta
        scale = np.min(np.where(grow, (factor - 1.0) * f / np.where(grow, d, 1.0), np.inf))
        return delta * min(1.0, float(scale))

    def _sensitivity_batch(self, phi: np.ndarray, R: np.ndarray, rows: Sequence[np.ndarray]):
        """The perturbed filter runs of :meth:`_batch` for phi (column 0 the base) and their
        steps; a column whose forward step makes the gain over-correct (diag(C K) > 1) or
        the prediction run away is run again with the step reversed."""
        Phis, hsteps = self._batch(phi)
        batch = self._filter(Phis, R, rows=rows)
        flip = np.zeros(phi.size, dtype=bool)
        for k, r in enumerate(batch):
            Y = r["Y"]
            big = 1e6 * (1.0 + np.nanmax(np.abs(Y[0])))
            with np.errstate(invalid="ignore"):
                bad = (
                    np.any(r["CK"][1:] > 1.0 + 1e-9, axis=1)
                    | ~np.all(
                        np.isfinite(Y[1:]).reshape(Y.shape[0] - 1, -1) | ~np.isfinite(Y[:1]).reshape(1, -1), axis=1
                    )
                    | (np.nanmax(np.abs(Y[1:] - Y[:1]).reshape(Y.shape[0] - 1, -1), axis=1, initial=0.0) > big)
                )
            flip[rows[k][1:][bad] - 1] = True
        if np.any(flip):
            hsteps = np.where(flip, -hsteps, hsteps)
            Phis = np.repeat(phi[None, :], phi.size + 1, axis=0)
            Phis[1 + np.arange(phi.size), np.arange(phi.size)] += hsteps
            batch = self._filter(Phis, R, rows=rows)
        return batch, hsteps

    def _batch(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        hsteps = self.fd_step * np.maximum(np.abs(phi), self._floor)
        up_ok = phi + hsteps <= self._hi
        hsteps = np.where(up_ok, hsteps, -hsteps)
        Phis = np.repeat(phi[None, :], phi.size + 1, axis=0)
        Phis[1 + np.arange(phi.size), np.arange(phi.size)] += hsteps
        return Phis, hsteps

    def _raise_diverged(self, res) -> None:
        for k, (seg, r) in enumerate(zip(self._segments, res)):
            bad = np.isfinite(seg.z) & ~np.isfinite(r["Y"][0])
            if np.any(bad):
                i = int(np.argmax(np.any(bad, axis=1)))
                raise SimulationDivergedError(
                    f"the {'nonlinear ' if self.form == 'nonlinear' else ''}filter prediction of "
                    f"segment {seg.name or k} became non-finite at t={seg.t[i]:.4g} s (start "
                    "closer, e.g. from output-error or equation-error estimates, or give a "
                    "smaller process-noise start)",
                    segment=k,
                    time=float(seg.t[i]),
                )
        raise SimulationDivergedError(
            "the filter-error Riccati equation has no stabilising solution at the current "
            "parameters (a state not detectable from the outputs?)"
        )

    def _compensate(self, phi: np.ndarray, R_old: np.ndarray, R_new: np.ndarray, res) -> np.ndarray:
        """F-R compensation (Maine and Iliff): after R changes from R_old to R_new, F_i is
        scaled by sum_k C_ki^2 / R_old,kk sqrt(R_new,kk / R_old,kk) / sum_k C_ki^2 / R_old,kk
        so that the gain, and the noise R - C P C^T it implies, stay consistent."""
        if not self.estimate_F or not self._noisy:
            return phi
        C2 = np.mean([r["C"][0] ** 2 for r in res], axis=0)  # (m, n)
        w = 1.0 / np.diag(R_old)
        ratio = np.sqrt(np.diag(R_new) / np.diag(R_old))
        with np.errstate(invalid="ignore", divide="ignore"):
            fac = (C2.T @ (w * ratio)) / (C2.T @ w)
        out = phi.copy()
        sl = self._fslice()
        f = np.asarray(self._noisy)
        out[sl] = phi[sl] * np.where(np.isfinite(fac[f]) & (fac[f] > 0), fac[f], 1.0)
        return out

    def _feasible_start(self, phi: np.ndarray, res, R: np.ndarray) -> tuple[np.ndarray, Any]:
        """The start with F scaled down, halving at most 30 times, until diag(C K) <= 1 and
        the filter's predictions stay finite: a start F too large for the start R implies a
        negative measurement noise, and its filter over-corrects every sample. The free F entries are scaled, else the fixed
        ones; unchanged when already feasible."""
        for _ in range(30):
            if not self._noisy or (self._constraint_ok(res) and np.isfinite(self._cost(res)[0])):
                break
            if self.estimate_F:
                phi = phi.copy()
                phi[self._fslice()] *= 0.5
            else:
                self._f_fixed = 0.5 * self._f_fixed
            res = self._filter(phi[None, :], R)
        return phi, res

    def _to_constraint(self, phi: np.ndarray, res, R: np.ndarray, margin: float = 1e-4):
        """phi with its F scaled by the largest factor in (0, 1] (bisection, 30 steps) that
        keeps diag(C K) <= 1 - margin for the innovation covariance R, and its filter run;
        (phi, None) when no factor does or F is not estimated."""
        if not self.estimate_F or not self._noisy:
            return phi, None
        sl = self._fslice()
        lo, hi, best = 0.0, 1.0, None
        for _ in range(30):
            s = 0.5 * (lo + hi)
            c = phi.copy()
            c[sl] *= s
            rc = self._filter(c[None, :], R)
            if all(np.all(r["CK"][0] <= 1.0 - margin) for r in rc):
                lo, best = s, (c, rc)
            else:
                hi = s
            if hi - lo < 1e-3 * hi:
                break
        return best if best is not None else (phi, None)

    def _relax(self, phi, res, cost, Rh, R):
        """One relaxation update: R in closed form from the innovations (Rh) with F
        compensated for it (:meth:`_compensate`). When the compensated F raises det(R), it
        is halved back towards the old F (the reference software's rule); when the new R
        makes the gain over-correct (diag(C K) > 1), F is scaled down until it does not.
        The first candidate that lowers det(R) is taken, else the feasible one of least
        det(R): R must follow the innovations, or the relaxation stalls on a stale R.
        Returns (phi, res, cost, Rh, R, the relative change of R)."""
        change = float(np.max(np.abs(np.diag(Rh) / np.diag(R) - 1.0)))
        phi_c = self._compensate(phi, R, Rh, res)
        cands = [phi_c, 0.5 * (phi_c + phi), phi]
        best = None
        for c in cands:
            rc = self._filter(c[None, :], Rh)
            if not self._constraint_ok(rc):
                c, rc = self._to_constraint(c, rc, Rh)
            if rc is None:
                continue
            cc, Rc = self._cost(rc)
            if not np.isfinite(cc):
                continue
            if cc <= cost * (1.0 + 1e-9):
                return c, rc, cc, Rc, Rh, change
            if best is None or cc < best[2]:
                best = (c, rc, cc, Rc)
        if best is not None:
            return (*best, Rh, change)
        return phi, res, cost, Rh, R, change

    def _fslice(self) -> slice:
        nf = self._lay.free_idx.size
        return slice(nf, nf + (len(self._noisy) if self.estimate_F else 0))

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
        model = self.model
        self._segments = segments
        lay = self._lay = Layout.build(model, segments, estimate_x0, values=start)
        self._h = [sample_interval(seg, k) for k, seg in enumerate(segments)]
        self._patterns = [output_patterns(seg.z) for seg in segments]
        self._n_samples = int(sum(seg.n for seg in segments))
        check_outputs_measured(self.model, segments, "filter error")
        if self.form_requested == "auto":
            self._set_form("linear" if is_affine(model, segments, lay) else "nonlinear")
        m = len(model.outputs)
        self._noisy, f0 = self._noise_setup(segments)
        start = dict(start) if start is not None else {}
        for i in self._noisy:  # an earlier fit's F (``start`` of a refit) over the default
            v = start.get(f"F_{model.states[i]}")
            if v is not None and float(v) > 0.0:
                f0[i] = float(v)
        self._f_fixed = f0.copy()
        fi = lay.free_idx
        names = list(lay.free_names)
        lo = list(lay.lower[fi])
        hi = list(lay.upper[fi])
        phi = list(lay.values[fi])
        if self.estimate_F:
            for i in self._noisy:
                names.append(f"F_{model.states[i]}")
                phi.append(f0[i])
                lo.append(0.0)
                hi.append(np.inf)
        phi = np.array(phi, dtype=float)
        nphi = phi.size
        self._lo, self._hi = np.array(lo, float), np.array(hi, float)
        # finite-difference floor: 1 for model parameters (as OEM), the start for F
        self._floor = np.concatenate([np.ones(fi.size), np.maximum(np.abs(phi[fi.size :]), 1e-12)])
        # the start of R: the given output-error std, else the residuals without a gain
        if self.measurement_noise is not None:
            from estimators.filters.kalman import _vector

            R = np.diag(_vector(self.measurement_noise, model.outputs, "measurement_noise", np.ones(m)) ** 2)
        else:
            # the start model's residuals without a gain, each output's variance at most
            # that of its data: a model that misses by more (an unstable aircraft's
            # simulation runs away) is no guide to R
            r0 = self._filter(phi[None, :], np.eye(m), gain=False)
            R = self._cost(r0)[1]
            Zall = np.concatenate([seg.z for seg in segments])
            var_z = np.nanvar(Zall, axis=0)
            var_z = np.where(var_z > 0, var_z, 1.0)
            d = np.diag(R)
            if not np.all(np.isfinite(R)) or np.any(d > var_z):
                R = np.diag(np.where(np.isfinite(d) & (d > 0), np.minimum(d, var_z), var_z))
        if np.any(np.diag(R) <= 0) or not np.all(np.isfinite(R)):
            raise ModelDefinitionError("measurement_noise: every output needs a positive, finite std")
        seg_rows = self._segment_rows(nphi)
        res = self._filter(phi[None, :], R)
        phi, res = self._feasible_start(phi, res, R)
        cost, Rh = self._cost(res)
        if not np.isfinite(cost):
            self._raise_diverged(res)
        history: list[dict] = []
        converged = False
        message = ""
        it = 0
        for it in range(1, self.max_iter + 1):
            batch, hsteps = self._sensitivity_batch(phi, R, seg_rows)
            M, g, dCK, _ = self._scoring(batch, R, hsteps, seg_rows)
            if it == 1:
                # at the start only parameters without any effect are an error
                # (the process noise is exempt: with a start R far above the innovations its
                # gain, and so its effect, can start out negligible)
                d = np.diag(M) * np.maximum(np.abs(phi), self._floor) ** 2  # scale-free
                dead = d <= 1e-14 * max(float(d.max()), 1e-300)
                dead[fi.size :] = False
                if np.any(dead):
                    st.check_identifiable(np.diag(np.where(dead, 0.0, 1.0)), names, " at the start values")
            history.append(
                {
                    "iteration": it - 1,
                    "J": 0.5 * self._n_samples * np.log(cost),
                    "det_R": cost,
                    "step": np.nan,
                    **dict(zip(names, phi)),
                }
            )
            if self.callback:
                self.callback(it - 1, cost, pd.Series(phi, index=names))
            span = np.maximum(1.0, np.abs(phi))
            at_lo = phi <= self._lo + 1e-12 * span
            at_hi = phi >= self._hi - 1e-12 * span
            active = ~((at_lo & (g < 0)) | (at_hi & (g > 0)))
            delta = self._cap_noise_step(phi, self._step(M, g, active, batch, dCK))
            J0 = self._weighted(res, R)
            accepted, alpha = False, 1.0
            for _ in range(self.step_halvings + 1):
                trial = np.clip(phi + alpha * delta, self._lo, self._hi)
                rt = self._filter(trial[None, :], R)
                if self._weighted(rt, R) < J0 and self._constraint_ok(rt):
                    accepted = True
                    break
                alpha *= 0.5
            if not accepted:
                for lam in (1e-2, 1e-1, 1.0, 10.0, 1e2, 1e3, 1e4):
                    trial = np.clip(
                        phi + self._cap_noise_step(phi, self._step(M, g, active, batch, dCK, lam)), self._lo, self._hi
                    )
                    rt = self._filter(trial[None, :], R)
                    if self._weighted(rt, R) < J0 and self._constraint_ok(rt):
                        accepted, alpha = True, -lam  # recorded as a negative step: LM
                        break
            if accepted:
                ct, Rt = self._cost(rt)
            history[-1]["step"] = alpha
            prev = cost
            if accepted:
                phi, res, cost, Rh = trial, rt, ct, Rt
            r_change = 0.0
            if it >= self.r_update_from:
                phi, res, cost, Rh, R, r_change = self._relax(phi, res, cost, Rh, R)
            settled = abs(prev - cost) <= self.tol * abs(cost) and r_change <= R_SETTLED
            if settled and it >= self.r_update_from:
                converged = True
                break
            if not accepted and r_change <= R_SETTLED:
                if 0.5 * float(g @ delta) <= 1e-6 * max(1.0, J0):
                    converged = True  # the predicted decrease is negligible
                else:
                    message = "no step lowered det(R) (line search failed)"
                break
        else:
            message = f"stopped at max_iter={self.max_iter} before det(R) settled"
        # information at the final estimate, with R the innovations' covariance there
        R = Rh
        batch, hsteps = self._sensitivity_batch(phi, R, seg_rows)
        parts: list = []
        M, g, _, sens = self._scoring(batch, R, hsteps, seg_rows, keep=parts)
        M = self._marginal_information(M, phi, batch, R, sens, seg_rows)
        from estimators.validation.cluster import ClusterResult, cluster_covariance

        span = np.maximum(1.0, np.abs(phi))
        on_bound = (phi <= self._lo + 1e-9 * span) | (phi >= self._hi - 1e-9 * span)
        inner = np.flatnonzero(~on_bound)
        cov = np.full((nphi, nphi), np.nan)
        cov_mk = np.full((nphi, nphi), np.nan)
        cov_cl = np.full((nphi, nphi), np.nan)
        share = np.full((len(parts), nphi), np.nan)
        mk_lags: list[int] = []
        if inner.size:
            st.check_identifiable(M[np.ix_(inner, inner)], [names[i] for i in inner], " at the estimates")
            cov[np.ix_(inner, inner)] = st.covariance(M[np.ix_(inner, inner)])
            cov_mk[np.ix_(inner, inner)], mk_lags = _coloured_innovation_cov(
                M[np.ix_(inner, inner)],
                sum(p[4] for p in parts)[np.ix_(inner, inner)],
                [(S.take(inner), E, Ri, ok) for S, E, Ri, ok, *_ in parts],
            )
            if len(parts) >= 2:
                # each segment's score at the optimum of the whole: g_k - M_k M^-1 sum g (the
                # iterations stop with a small gradient left, which is not the maneuvers'
                # disagreement)
                # over the model's parameters only: the process noise is the air's, whose
                # intensity differs between maneuvers without any fault of the model
                mi = inner[inner < fi.size]
                Mi = [p[5][np.ix_(mi, mi)] for p in parts]
                try:
                    step = np.linalg.solve(sum(Mi), sum(p[6][mi] for p in parts))
                except np.linalg.LinAlgError:
                    step = np.zeros(mi.size)
                try:
                    cl = cluster_covariance(Mi, [p[6][mi] - Mk @ step for p, Mk in zip(parts, Mi)], M[np.ix_(mi, mi)])
                    cov_cl[np.ix_(mi, mi)], share[:, mi] = cl.cov, cl.share
                except np.linalg.LinAlgError:
                    pass
        cluster = (
            None
            if len(parts) < 2 or not np.any(np.isfinite(share))
            else ClusterResult(names=names, cov=cov_cl, crb_std=np.sqrt(np.clip(np.diag(cov), 0.0, None)), share=share)
        )
        theta, F = self._unpack(phi)
        E = self._innovations(batch)
        Ys = [r["Y"][0] for r in batch]
        all_names = list(lay.names) + names[fi.size :]
        values = np.concatenate([theta, phi[fi.size :]])
        free = np.concatenate([lay.free, np.ones(nphi - fi.size, dtype=bool)])
        if not converged and not message:
            message = "did not converge"
        noise = [np.diag(np.maximum(np.diag(R) - np.diag(r["C"][0] @ r["P"][0] @ r["C"][0].T), 0.0)) for r in batch]
        return EstimationResult(
            method=self.method,
            model=model,
            names=all_names,
            values=values,
            free=free,
            cov=cov,
            R=st.residual_covariance(E, full=True),
            converged=converged,
            iterations=it,
            history=pd.DataFrame(history),
            segments=segments,
            predicted=frames([s.t for s in segments], Ys, model.outputs),
            residuals=frames([s.t for s in segments], E, model.outputs),
            at_bounds=[names[i] for i in np.flatnonzero(on_bound)],
            message=message,
            information=M,
            settings={
                "form": self.form,
                "integrator": self.integrator if self.form == "nonlinear" else "transition matrix",
                "optimizer": "gauss-newton, R by relaxation, F-R compensation",
                "estimate_F": self.estimate_F,
                "inputs": self.inputs,
                "linearisation": "about x0 and u[0] of each segment",
            },
            extra={
                "gain": [r["K"][0] for r in batch],
                "F": F,
                "measurement_noise": noise[0],
                "innovation_cov": [R for _ in batch],
                "P": [r["P"][0] for r in batch],
                "linearisation": [dict(zip("ABCD", r["lin"])) for r in batch],
                "filtered_states": [
                    pd.DataFrame(r["X"][0], index=pd.Index(s.t, name="t"), columns=model.states)
                    for s, r in zip(segments, batch)
                ],
                "det_R": float(np.linalg.det(R)),
                "residuals_are": "innovations",
                "mk_cov": cov_mk,
                "mk_names": names,
                "mk_max_lag": mk_lags,
                "cluster": cluster,
            },
        )
