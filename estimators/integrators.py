"""Fixed-step Euler, RK2, RK3, RK4 and adaptive RKF45 over a batch of trajectories.

Every integrator marches ``x`` of shape (n_states, B) - B trajectories at once, one per
parameter set of a finite-difference batch - over the sample times ``t`` (N,), with the
inputs interpolated linearly at each stage's own time by default (RK4 reads u_k,
(u_k + u_k+1)/2 twice and u_k+1: the reference software's convention, DEFAULT_INPUTS) or
held at U[k] (zero-order hold). The right-hand side is a kernel

    rhs(x (n, B), u (n_in,), P (n_p, B), c, out (n, B)) -> None

built by :mod:`estimators.compile.kernels`. The functions below are plain Python; ``estimators.compile.kernels``
compiles the same source with numba, so there is one definition of each scheme. Their
array arithmetic goes through the small helpers of :data:`ARRAY_HELPERS` (numpy here);
the compiled kernels bind those names to the element loops of :data:`LOOP_HELPERS`
instead, which give the same numbers operation for operation: numba compiles loops over
scalars several times faster than numpy array expressions (whose first use in a process
compiles numba's broadcasting machinery, seconds), and a fresh installation's first fit
waits for that compile.

The integrators return X of shape (N, n, B). When a state becomes non-finite the rest of
the trajectory is filled with NaN and marching stops (the caller reports divergence).
This module does not import numba: :mod:`estimators.compile.kernels` does, when it compiles.
"""

from __future__ import annotations

import numpy as np

from estimators.errors import ModelDefinitionError

INTEGRATORS = ("euler", "rk2", "rk3", "rk4", "rkf45")
#: how inputs vary inside a sample interval [t_k, t_k+1]: "linear" interpolates them at each
#: integration stage's time (sampled continuous signals; the reference software's RK4), "hold"
#: keeps U[k] (zero-order hold: step inputs that switch exactly at samples, e.g. a flight
#: computer's commands)
INPUT_MODES = {"linear": 1, "hold": 2}
#: the input convention of every integrator and estimator unless told otherwise
DEFAULT_INPUTS = "linear"
ORDER = {"euler": 1, "rk2": 2, "rk3": 3, "rk4": 4, "rkf45": 5}


def check_options(integrator: str, inputs: str) -> None:
    """Raise ModelDefinitionError naming the choices when ``integrator`` or ``inputs`` is
    not one of INTEGRATORS / INPUT_MODES (shared by every estimator's constructor)."""
    if integrator not in INTEGRATORS:
        raise ModelDefinitionError(f"unknown integrator {integrator!r}: use one of {INTEGRATORS}")
    if inputs not in INPUT_MODES:
        raise ModelDefinitionError(f"inputs must be one of {list(INPUT_MODES)}, not {inputs!r}")


# -- array helpers: numpy here, element loops in the compiled kernels ------------------------
def _u_at(U, i, s, mode):
    """Inputs at fraction s in [0, 1] of interval i (see INPUT_MODES), a new (n_in,) array."""
    if mode == 1:
        return U[i] + s * (U[i + 1] - U[i])
    return U[i].copy()


def _finite(x):
    """True when every element of the (n, B) array x is finite."""
    return bool(np.isfinite(x).all())


def _copy(x):
    """A copy of the (n, B) array x."""
    return x.copy()


def _put(dst, src):
    """dst[...] = src for (n, B) arrays."""
    dst[...] = src


def _start(x0, N):
    """The (N, n, B) trajectory array: x0 (n, B) at sample 0, NaN after."""
    X = np.full((N,) + x0.shape, np.nan)
    X[0] = x0
    return X


def _stage(xs, x, h, A, j, K):
    """xs = x + sum_{m<j} (h A[j, m]) K[m] in place (terms with A[j, m] = 0 skipped), the
    state at which stage j of a Runge-Kutta step evaluates the right-hand side."""
    xs[...] = x
    for m in range(j):
        if A[j, m] != 0.0:
            xs += (h * A[j, m]) * K[m]


def _advance(X, i, x, h, b, K):
    """x += sum_j (h b[j]) K[j] in place (zero weights skipped), then X[i] = x when every
    element is finite; returns False (X[i] untouched) when one is not."""
    for j in range(b.size):
        if b[j] != 0.0:
            x += (h * b[j]) * K[j]
    if not np.isfinite(x).all():
        return False
    X[i] = x
    return True


def _combine(x, h, w, K):
    """x + h * (w[0] K[0] + w[1] K[1] + ...), summed left to right; w a tuple of floats,
    K a tuple of (n, B) arrays of the same length."""
    acc = w[0] * K[0]
    for m in range(1, len(w)):
        acc = acc + w[m] * K[m]
    return x + h * acc


def _scaled_sum(h, w, K):
    """h * (w[0] K[0] + w[1] K[1] + ...), summed left to right (see _combine)."""
    acc = w[0] * K[0]
    for m in range(1, len(w)):
        acc = acc + w[m] * K[m]
    return h * acc


