"""Filter-error method (FEM): maximum likelihood with process and measurement noise.

Model (DESIGN.md section 8): x' = f(x, u, theta) + F w, y = g(x, u, theta),
z_k = y_k + G v_k with w, v unit white noise; F (diagonal, states listed in
``process_noise``) and G (diagonal, every output; R = G G^T) are estimated with theta.

Filter (steady-state Kalman filter, one per parameter set):

* Linearisation: A = df/dx, B = df/du, C = dg/dx, D = dg/du by central differences about
  each segment's initial state and first input (the trim point), re-evaluated for every
  parameter set; the affine parts f(x_r, u_r) - A x_r - B u_r and g(...) - C x_r - D u_r
  are kept, so linear models with trim offsets and output biases are represented
  exactly.
* Discretisation over the sample interval h: Phi = e^{A h}, Gamma = int_0^h e^{A s} ds,
  Qd = int_0^h e^{A s} F F^T e^{A^T s} ds (van Loan), inputs averaged over the step as in
  output error.
* Gain: P from the discrete algebraic Riccati equation
  P = Phi P Phi^T - Phi P C^T (C P C^T + R)^-1 C P Phi^T + Qd (scipy solve_discrete_are),
  innovation covariance B = C P C^T + R, K = P C^T B^-1.
* ``form="linear"``: prediction x~_{k+1} = Phi x^_k + Gamma (B u_k + f_0);
  ``form="nonlinear"``: prediction by one integrator step of the nonlinear f from x^_k
  (the package integrators, default RK4), outputs g(x~_k) of the nonlinear g, and the
  steady-state gain of the linearisation at the trim point (a constant gain; state it
  when reporting: the linearisation is about x0 and u[0] of each segment).
* Correction x^_k = x~_k + K (z_k - y~_k). A sample where only the outputs o are measured
  (NaN = missing: multi-rate data) is corrected with the gain of those outputs,
  K_o = P C_o^T B_oo^-1, and enters the likelihood and information below with the block
  B_oo (``output_patterns``, ``pattern_gains``; P stays the steady state of the full
  output set).

Estimation (internally the process-noise unknowns are F_i^2, which enter Qd linearly;
results report F_i and its std): the negative log-likelihood of the innovations
J = 1/2 sum (nu^T B^-1 nu + log det B) over all samples and segments, minimised by
Gauss-Newton (Fisher scoring) over phi = [theta, F_i, G_j]:

    M = sum S^T B^-1 S + N/2 tr(B^-1 B_i B^-1 B_j),  S = d y~/d phi (filtered outputs),
    g = sum S^T B^-1 nu + 1/2 tr(B^-1 B_i B^-1 (sum nu nu^T - N B)),

with the sensitivities of the filtered outputs (they include the gain's gradients
dK/dphi) from forward differences, all perturbed parameter sets filtered in one batch.
Step halving on J, then Levenberg-Marquardt damping when halving fails; F_i >= 0 and
G_j > 0 by bounds. The Cramér-Rao bounds M^-1 cover
theta, F and G together.

F-R compensation: Maine and Iliff's relaxation estimates the innovation covariance in
closed form and afterwards rescales F so that the implied measurement-noise covariance
B - C P C^T stays positive definite. Here the measurement noise G is itself a
parameter of the likelihood and B = C P C^T + G G^T comes from the Riccati solution, so
every Gauss-Newton step moves F and R consistently and the measurement-noise part stays
positive by construction; no separate compensation step is needed.

Result: an :class:`~estimators.EstimationResult`; ``predicted`` are the one-step
predictions y~_k, ``residuals`` the innovations, ``R`` their sample covariance;
``extra`` holds ``gain`` (K per segment), ``F`` (n, n), ``measurement_noise`` (G G^T),
``innovation_cov`` (B per segment), ``P`` (a-priori state covariance), ``A/B/C/D``
(linearisation per segment) and ``filtered_states``.
"""
from __future__ import annotations

import warnings
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd
from scipy import linalg

from estimators.errors import ModelDefinitionError, SimulationDivergedError
from estimators.integrators import INTEGRATORS, check_options
from estimators.jit import (adapter_source, bound_source, compile_user_function, first_line,
                           kernel_for, load_kernels, probe_point)
from estimators.kalman import (SEGMENT_HELPERS, _ekf_segment, _ukf_segment, default_process_noise,
                               is_name_list, named_process_noise)
from estimators.model import Model, Segment, check_outputs_measured
from estimators.results import EstimationResult, frames
from estimators.sensitivity import Sensitivity, add_block
from estimators.simulation import Layout
from estimators import statistics as st

try:
    import numba
except ImportError:  # pragma: no cover
    numba = None


def _coloured_innovation_cov(M: np.ndarray, M_S: np.ndarray, parts: list
                             ) -> tuple[np.ndarray, list[int]]:
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

    mid, lags = coloured_information([p[0] for p in parts], [p[1] for p in parts],
                                     [p[2] for p in parts],
                                     [np.repeat(p[3][:, None], p[1].shape[1], axis=1) for p in parts])
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


