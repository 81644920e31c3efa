"""Fixed-step Euler, RK2, RK3, RK4 and adaptive RKF45 over a batch of trajectories.

Every integrator marches ``x`` of shape (n_states, B) - B trajectories at once, one per
parameter set of a finite-difference batch - over the sample times ``t`` (N,), with the
inputs averaged over each step, ``u = (U[k] + U[k+1]) / 2``, held over [t_k, t_k+1]
(the convention of Jategaonkar's output-error codes). The right-hand side is a kernel

    rhs(x (n, B), u (n_in,), P (n_p, B), c, out (n, B)) -> None

built by :mod:`estimators.jit`. The functions below are plain Python; ``estimators.jit``
compiles the same source with numba, so there is one definition of each scheme.

The integrators return X of shape (N, n, B). When a state becomes non-finite the rest of
the trajectory is filled with NaN and marching stops (the caller reports divergence).
"""
from __future__ import annotations

import numpy as np

try:  # the same source runs compiled (estimators.jit) and as plain Python
    from numba.extending import register_jitable
except ImportError:  # pragma: no cover - numba is a dependency; keep numpy-only use possible
    def register_jitable(fn):
        return fn

INTEGRATORS = ("euler", "rk2", "rk3", "rk4", "rkf45")
#: how inputs vary inside a sample interval [t_k, t_k+1]: "average" holds (U[k] + U[k+1]) / 2
#: (Jategaonkar's convention, default), "linear" interpolates at each stage time (for
#: sampled continuous signals), "hold" keeps U[k] (zero-order hold: step inputs that switch
#: exactly at samples, e.g. a flight computer's commands)
INPUT_MODES = {"average": 0, "linear": 1, "hold": 2}
ORDER = {"euler": 1, "rk2": 2, "rk3": 3, "rk4": 4, "rkf45": 5}


def check_options(integrator: str, inputs: str) -> None:
    """Raise ModelDefinitionError naming the choices when ``integrator`` or ``inputs`` is
    not one of INTEGRATORS / INPUT_MODES (shared by every estimator's constructor)."""
    from estimators.errors import ModelDefinitionError

    if integrator not in INTEGRATORS:
        raise ModelDefinitionError(f"unknown integrator {integrator!r}: use one of {INTEGRATORS}")
    if inputs not in INPUT_MODES:
        raise ModelDefinitionError(f"inputs must be one of {list(INPUT_MODES)}, not {inputs!r}")


@register_jitable
def _u_at(U, i, s, mode):
    """Inputs at fraction s in [0, 1] of interval i (see INPUT_MODES)."""
    if mode == 0:
        return 0.5 * (U[i] + U[i + 1])
    if mode == 1:
        return U[i] + s * (U[i + 1] - U[i])
    return U[i].copy()


@register_jitable
def _finite(x):
    for v in x.ravel():
        if not np.isfinite(v):
            return False
    return True


@register_jitable
def _explicit_rk(rhs, x0, U, t, P, c, mode, A, b, cu):
    """One explicit Runge-Kutta scheme given by its tableau: stage j evaluates the
    right-hand side at x + h sum_l A[j, l] k_l with the inputs at fraction cu[j] of the
    interval; the step is x + h sum_j b[j] k_j."""
    N = t.size
    n, B = x0.shape
    s = b.size
    X = np.full((N, n, B), np.nan)
    x = x0.copy()
    X[0] = x
    K = np.empty((s, n, B))
    for i in range(N - 1):
        h = t[i + 1] - t[i]
        for j in range(s):
            xs = x.copy()
            for m in range(j):
                if A[j, m] != 0.0:
                    xs += (h * A[j, m]) * K[m]
            rhs(xs, _u_at(U, i, cu[j], mode), P, c, K[j])
        for j in range(s):
            if b[j] != 0.0:
                x = x + (h * b[j]) * K[j]
        if not _finite(x):
            break
        X[i + 1] = x
    return X


# Butcher tableaux (A, b) and the interval fraction at which each stage reads the inputs.
# Euler reads them mid-interval, so "linear" inputs integrate a sampled ramp exactly.
_EULER = (np.zeros((1, 1)), np.array([1.0]), np.array([0.5]))
#: Heun's method (trapezoidal predictor-corrector), order 2
_RK2 = (np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([0.5, 0.5]), np.array([0.0, 1.0]))
#: Kutta's third-order method
_RK3 = (np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [-1.0, 2.0, 0.0]]),
        np.array([1.0, 4.0, 1.0]) / 6.0, np.array([0.0, 0.5, 1.0]))
#: classical fourth-order Runge-Kutta
_RK4 = (np.array([[0.0, 0.0, 0.0, 0.0], [0.5, 0.0, 0.0, 0.0], [0.0, 0.5, 0.0, 0.0],
                  [0.0, 0.0, 1.0, 0.0]]),
        np.array([1.0, 2.0, 2.0, 1.0]) / 6.0, np.array([0.0, 0.5, 0.5, 1.0]))
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
    X = np.full((N, n, B), np.nan)
    x = x0.copy()
    X[0] = x
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
            rhs(x + h * (0.25 * k1), _u_at(U, i, s0 + 0.25 * ds, mode), P, c, k2)
            rhs(x + h * (3.0 / 32.0 * k1 + 9.0 / 32.0 * k2), _u_at(U, i, s0 + 0.375 * ds, mode),
                P, c, k3)
            rhs(x + h * (1932.0 / 2197.0 * k1 - 7200.0 / 2197.0 * k2 + 7296.0 / 2197.0 * k3),
                _u_at(U, i, s0 + 12.0 / 13.0 * ds, mode), P, c, k4)
            rhs(x + h * (439.0 / 216.0 * k1 - 8.0 * k2 + 3680.0 / 513.0 * k3
                         - 845.0 / 4104.0 * k4), _u_at(U, i, s0 + ds, mode), P, c, k5)
            rhs(x + h * (-8.0 / 27.0 * k1 + 2.0 * k2 - 3544.0 / 2565.0 * k3
                         + 1859.0 / 4104.0 * k4 - 11.0 / 40.0 * k5), _u_at(U, i, s0 + 0.5 * ds, mode),
                P, c, k6)
            x5 = x + h * (16.0 / 135.0 * k1 + 6656.0 / 12825.0 * k3 + 28561.0 / 56430.0 * k4
                          - 9.0 / 50.0 * k5 + 2.0 / 55.0 * k6)
            err = h * (1.0 / 360.0 * k1 - 128.0 / 4275.0 * k3 - 2197.0 / 75240.0 * k4
                       + 1.0 / 50.0 * k5 + 2.0 / 55.0 * k6)
            scale = atol + rtol * np.maximum(np.abs(x), np.abs(x5))
            enorm = np.max(np.abs(err) / scale)
            if not np.isfinite(enorm):
                ok = False
                break
            n_sub += 1
            if enorm <= 1.0 or n_sub > 10000:
                tau += h
                x = x5
                fac = 5.0 if enorm == 0.0 else min(5.0, 0.9 * enorm ** -0.2)
            else:
                fac = max(0.1, 0.9 * enorm ** -0.25)
            h = h * fac
        if not ok or not _finite(x):
            break
        X[i + 1] = x
    return X


PY_SCHEMES = {"euler": euler, "rk2": rk2, "rk3": rk3, "rk4": rk4, "rkf45": rkf45}