def _error_norm(err, x, x5, rtol, atol):
    """max |err| / (atol + rtol max(|x|, |x5|)) over every element (RKF45's step control)."""
    return np.max(np.abs(err) / (atol + rtol * np.maximum(np.abs(x), np.abs(x5))))


def _u_at_loop(U, i, s, mode):
    n_in = U.shape[1]
    u = np.empty(n_in)
    if mode == 1:
        for k in range(n_in):
            u[k] = U[i, k] + s * (U[i + 1, k] - U[i, k])
    else:
        for k in range(n_in):
            u[k] = U[i, k]
    return u


def _finite_loop(x):
    for q in range(x.shape[0]):
        for r in range(x.shape[1]):
            if not np.isfinite(x[q, r]):
                return False
    return True


def _copy_loop(x):
    y = np.empty((x.shape[0], x.shape[1]))
    for q in range(x.shape[0]):
        for r in range(x.shape[1]):
            y[q, r] = x[q, r]
    return y


def _put_loop(dst, src):
    for q in range(src.shape[0]):
        for r in range(src.shape[1]):
            dst[q, r] = src[q, r]


def _start_loop(x0, N):
    n, B = x0.shape
    X = np.empty((N, n, B))
    for q in range(n):
        for r in range(B):
            X[0, q, r] = x0[q, r]
    for i in range(1, N):
        for q in range(n):
            for r in range(B):
                X[i, q, r] = np.nan
    return X


def _stage_loop(xs, x, h, A, j, K):
    n, B = x.shape
    for q in range(n):
        for r in range(B):
            v = x[q, r]
            for m in range(j):
                if A[j, m] != 0.0:
                    v += (h * A[j, m]) * K[m, q, r]
            xs[q, r] = v


def _advance_loop(X, i, x, h, b, K):
    n, B = x.shape
    ok = True
    for q in range(n):
        for r in range(B):
            v = x[q, r]
            for j in range(b.size):
                if b[j] != 0.0:
                    v += (h * b[j]) * K[j, q, r]
            x[q, r] = v
            if not np.isfinite(v):
                ok = False
    if ok:
        for q in range(n):
            for r in range(B):
                X[i, q, r] = x[q, r]
    return ok


def _combine_loop(x, h, w, K):
    n, B = x.shape
    y = np.empty((n, B))
    for q in range(n):
        for r in range(B):
            acc = w[0] * K[0][q, r]
            for m in range(1, len(w)):
                acc = acc + w[m] * K[m][q, r]
            y[q, r] = x[q, r] + h * acc
    return y


def _scaled_sum_loop(h, w, K):
    n, B = K[0].shape
    y = np.empty((n, B))
    for q in range(n):
        for r in range(B):
            acc = w[0] * K[0][q, r]
            for m in range(1, len(w)):
                acc = acc + w[m] * K[m][q, r]
            y[q, r] = h * acc
    return y


def _error_norm_loop(err, x, x5, rtol, atol):
    out = -np.inf
    for q in range(err.shape[0]):
        for r in range(err.shape[1]):
            a, b = abs(x[q, r]), abs(x5[q, r])
            big = a if (a > b or a != a) else b  # np.maximum: NaN propagates
            v = abs(err[q, r]) / (atol + rtol * big)
            if v != v:  # np.max: NaN propagates
                return v
            if v > out:
                out = v
    return out


#: the helpers the schemes call, by name, and the element loops that stand for them in the
#: compiled kernels (estimators.compile.kernels binds each name to its loop compiled with numba)
ARRAY_HELPERS = (
    "_u_at",
    "_finite",
    "_copy",
    "_put",
    "_start",
    "_stage",
    "_advance",
    "_combine",
    "_scaled_sum",
    "_error_norm",
)
LOOP_HELPERS = {name: globals()[name + "_loop"] for name in ARRAY_HELPERS}


def _explicit_rk(rhs, x0, U, t, P, c, mode, A, b, cu):
    """One explicit Runge-Kutta scheme given by its tableau: stage j evaluates the
    right-hand side at x + h sum_l A[j, l] k_l with the inputs at fraction cu[j] of the
    interval; the step is x + h sum_j b[j] k_j."""
    N = t.size
    n, B = x0.shape
    s = b.size
    X = _start(x0, N)
    x = _copy(x0)
    xs = np.empty((n, B))
    K = np.empty((s, n, B))
    for i in range(N - 1):
        h = t[i + 1] - t[i]
        for j in range(s):
            _stage(xs, x, h, A, j, K)
            rhs(xs, _u_at(U, i, cu[j], mode), P, c, K[j])
        if not _advance(X, i + 1, x, h, b, K):
            break
    return X