def linearize_batch(model: Model, P: np.ndarray, xr: np.ndarray, ur: np.ndarray,
                    constants: Mapping[str, float], rel_step: float = 1e-5):
    """A (B, n, n), Bu (B, n, ni), C (B, m, n), D (B, m, ni), f0 (B, n), y0 (B, m) of the
    affine approximation f ~ A x + Bu u + f0, g ~ C x + D u + y0 about (xr (n, B), ur (ni,))
    for the parameter columns P (n_p, B); central differences, all columns in one call."""
    n, Bc = xr.shape
    ni = ur.size
    L = n + ni
    v0 = np.concatenate([xr, np.repeat(ur[:, None], Bc, axis=1)], axis=0)     # (L, B)
    h = rel_step * np.maximum(np.abs(v0), 1.0)                                  # (L, B)
    V = np.repeat(v0[:, :, None], 1 + 2 * L, axis=2)                            # (L, B, E)
    idx = np.arange(L)
    V[idx, :, 1 + idx] += h
    V[idx, :, 1 + L + idx] -= h
    Vf = V.reshape(L, -1)
    Pf = np.repeat(P[:, :, None], 1 + 2 * L, axis=2).reshape(P.shape[0], -1)
    with np.errstate(all="ignore"):
        fv = model.eval_f(Vf[:n], Vf[n:], Pf, constants).reshape(n, Bc, -1)
        gv = model.eval_g(Vf[:n][:, None, :], Vf[n:][:, None, :], Pf, constants)[:, 0, :]
    gv = gv.reshape(len(model.outputs), Bc, -1)
    Jf = (fv[:, :, 1:1 + L] - fv[:, :, 1 + L:]) / (2 * h.T[None, :, :])        # (n, B, L)
    Jg = (gv[:, :, 1:1 + L] - gv[:, :, 1 + L:]) / (2 * h.T[None, :, :])
    Jf = Jf.transpose(1, 0, 2)
    Jg = Jg.transpose(1, 0, 2)
    A, Bu = Jf[:, :, :n], Jf[:, :, n:]
    C, D = Jg[:, :, :n], Jg[:, :, n:]
    x_r = xr.T
    f0 = fv[:, :, 0].T - np.einsum("bij,bj->bi", A, x_r) - Bu @ ur
    y0 = gv[:, :, 0].T - np.einsum("bij,bj->bi", C, x_r) - D @ ur
    return A, Bu, C, D, f0, y0


def is_affine(model: Model, segments: Sequence[Segment], layout: Layout,
              rtol: float = 1e-6) -> bool:
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
            if not np.all(np.isfinite(ma)) or not np.all(np.isfinite(mb)) \
                    or np.max(np.abs(ma - mb)) > rtol * scale:
                return False
    return True


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
    A = M / (2.0 ** s)
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
    """Phi = e^{A h}, Gamma = int_0^h e^{As} ds, Qd (van Loan) for one system."""
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


def _mm(A, B):
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


def _inv(M):
    """Gauss-Jordan inverse with partial pivoting (small matrices); NaN if singular."""
    n = M.shape[0]
    A = M.copy()
    I = np.eye(n)
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(A[r, c]) > abs(A[p, c]):
                p = r
        if A[p, c] == 0.0 or not np.isfinite(A[p, c]):
            return np.full((n, n), np.nan)
        if p != c:
            for j in range(n):
                A[c, j], A[p, j] = A[p, j], A[c, j]
                I[c, j], I[p, j] = I[p, j], I[c, j]
        d = A[c, c]
        for j in range(n):
            A[c, j] /= d
            I[c, j] /= d
        for r in range(n):
            if r != c:
                f = A[r, c]
                if f != 0.0:
                    for j in range(n):
                        A[r, j] -= f * A[c, j]
                        I[r, j] -= f * I[c, j]
    return I


def _dare_sda(A, G, H, max_iter, tol):
    """Structure-preserving doubling for X = A^T X A - A^T X B (R + B^T X B)^-1 B^T X A + H
    with G = B R^-1 B^T:  W = I + G_k H_k,  A_{k+1} = A_k W^-1 A_k,
    G_{k+1} = G_k + A_k W^-1 G_k A_k^T,  H_{k+1} = H_k + A_k^T H_k W^-1 A_k  ->  H_k -> X."""
    n = A.shape[0]
    Ak, Gk, Hk = A.copy(), G.copy(), H.copy()
    for _ in range(max_iter):
        Wi = _inv(np.eye(n) + _mm(Gk, Hk))
        if not np.all(np.isfinite(Wi)):
            return np.full((n, n), np.nan)
        AW = _mm(Ak, Wi)
        Gn = Gk + _mm(_mm(AW, Gk), Ak.T.copy())
        Hn = Hk + _mm(_mm(Ak.T.copy(), Hk), _mm(Wi, Ak))
        An = _mm(AW, Ak)
        num = 0.0
        den = 0.0
        for i in range(n):
            for j in range(n):
                num = max(num, abs(Hn[i, j] - Hk[i, j]))
                den = max(den, abs(Hn[i, j]))
        Ak, Gk, Hk = An, Gn, Hn
        if num <= tol * max(den, 1e-300):
            return 0.5 * (Hk + Hk.T)
        if not np.all(np.isfinite(Hk)):
            break
    return np.full((n, n), np.nan)


def _gain(Phi, C, Qd, R):
    """P (a-priori), B = C P C^T + R, K = P C^T B^-1 (all compiled, small matrices)."""
    Ri = _inv(R)
    G = _mm(_mm(C.T.copy(), Ri), C)
    P = _dare_sda(Phi.T.copy(), G, Qd, 60, 1e-13)
    PCt = _mm(P, C.T.copy())
    Bm = _mm(C, PCt) + R
    Bm = 0.5 * (Bm + Bm.T)
    K = _mm(PCt, _inv(Bm))
    return P, Bm, K


if numba is not None:
    _mm = numba.njit(cache=True)(_mm)
    _inv = numba.njit(cache=True)(_inv)
    _dare_sda = numba.njit(cache=True)(_dare_sda)
    _gain = numba.njit(cache=True)(_gain)


