"""Affine approximation of a model about a reference point, batched over parameter sets:
f ~ A x + B u + f0, g ~ C x + D u + y0 by central differences, and the test whether a
model is affine over its data (the filter-error method's choice of its linear form).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from estimators.layout import Layout
from estimators.model import Model, Segment


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
