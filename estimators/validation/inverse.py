"""Inverse simulation: the control inputs that make a linear model follow measured
outputs, computed with a feedback loop closed around the model, and the residual inputs.

Loop (sampled: the model is discretised exactly with a zero-order hold on u over each
sample interval dt, and the loop acts at the samples, like a digital controller):

    u_k = u_ref_k + K (z_k - y_k),   y_k = C x_k + D u_k,   x_{k+1} = Phi x_k + Gam u_k
    => u_k = M (u_ref_k + K z_k - K C x_k),  M = (I + K D)^-1

so the closed loop x_{k+1} = (Phi - Gam M K C) x_k + Gam M (u_ref_k + K z_k) is one linear
system driven by the measured outputs (scipy's dlsim marches it). With the true model and
u_ref the flown inputs, the residual inputs are zero; where the model is wrong, u - u_ref
shows what the model needed beyond the measured inputs (its deficiency).

Default gain: K = bandwidth * pinv(Wt C B) Wt with Wt = diag(weights): the tracked output
errors of outputs that respond directly to the inputs (C B != 0) decay at about
``bandwidth`` rad/s (default min(20, 0.3/dt), so the sampled loop is stable); weights (default 1/std(z) per output) make units commensurable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, signal

from ._util import as_2d

__all__ = ["InverseSimResult", "inverse_simulation"]


@dataclass(frozen=True)
class InverseSimResult:
    """``t`` (N,) s; ``u`` (N, n_in) inputs that make the model follow z; ``residual_inputs``
    u - u_ref (N, n_in); ``y`` (N, n_out) model outputs; ``x`` (N, n) states;
    ``tracking_error`` z - y (N, n_out); ``K`` (n_in, n_out) the gain used."""

    t: np.ndarray
    u: np.ndarray
    residual_inputs: np.ndarray
    y: np.ndarray
    x: np.ndarray
    tracking_error: np.ndarray
    K: np.ndarray


def inverse_simulation(
    A, B, C, D, t, z, u_ref=None, x0=None, *, K=None, bandwidth: float | None = None, weights=None
) -> InverseSimResult:
    """Inputs that make the linear model (A, B, C, D) follow measured outputs z.

    A (n, n), B (n, n_in), C (n_out, n), D (n_out, n_in) or None (continuous time), in perturbation
    variables (subtract trim values from z and u first); t (N,) s uniformly sampled;
    z (N, n_out) measured outputs; u_ref (N, n_in) the measured inputs or None (zeros);
    x0 (n,) initial state (default zeros). K (n_in, n_out) overrides the default gain
    bandwidth * pinv(W C B) W (bandwidth rad/s, W = diag(weights), weights default
    1/std(z)). Returns an :class:`InverseSimResult`.
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    n = A.shape[0]
    B = np.asarray(B, dtype=float).reshape(n, -1)
    C = np.asarray(C, dtype=float).reshape(-1, n)
    n_in, n_out = B.shape[1], C.shape[0]
    D = np.zeros((n_out, n_in)) if D is None else np.asarray(D, dtype=float).reshape(n_out, n_in)
    t = np.asarray(t, dtype=float)
    z = as_2d(z, "z")
    if z.shape != (t.size, n_out):
        raise ValueError(f"z must be (N, n_out) = ({t.size}, {n_out}), got {z.shape}")
    u_ref = np.zeros((t.size, n_in)) if u_ref is None else as_2d(u_ref, "u_ref")
    x0 = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).ravel()
    dt = np.diff(t)
    if t.size < 2 or not np.allclose(dt, dt[0], rtol=1e-6, atol=0):
        raise ValueError("t must be uniformly sampled with at least 2 samples")
    dt = float(dt[0])
    if bandwidth is None:
        bandwidth = min(20.0, 0.3 / dt)
    if K is None:
        if weights is None:
            sd = z.std(axis=0)
            weights = np.where(sd > 0, 1.0 / np.where(sd > 0, sd, 1.0), 1.0)
        Wt = np.diag(np.asarray(weights, dtype=float))
        CB = Wt @ C @ B
        if not np.any(np.abs(CB) > 0):
            raise ValueError("no output responds directly to the inputs (C B = 0): give K")
        K = bandwidth * np.linalg.pinv(CB) @ Wt
    K = np.asarray(K, dtype=float).reshape(n_in, n_out)
    M = np.linalg.inv(np.eye(n_in) + K @ D)
    E = linalg.expm(np.block([[A, B], [np.zeros((n_in, n + n_in))]]) * dt)
    Phi, Gam = E[:n, :n], E[:n, n:]
    GM = Gam @ M
    Acl = Phi - GM @ K @ C
    rho = float(np.max(np.abs(np.linalg.eigvals(Acl))))
    if rho >= 1.0:
        raise ValueError(
            f"inverse-simulation loop unstable (spectral radius {rho:.3g}): "
            f"lower bandwidth (now {bandwidth:g} rad/s at dt = {dt:g} s) or give K"
        )
    ext = np.hstack([u_ref, z])
    sys = (Acl, np.hstack([GM, GM @ K]), np.eye(n), np.zeros((n, n_in + n_out)), dt)
    _, x, _ = signal.dlsim(sys, ext, t=t - t[0], x0=x0)
    x = np.asarray(x).reshape(t.size, n)
    u = (u_ref + (z - x @ C.T) @ K.T) @ M.T
    y = x @ C.T + u @ D.T
    return InverseSimResult(t=t, u=u, residual_inputs=u - u_ref, y=y, x=x, tracking_error=z - y, K=K)