def steady_state_gain(Phi: np.ndarray, C: np.ndarray, Qd: np.ndarray, R: np.ndarray):
    """(P a-priori, B = C P C^T + R, K = P C^T B^-1) from the discrete algebraic Riccati
    equation P = Phi P Phi^T - Phi P C^T (C P C^T + R)^-1 C P Phi^T + Qd, solved by the
    structure-preserving doubling algorithm (compiled; same solution as
    scipy.linalg.solve_discrete_are, which the tests check). Raises LinAlgError when there
    is no stabilising solution."""
    P, Bm, K = _gain(np.ascontiguousarray(Phi, dtype=float), np.ascontiguousarray(C, dtype=float),
                     np.ascontiguousarray(Qd, dtype=float), np.ascontiguousarray(R, dtype=float))
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(K))):
        raise np.linalg.LinAlgError("the Riccati equation has no stabilising solution")
    return P, Bm, K


# -- compiled nonlinear filter loop ----------------------------------------------------------
_OUT_KERNELS: dict = {}


def output_kernel(model: Model):
    """The model's compiled filter kernels (a module, kept on disk by
    :func:`estimators.jit.load_kernels`): ``gout(x (n, B), u (n_in,), P (n_p, B), c,
    out (n_out, B))``, g in the integrators' calling convention (output biases added), and
    ``nl_loop_<integrator>(x0, U, t, P, c, K, pat, Z, rtol, atol, mode)``, :func:`_nl_loop`
    with the model's rhs and gout; None when g does not compile or disagrees with the numpy
    evaluation."""
    # f too: the module's filter loops call the model's rhs
    key = (model.f, model.g, tuple(model.states), tuple(model.inputs), tuple(model.parameter_names),
           tuple(model.outputs), tuple(model.output_biases), tuple(sorted(model.constants)))
    if key in _OUT_KERNELS:
        return _OUT_KERNELS[key]
    mod, why = None, ""
    kern = kernel_for(model)
    for helpers in ((False, True) if numba is not None and kern.prepare() else ()):
        mod, why = _output_kernel(model, kern, helpers)
        if mod is not None:
            break
    if mod is None and why:
        # f compiled (else it has said so itself) but g did not
        warnings.warn(
            f"model {model.name!r}: g could not be compiled with numba ({why}); the filter "
            "loop runs with numpy, which is slower. Write g with numpy functions and "
            "arithmetic on the unpacked rows to get the compiled path.",
            RuntimeWarning, stacklevel=3)
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
        # module's gout called as globals (estimators.jit.bound_source)
        loops = [bound_source(_nl_loop, "scheme, rhs, gout, ",
                              {"def _nl_loop(": f"def nl_loop_{s}(", "scheme(rhs, ": f"_integrate_{s}("})
                 + f"nl_loop_{s} = numba.njit(error_model='numpy', cache=CACHE)(nl_loop_{s})"
                 for s in INTEGRATORS]
        # the EKF's and UKF's segment loops (estimators.kalman) on the same rhs and g
        loops += [bound_source(h, "") + f"{h.__name__} = numba.njit(error_model='numpy', "
                  f"cache=CACHE)({h.__name__})" for h in SEGMENT_HELPERS]
        loops += [bound_source(fn, "scheme, gout, ",
                               {f"def _{w}_segment(": f"def {w}_segment_{s}(", "scheme(": f"_integrate_{s}("})
                  + f"{w}_segment_{s} = numba.njit(error_model='numpy', cache=CACHE)({w}_segment_{s})"
                  for w, fn in (("ekf", _ekf_segment), ("ukf", _ukf_segment)) for s in INTEGRATORS]
        src = "\n".join([
            f"# fsid compiled filter loop of model {model.name!r} (generated by estimators.fem; "
            "safe to delete)",
            f"# g: {getattr(g_full, '__module__', '?')}.{getattr(g_full, '__qualname__', '?')}, "
            f"helpers compiled: {helpers}; rhs: {getattr(kern.module, '__name__', 'in memory')}",
            "from collections import namedtuple",
            "import numba",
            "import numpy as np",
            f"Params = namedtuple('Params', {list(names)!r})",
            *adapter_source("gout", "_g", n, ni, len(names), rows,
                            [f"    out[{j}, :] += P[{i}]" for j, i in bias]),
            *loops, ""])
        gj = compile_user_function(g_full) if helpers else numba.njit(error_model="numpy")(g_full)
        steps = {f"_integrate_{s}": getattr(kern.module, f"integrate_{s}") for s in INTEGRATORS}
        mod = load_kernels(src, {"_g": gj, **steps}, [g_full, model.f], "fsid_filter",
                           package=("fem.py",))
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
            Xs = scheme(rhs, xh[:, idx], U[i:i + 2], t[i:i + 2], P[:, idx], c, rtol, atol, mode)
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
                    Xb = scheme(rhs, xh[:, b:b + 1].copy(), U[i:i + 2], t[i:i + 2],
                                P[:, b:b + 1].copy(), c, rtol, atol, mode)
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