# Butcher tableaux (A, b) and the interval fraction at which each stage reads the inputs
# (its own time: c of the tableau).
_EULER = (np.zeros((1, 1)), np.array([1.0]), np.array([0.0]))
#: Heun's method (trapezoidal predictor-corrector), order 2
_RK2 = (np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([0.5, 0.5]), np.array([0.0, 1.0]))
#: Kutta's third-order method
_RK3 = (
    np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [-1.0, 2.0, 0.0]]),
    np.array([1.0, 4.0, 1.0]) / 6.0,
    np.array([0.0, 0.5, 1.0]),
)
#: classical fourth-order Runge-Kutta
_RK4 = (
    np.array([[0.0, 0.0, 0.0, 0.0], [0.5, 0.0, 0.0, 0.0], [0.0, 0.5, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]),
    np.array([1.0, 2.0, 2.0, 1.0]) / 6.0,
    np.array([0.0, 0.5, 0.5, 1.0]),
)
_EULER_A, _EULER_B, _EULER_C = _EULER
_RK2_A, _RK2_B, _RK2_C = _RK2
_RK3_A, _RK3_B, _RK3_C = _RK3
_RK4_A, _RK4_B, _RK4_C = _RK4


def euler(rhs, x0, U, t, P, c, rtol, atol, mode):
    """Explicit Euler, order 1."""
    return _explicit_rk(rhs, x0, U, t, P, c, mode, _EULER_A, _EULER_B, _EULER_C)


def rk2(rhs, x0, U, t, P, c, rtol, atol, mode):
    """Heun's method, order 2."""
    return _explicit_rk(rhs, x0, U, t, P, c, mode, _RK2_A, _RK2_B, _RK2_C)


def rk3(rhs, x0, U, t, P, c, rtol, atol, mode):
    """Kutta's third-order method."""
    return _explicit_rk(rhs, x0, U, t, P, c, mode, _RK3_A, _RK3_B, _RK3_C)


def rk4(rhs, x0, U, t, P, c, rtol, atol, mode):
    """Classical fourth-order Runge-Kutta."""
    return _explicit_rk(rhs, x0, U, t, P, c, mode, _RK4_A, _RK4_B, _RK4_C)


def rkf45(rhs, x0, U, t, P, c, rtol, atol, mode):
    """Runge-Kutta-Fehlberg 4(5) with step-size control inside each sample interval
    (local extrapolation: the 5th-order solution is kept). The error norm is the largest
    scaled error over all states and all trajectories of the batch, so the batch shares
    its steps and finite differences between its members stay smooth."""
    N = t.size
    n, B = x0.shape
    X = _start(x0, N)
    x = _copy(x0)
    k1 = np.empty((n, B))
    k2 = np.empty((n, B))
    k3 = np.empty((n, B))
    k4 = np.empty((n, B))
    k5 = np.empty((n, B))
    k6 = np.empty((n, B))
    h = t[1] - t[0]
    ok = True
    for i in range(N - 1):
        tau = t[i]
        t_end = t[i + 1]
        n_sub = 0
        while tau < t_end and ok:
            if tau + h > t_end:
                h = t_end - tau
            s0 = (tau - t[i]) / (t_end - t[i])
            ds = h / (t_end - t[i])
            rhs(x, _u_at(U, i, s0, mode), P, c, k1)
            rhs(_combine(x, h, (0.25,), (k1,)), _u_at(U, i, s0 + 0.25 * ds, mode), P, c, k2)
            rhs(_combine(x, h, (3.0 / 32.0, 9.0 / 32.0), (k1, k2)), _u_at(U, i, s0 + 0.375 * ds, mode), P, c, k3)
            rhs(
                _combine(x, h, (1932.0 / 2197.0, -(7200.0 / 2197.0), 7296.0 / 2197.0), (k1, k2, k3)),
                _u_at(U, i, s0 + 12.0 / 13.0 * ds, mode),
                P,
                c,
                k4,
            )
            rhs(
                _combine(x, h, (439.0 / 216.0, -8.0, 3680.0 / 513.0, -(845.0 / 4104.0)), (k1, k2, k3, k4)),
                _u_at(U, i, s0 + ds, mode),
                P,
                c,
                k5,
            )
            rhs(
                _combine(
                    x, h, (-8.0 / 27.0, 2.0, -(3544.0 / 2565.0), 1859.0 / 4104.0, -(11.0 / 40.0)), (k1, k2, k3, k4, k5)
                ),
                _u_at(U, i, s0 + 0.5 * ds, mode),
                P,
                c,
                k6,
            )
            x5 = _combine(
                x,
                h,
                (16.0 / 135.0, 6656.0 / 12825.0, 28561.0 / 56430.0, -(9.0 / 50.0), 2.0 / 55.0),
                (k1, k3, k4, k5, k6),
            )
            err = _scaled_sum(
                h, (1.0 / 360.0, -(128.0 / 4275.0), -(2197.0 / 75240.0), 1.0 / 50.0, 2.0 / 55.0), (k1, k3, k4, k5, k6)
            )
            enorm = _error_norm(err, x, x5, rtol, atol)
            if not np.isfinite(enorm):
                ok = False
                break
            n_sub += 1
            if enorm <= 1.0 or n_sub > 10000:
                tau += h
                x = x5
                fac = 5.0 if enorm == 0.0 else min(5.0, 0.9 * enorm**-0.2)
            else:
                fac = max(0.1, 0.9 * enorm**-0.25)
            h = h * fac
        if not ok or not _finite(x):
            break
        _put(X[i + 1], x)
    return X


PY_SCHEMES = {"euler": euler, "rk2": rk2, "rk3": rk3, "rk4": rk4, "rkf45": rkf45}
