"""Affine approximation of a model about a reference point, batched over parameter sets:
f ~ A x + B u + f0, g ~ C x + D u + y0 by central differences.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from estimators.model import Model


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