def pattern_gains(Pp: np.ndarray, C: np.ndarray, B: np.ndarray, K: np.ndarray,
                  masks: np.ndarray) -> np.ndarray:
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
            PCt = np.einsum("bij,bkj->bik", Pp, C[:, o, :])                 # (Bc, n, m_o)
            with np.errstate(all="ignore"):
                out[:, p][:, :, o] = np.linalg.solve(B[:, o][:, :, o], PCt.transpose(0, 2, 1)
                                                     ).transpose(0, 2, 1)
    return np.nan_to_num(out)


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
            "rate or split the segment at the gap")
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
    measurement_noise : start of G (std per output): {output: std} or (n_out,); default
        from the innovations of the start model.
    estimate_G : estimate G (True, default) or hold it at ``measurement_noise`` (False;
        then ``measurement_noise`` is required). Holding G at an independent measurement-
        noise estimate helps when the process noise is a white-noise stand-in for coloured
        turbulence: the likelihood can then trade G of an output that also measures the
        gust-driven state (e.g. az for alpha) down towards 0, where the information matrix
        becomes singular. Held entries are reported with no std.
    form : "auto" (default: "linear" when f and g are affine in x and u over the data,
        :func:`is_affine`, else "nonlinear"), "linear" (transition matrix of the
        linearisation at each segment's start: exact for linear models only - on the
        nonlinear HFB-320 class model of an 18 m/s speed change it put the derivatives
        up to 44 std off) or "nonlinear" (integrator prediction, gain of the
        linearisation at the trim point).
    integrator : the one-step predictor of the nonlinear form.
    max_iter, tol : Gauss-Newton iterations; stop when the relative change of J is < tol.
    fd_step : relative forward-difference step of the sensitivities.
    step_halvings : maximum halvings of a step that does not lower J.
    inputs : input variation over a sample interval, as OutputError: "average" (default),
        "hold" (zero-order hold) or "linear" (nonlinear form only).
    compiled : run the nonlinear filter loop compiled with numba (f and g compiled; falls
        back to the numpy loop when the model does not compile).
    """

    method = "fem"

    def __init__(self, model: Model, *, process_noise: Any = None, estimate_F: bool = True,
                 measurement_noise: Any = None, estimate_G: bool = True, form: str = "auto", integrator: str = "rk4",
                 max_iter: int = 30, tol: float = 1e-7, fd_step: float = 1e-6,
                 step_halvings: int = 10, inputs: str = "average", compiled: bool = True,
                 callback=None) -> None:
        if form not in ("auto", "linear", "nonlinear"):
            raise ModelDefinitionError(f"form must be 'auto', 'linear' or 'nonlinear', not {form!r}")
        check_options(integrator, inputs)
        self.model = model
        self.process_noise = process_noise
        self.estimate_F = estimate_F
        self.estimate_G = estimate_G
        if not estimate_G and measurement_noise is None:
            raise ModelDefinitionError("estimate_G=False needs measurement_noise (std per output)")
        self.measurement_noise = measurement_noise
        self.form_requested = form
        self.integrator = integrator
        self.max_iter = max_iter
        self.tol = tol
        self.fd_step = fd_step
        self.step_halvings = step_halvings
        self.callback = callback
        if form == "linear" and inputs == "linear":
            raise ModelDefinitionError("the linear form supports inputs='average' or 'hold'; use "
                                       "form='nonlinear' for linearly interpolated inputs")
        self.inputs = inputs
        self.compiled = compiled
        self._set_form(form)

    def _set_form(self, form: str) -> None:
        self.form = form
        self.method = "fem-nl" if form == "nonlinear" else "fem"

    # -- parameter vector phi = [layout free, F_i, G_j] ---------------------------------------
    def _noise_setup(self, segments: Sequence[Segment]) -> tuple[list[int], np.ndarray]:
        m = self.model
        n = len(m.states)
        default = default_process_noise(m, segments)
        spec = self.process_noise
        if spec is None:
            f0 = default
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

    def _unpack(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """theta (n_all,), F (n, n), R (m, m) from phi (free vector)."""
        theta = self._lay.values.copy()
        nf = self._lay.free_idx.size
        theta[self._lay.free_idx] = phi[:nf]
        fvec = self._f_fixed.copy()
        if self.estimate_F:
            fvec[self._noisy] = np.sqrt(np.maximum(phi[nf:nf + len(self._noisy)], 0.0))
        g = phi[-len(self.model.outputs):]
        return theta, np.diag(fvec), np.diag(g ** 2)

    def _fslice(self) -> slice:
        nf = self._lay.free_idx.size
        return slice(nf, nf + (len(self._noisy) if self.estimate_F else 0))

    def _report(self, phi: np.ndarray) -> np.ndarray:
        """phi with the process-noise entries as std F (internally F^2 is the unknown: it
        enters Qd linearly, so its gradient does not vanish at F = 0 and the bound works)."""
        out = np.array(phi, dtype=float)
        sl = self._fslice()
        out[sl] = np.sqrt(np.maximum(out[sl], 0.0))
        return out

    def _dphi(self, phi: np.ndarray) -> np.ndarray:
        """d phi / d reported: 2 F for the process-noise entries, 1 otherwise."""
        D = np.ones(phi.size)
        D[self._fslice()] = 2.0 * self._report(phi)[self._fslice()]
        return D

    # -- filtering a batch of parameter vectors ------------------------------------------------
    def _filter(self, Phis: np.ndarray, want_states: bool = False,
                rows: Sequence[np.ndarray] | None = None):
        """For parameter columns Phis (Bc, n_phi): per segment predicted outputs
        (Bc_k, N, m), innovation covariances (Bc_k, m, m) and details of column 0.
        ``rows``: per segment the columns of Phis to run (column 0 first; default all):
        a sensitivity batch needs only the parameters the segment depends on
        (:meth:`_segment_rows`)."""
        model = self.model
        n, m = len(model.states), len(model.outputs)
        unpacked = [self._unpack(p) for p in Phis]
        Theta_all = np.stack([u[0] for u in unpacked])
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
            Phi = np.empty((Bc, n, n)); Gam = np.empty((Bc, n, n))
            Kg = np.empty((Bc, n, m)); Binn = np.empty((Bc, m, m)); Pp = np.empty((Bc, n, n))
            for b in range(Bc):
                F, R = unpacked[idx[b]][1], unpacked[idx[b]][2]
                Phi[b], Gam[b], Qd = discretize(A[b], F @ F.T, h)
                try:
                    Pp[b], Binn[b], Kg[b] = steady_state_gain(Phi[b], C[b], Qd, R)
                except np.linalg.LinAlgError:
                    Pp[b] = np.nan; Binn[b] = np.nan; Kg[b] = np.nan
            if self.inputs == "hold":
                ua = seg.u
            else:
                ua = np.vstack([0.5 * (seg.u[:-1] + seg.u[1:]), seg.u[-1:]])    # (N, ni)
            offset = np.einsum("bij,nj->bni", D, seg.u) + y0[:, None, :]
            Z = np.ascontiguousarray(seg.z)
            masks, pat = self._patterns[k]
            Kp = pattern_gains(Pp, C, Binn, Kg, masks)
            if self.form == "linear":
                drive = np.einsum("bij,bnj->bni", Gam,
                                  np.einsum("bij,nj->bni", Bu, ua) + f0[:, None, :])
                ok = np.all(np.isfinite(Kg.reshape(Bc, -1)), axis=1)
                Y = np.full((Bc, seg.n, m), np.nan)
                Xf = np.full((Bc, seg.n, n), np.nan)
                if np.any(ok):
                    Y[ok], Xf[ok] = _kf_loop_jit(np.ascontiguousarray(Phi[ok]), np.ascontiguousarray(Kp[ok]),
                                                 pat, np.ascontiguousarray(C[ok]), np.ascontiguousarray(drive[ok]),
                                                 np.ascontiguousarray(offset[ok]), Z,
                                                 np.ascontiguousarray(X0.T[ok]))
            else:
                Y, Xf = self._nonlinear_loop(seg, k, P, X0, Kg, Kp, pat, c)
            out.append({"Y": Y, "B": Binn, "K": Kg, "P": Pp, "X": Xf,
                        "lin": (A[0], Bu[0], C[0], D[0])})
        return out

    def _nonlinear_loop(self, seg: Segment, k: int, P: np.ndarray, X0: np.ndarray,
                        Kg: np.ndarray, Kp: np.ndarray, pat: np.ndarray, c: Mapping[str, float]):
        """Integrator prediction and nonlinear outputs, constant gain per pattern of measured
        outputs (Kp (Bc, n_pat, n, m), pat (N,); Kg the full gain, NaN where the Riccati
        equation failed), batched over columns."""
        model = self.model
        kern = kernel_for(model)
        N, m = seg.n, len(model.outputs)
        n, Bc = X0.shape
        kmod = output_kernel(model) if self.compiled else None
        if kmod is not None:
            from estimators import integrators as _integ
            Y, Xf = getattr(kmod, f"nl_loop_{self.integrator}")(
                np.ascontiguousarray(X0, dtype=float), np.ascontiguousarray(seg.u), seg.t,
                np.ascontiguousarray(P, dtype=float), kern._c_jit(c), np.ascontiguousarray(Kp),
                pat, np.ascontiguousarray(seg.z), float(1e-8), float(1e-10),
                _integ.INPUT_MODES[self.inputs])
            # a diverging column is not an error here: its non-finite predictions make the
            # likelihood infinite, so a trial step that causes it is rejected (see _seg_nll);
            # fit() raises SimulationDivergedError when the accepted parameters diverge
            bad = ~np.all(np.isfinite(Kg.reshape(Bc, -1)), axis=1)
            Y[bad] = np.nan
            return Y, Xf
        Y = np.full((Bc, N, m), np.nan)
        Xf = np.full((Bc, N, n), np.nan)
        x = X0.copy()
        alive = np.ones(Bc, dtype=bool)
        for i in range(N):
            with np.errstate(all="ignore"):
                y = model.eval_g(x[:, None, :], seg.u[i][:, None, None], P, c)[:, 0, :]   # (m, Bc)
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
                    break                     # every column diverged: the rest stays NaN
                x = np.full_like(xh, np.nan)
                with np.errstate(all="ignore"):
                    xs = kern.integrate(self.integrator, xh[:, idx], seg.u[i:i + 2], seg.t[i:i + 2],
                                        P[:, idx], c, inputs=self.inputs)[1]
                    if np.all(np.isfinite(xs)):
                        x[:, idx] = xs
                    else:
                        for b in idx:
                            xb = kern.integrate(self.integrator, xh[:, b:b + 1], seg.u[i:i + 2],
                                                seg.t[i:i + 2], P[:, b:b + 1], c,
                                                inputs=self.inputs)[1]
                            if np.all(np.isfinite(xb)):
                                x[:, b] = xb[:, 0]
                            else:
                                alive[b] = False
        bad = ~np.all(np.isfinite(Kg.reshape(Bc, -1)), axis=1)
        Y[bad] = np.nan
        return Y, Xf

    # -- likelihood pieces ----------------------------------------------------------------------
    def _nll(self, res) -> float:
        J = 0.0
        for k, (seg, r) in enumerate(zip(self._segments, res)):
            Y, Bm = r["Y"][0], r["B"][0]
            if not np.all(np.isfinite(Bm)):
                return np.inf
            E = seg.z - Y
            J += self._seg_nll(E, Bm, *self._patterns[k])
        return J

    @staticmethod
    def _seg_nll(E: np.ndarray, Bm: np.ndarray, masks: np.ndarray, pat: np.ndarray) -> float:
        """Innovation likelihood over every sample, each on the outputs measured there
        (the block of B for them). A non-finite prediction of a measured output (a filter
        that diverged) makes J infinite: it must not shorten the sum (fewer samples would
        look like a better fit)."""
        val = 0.0
        for p, o in enumerate(masks):
            if not o.any():
                continue
            Ei = E[pat == p][:, o]
            if not np.all(np.isfinite(Ei)):
                return np.inf
            sign, logdet = np.linalg.slogdet(Bm[np.ix_(o, o)])
            if sign <= 0:
                return np.inf
            W = np.linalg.solve(Bm[np.ix_(o, o)], Ei.T)
            val += 0.5 * float(np.sum(Ei.T * W)) + 0.5 * Ei.shape[0] * logdet
        return val if np.isfinite(val) else np.inf

    def _segment_rows(self, nphi: int) -> list[np.ndarray]:
        """Per segment the columns of a sensitivity batch (:meth:`_batch`) it needs: 0 (the
        base) and 1 + the phi it depends on - the model parameters of
        ``Layout.relevant`` (shared ones and its own initial states) and every noise
        parameter. Without this every segment ran every other segment's initial states:
        G maneuvers cost G^2 filter runs."""
        fi = self._lay.free_idx
        noise = np.arange(fi.size, nphi)
        return [np.r_[0, 1 + np.searchsorted(fi, rel), 1 + noise] for rel in self._lay.relevant]

    def _scoring(self, res, hsteps: np.ndarray, rows: Sequence[np.ndarray],
                 keep: list | None = None):
        """Fisher information M, gradient g (of -J) and J from a batch (column 0 = base),
        each sample on the outputs measured there (per pattern of measured outputs, the
        block of B for them; samples whose measured outputs have a non-finite prediction
        left out). ``rows``: per segment the batch columns it was run with
        (:meth:`_segment_rows`, as given to :meth:`_filter`). ``keep``: a list that receives, per segment,
        (S innovation sensitivities (a :class:`Sensitivity`, (N, m) by its phi), E (N, m)
        innovations, B^-1, rows used, S^T B^-1 S (nphi, nphi): its part of M) for the
        coloured-innovation covariance - the samples where every output is measured (the
        others stay in M as white) - then the segment's whole part of M and of g (for the
        maneuver cluster covariance)."""
        nphi = hsteps.size
        M = np.zeros((nphi, nphi))
        g = np.zeros(nphi)
        J = 0.0
        for k, (seg, r) in enumerate(zip(self._segments, res)):
            M0, g0 = (M.copy(), g.copy()) if keep is not None else (None, None)
            cols = rows[k][1:] - 1                                   # its phi
            npk = cols.size
            Y, Bs = r["Y"], r["B"]
            E = seg.z - Y[0]
            Bm = Bs[0]
            S = (Y[1:] - Y[:1]) / hsteps[cols, None, None]           # (npk, N, m)
            S = np.where(np.isfinite(S), S, 0.0)
            dB = (Bs[1:] - Bs[:1]) / hsteps[cols, None, None]        # (npk, m, m)
            dB = np.where(np.isfinite(dB), dB, 0.0)
            masks, pat = self._patterns[k]
            full = np.zeros(seg.n, dtype=bool)
            M_full = np.zeros((nphi, nphi))
            for p, o in enumerate(masks):
                used = (pat == p) & np.all(np.isfinite(np.where(o, E, 0.0)), axis=1)
                if not (o.any() and used.any()):
                    continue
                Bo = Bm[np.ix_(o, o)]
                Binv = np.linalg.inv(Bo)
                Lw = np.linalg.cholesky(Binv)
                Eo = E[used][:, o]
                Sw = np.einsum("pnm,mk->pnk", S[:, used][:, :, o], Lw).reshape(npk, -1)
                M_S = Sw @ Sw.T
                add_block(M, cols, M_S)
                add_block(g, cols, Sw @ (Eo @ Lw).ravel())
                Nk = used.sum()
                T = np.einsum("ij,pjk->pik", Binv, dB[:, o][:, :, o])   # B^-1 B_i
                add_block(M, cols, 0.5 * Nk * np.einsum("pij,qji->pq", T, T))
                add_block(g, cols, 0.5 * np.einsum("pij,jk,kl->pil", T, Binv,
                                                   Eo.T @ Eo - Nk * Bo).trace(axis1=1, axis2=2))
                if o.all():
                    full = used
                    M_full = np.zeros((nphi, nphi))
                    add_block(M_full, cols, M_S)
            if keep is not None:
                keep.append((Sensitivity(np.where(full[:, None, None], np.moveaxis(S, 0, 2), 0.0),
                                         cols, nphi),
                             np.where(full[:, None], E, 0.0), np.linalg.inv(Bm), full, M_full,
                             M - M0, g - g0))
            J += self._seg_nll(E, Bm, masks, pat)
        return M, g, J

    def _raise_diverged(self, res) -> None:
        for k, (seg, r) in enumerate(zip(self._segments, res)):
            bad = np.isfinite(seg.z) & ~np.isfinite(r["Y"][0])
            if np.any(bad):
                i = int(np.argmax(np.any(bad, axis=1)))
                raise SimulationDivergedError(
                    f"the {'nonlinear ' if self.form == 'nonlinear' else ''}filter prediction of "
                    f"segment {seg.name or k} became non-finite at t={seg.t[i]:.4g} s (start "
                    "closer, e.g. from output-error or equation-error estimates, or give a "
                    "larger process-noise start)", segment=k, time=float(seg.t[i]))
        raise SimulationDivergedError("the filter-error likelihood is not finite at the "
                                      "current parameters")

    def _batch(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        hsteps = self.fd_step * np.maximum(np.abs(phi), self._floor)
        up_ok = phi + hsteps <= self._hi
        hsteps = np.where(up_ok, hsteps, -hsteps)
        Phis = np.repeat(phi[None, :], phi.size + 1, axis=0)
        Phis[1 + np.arange(phi.size), np.arange(phi.size)] += hsteps
        return Phis, hsteps

    # -- the fit --------------------------------------------------------------------------------
    def fit(self, segments: Segment | Sequence[Segment], estimate_x0: bool | Sequence[str] = False,
            start: Mapping[str, float] | None = None) -> EstimationResult:
        """Estimate the free parameters, F and G from one or several segments (see the class).
        ``start``: start values by expanded name, overriding the model's; an ``F_<state>``
        entry (an earlier fit's, for a refit) starts that state's process noise, or holds
        it with ``estimate_F=False``."""
        segments = [segments] if isinstance(segments, Segment) else list(segments)
        if not segments:
            raise ModelDefinitionError("fit() needs at least one segment")
        model = self.model
        self._segments = segments
        # per segment, once: the sample interval (jitter checked) and the patterns of
        # measured outputs
        self._h = [sample_interval(seg, k) for k, seg in enumerate(segments)]
        self._patterns = [output_patterns(seg.z) for seg in segments]
        lay = self._lay = Layout.build(model, segments, estimate_x0, values=start)
        check_outputs_measured(self.model, segments, "filter error")
        if self.form_requested == "auto":
            linear = self.inputs != "linear" and is_affine(model, segments, lay)
            self._set_form("linear" if linear else "nonlinear")
        m = len(model.outputs)
        self._noisy, f0 = self._noise_setup(segments)
        for i in self._noisy:   # an earlier fit's F (``start`` of a refit) over the default,
            v = (start or {}).get(f"F_{model.states[i]}")   # where it is not 0 (a start at 0
            if v is not None and float(v) > 0.0:            # gives F no gradient)
                f0[i] = float(v)
        self._f_fixed = f0.copy()
        fi = lay.free_idx
        names = list(lay.free_names)
        lo = list(lay.lower[fi]); hi = list(lay.upper[fi])
        phi = list(lay.values[fi])
        if self.estimate_F:
            for i in self._noisy:
                names.append(f"F_{model.states[i]}"); phi.append(f0[i] ** 2); lo.append(0.0); hi.append(np.inf)
        gnames = [f"G_{o}" for o in model.outputs]
        # measurement-noise start: from the innovations of the start model
        phi_arr = np.array(phi + [1.0] * m)
        if self.measurement_noise is not None:
            from estimators.kalman import _vector
            g0 = _vector(self.measurement_noise, model.outputs, "measurement_noise", np.ones(m))
        else:
            g0 = np.ones(m)
            phi_arr[-m:] = g0
            for _ in range(3):            # fixed point: G^2 ~ var(innovations) - C P C^T
                r0 = self._filter(phi_arr[None, :])
                E = [seg.z - r["Y"][0] for seg, r in zip(segments, r0)]
                V = np.diag(st.residual_covariance(E))
                CPC = np.diag(r0[0]["B"][0]) - phi_arr[-m:] ** 2
                if not np.all(np.isfinite(V)) or not np.all(np.isfinite(CPC)):
                    break
                g0 = np.sqrt(np.maximum(V - CPC, 0.1 * V))
                phi_arr[-m:] = g0
        phi_arr[-m:] = g0
        names += gnames
        lo += [0.0] * m; hi += [np.inf] * m
        self._lo, self._hi = np.array(lo, float), np.array(hi, float)
        self._scale = np.maximum(np.abs(phi_arr), 1e-12)
        self._held = np.zeros(phi_arr.size, dtype=bool)
        if not self.estimate_G:
            self._held[-m:] = True
        # finite-difference floor: 1 for model parameters (as OEM), the start for noise std
        self._floor = np.concatenate([np.ones(fi.size), self._scale[fi.size:]])
        phi = phi_arr
        nphi = phi.size
        seg_rows = self._segment_rows(nphi)
        history = []
        converged = False
        message = ""
        J_old = np.inf
        it = 0
        for it in range(1, self.max_iter + 1):
            Phis, hsteps = self._batch(phi)
            res = self._filter(Phis, rows=seg_rows)
            if not np.all(np.isfinite(res[0]["B"][0])):
                raise SimulationDivergedError(
                    "the filter-error Riccati equation has no stabilising solution at the "
                    "current parameters (system not detectable from the outputs?)")
            M, g, J = self._scoring(res, hsteps, seg_rows)
            if not np.isfinite(J):
                self._raise_diverged(res)
            if it == 1:
                # at the start only parameters without any effect are an error (a large start
                # F lets the filter follow the data and makes others weak, not unidentifiable)
                d = np.diag(M) * np.maximum(np.abs(phi), self._floor) ** 2    # scale-free
                dead = d <= 1e-14 * max(float(d.max()), 1e-300)
                if np.any(dead):
                    st.check_identifiable(np.diag(np.where(dead, 0.0, 1.0)), names,
                                          " at the start values")
            history.append({"iteration": it - 1, "J": J, "det_R": float(np.linalg.det(res[0]["B"][0])),
                            "step": np.nan, **dict(zip(names, self._report(phi)))})
            if self.callback:
                self.callback(it - 1, J, pd.Series(self._report(phi), index=names))
            if np.isfinite(J_old) and abs(J_old - J) <= self.tol * max(abs(J), 1.0):
                converged = True
                break
            J_old = J
            span = np.maximum(1.0, np.abs(phi))
            at_lo = phi <= self._lo + 1e-12 * span
            at_hi = phi >= self._hi - 1e-12 * span
            active = ~((at_lo & (g < 0)) | (at_hi & (g > 0))) & ~self._held
            a = np.flatnonzero(active)
            delta = np.zeros(nphi)
            delta[a] = st.solve_step(M[np.ix_(a, a)], g[a])
            alpha = 1.0
            accepted = False
            for _ in range(self.step_halvings + 1):
                trial = np.clip(phi + alpha * delta, self._lo, self._hi)
                # keep noise std off exactly zero from above (G > 0 needed for R > 0)
                trial[-m:] = np.maximum(trial[-m:], 1e-9 * self._scale[-m:])
                Jt = self._nll(self._filter(trial[None, :]))
                if Jt < J:
                    phi = trial
                    accepted = True
                    break
                alpha *= 0.5
            if not accepted:
                # Levenberg-Marquardt damping: bends the step towards the gradient
                for lam in (1e-2, 1e-1, 1.0, 10.0, 1e2, 1e3, 1e4):
                    d_lm = np.zeros(nphi)
                    d_lm[a] = st.solve_step(M[np.ix_(a, a)], g[a], lam)
                    trial = np.clip(phi + d_lm, self._lo, self._hi)
                    trial[-m:] = np.maximum(trial[-m:], 1e-9 * self._scale[-m:])
                    Jt = self._nll(self._filter(trial[None, :]))
                    if Jt < J:
                        phi = trial
                        accepted = True
                        alpha = -lam          # recorded as a negative step: LM with lambda
                        break
            history[-1]["step"] = alpha
            if not accepted:
                if 0.5 * float(g[a] @ delta[a]) <= 1e-9 * max(abs(J), 1.0):
                    converged = True
                    break
                message = "no step lowered the negative log-likelihood (line search failed)"
                break
        else:
            message = f"stopped at max_iter={self.max_iter} before J settled"
        # information at the final estimate
        Phis, hsteps = self._batch(phi)
        res = self._filter(Phis, rows=seg_rows)
        parts: list = []
        M, g, J = self._scoring(res, hsteps, seg_rows, keep=parts)
        from estimators.validation.cluster import ClusterResult, cluster_covariance
        span = np.maximum(1.0, np.abs(phi))
        on_bound = (phi <= self._lo + 1e-9 * span) | (phi >= self._hi - 1e-9 * span)
        inner = np.flatnonzero(~on_bound & ~self._held)
        on_bound &= ~self._held
        cov = np.full((nphi, nphi), np.nan)
        cov_mk = np.full((nphi, nphi), np.nan)
        cov_cl = np.full((nphi, nphi), np.nan)
        share = np.full((len(parts), nphi), np.nan)
        mk_lags: list[int] = []
        if inner.size:
            st.check_identifiable(M[np.ix_(inner, inner)], [names[i] for i in inner], " at the estimates")
            cov[np.ix_(inner, inner)] = st.covariance(M[np.ix_(inner, inner)])
            cov_mk[np.ix_(inner, inner)], mk_lags = _coloured_innovation_cov(
                M[np.ix_(inner, inner)], sum(p[4] for p in parts)[np.ix_(inner, inner)],
                [(S.take(inner), E, Bi, ok) for S, E, Bi, ok, *_ in parts])
            if len(parts) >= 2:
                # the maneuvers' scatter (estimators.validation.cluster), each segment a cluster
                try:
                    cl = cluster_covariance([p[5][np.ix_(inner, inner)] for p in parts],
                                            [p[6][inner] for p in parts], M[np.ix_(inner, inner)])
                    cov_cl[np.ix_(inner, inner)], share[:, inner] = cl.cov, cl.share
                except np.linalg.LinAlgError:
                    pass
        # report F as std: F = sqrt(phi_F); covariance and information by the chain rule
        D = self._dphi(phi)
        with np.errstate(divide="ignore", invalid="ignore"):
            cov = cov / np.outer(D, D)
            cov_mk = cov_mk / np.outer(D, D)
            cov_cl = cov_cl / np.outer(D, D)
        M = M * np.outer(D, D)
        keep = ~self._held
        cov, M = cov[np.ix_(keep, keep)], M[np.ix_(keep, keep)]
        cov_mk = cov_mk[np.ix_(keep, keep)]
        cov_cl = cov_cl[np.ix_(keep, keep)]
        kept_names = [nm for nm, k in zip(names, keep) if k]
        cluster = (None if len(parts) < 2 or not np.any(np.isfinite(share)) else ClusterResult(
            names=kept_names, cov=cov_cl, crb_std=np.sqrt(np.clip(np.diag(cov), 0.0, None)),
            share=share[:, keep]))
        theta, F, R = self._unpack(phi)
        E = [seg.z - r["Y"][0] for seg, r in zip(segments, res)]
        Ys = [r["Y"][0] for r in res]
        all_names = list(lay.names) + names[fi.size:]
        values = np.concatenate([theta, self._report(phi)[fi.size:]])
        free = np.concatenate([lay.free, ~self._held[fi.size:]])
        if not converged and not message:
            message = "did not converge"
        return EstimationResult(
            method=self.method, model=model, names=all_names, values=values, free=free, cov=cov,
            R=st.residual_covariance(E, full=True), converged=converged, iterations=it,
            history=pd.DataFrame(history), segments=segments,
            predicted=frames([s.t for s in segments], Ys, model.outputs),
            residuals=frames([s.t for s in segments], E, model.outputs),
            at_bounds=[names[i] for i in np.flatnonzero(on_bound)], message=message,
            information=M,
            settings={"form": self.form, "integrator": self.integrator if self.form == "nonlinear" else "transition matrix",
                      "optimizer": "gauss-newton", "estimate_F": self.estimate_F,
                      "estimate_G": self.estimate_G,
                      "linearisation": "about x0 and u[0] of each segment"},
            extra={"gain": [r["K"][0] for r in res], "F": F, "measurement_noise": R,
                   "innovation_cov": [r["B"][0] for r in res], "P": [r["P"][0] for r in res],
                   "linearisation": [dict(zip("ABCD", r["lin"])) for r in res],
                   "filtered_states": [pd.DataFrame(r["X"][0], index=pd.Index(s.t, name="t"),
                                                    columns=model.states) for s, r in zip(segments, res)],
                   "nll": J, "residuals_are": "innovations",
                   "mk_cov": cov_mk, "mk_names": kept_names,
                   "mk_max_lag": mk_lags, "cluster": cluster})
