"""How uncertain a held-out prediction is from the estimates' own uncertainty.

A proof of match holds the identified model fixed and compares its simulation of a
maneuver it was not fitted to with the measurements. When a channel leaves its band, the
engineer needs to know why: either the model's form (or its inputs) is wrong, or the
derivatives are right within their uncertainty and that uncertainty alone moves the
prediction beyond the band (too little information in the fitted maneuvers for this
one: a maneuver that excites a combination of derivatives the fitted ones did not).

To first order, a parameter error dtheta moves the prediction by S dtheta, S = dy/dtheta
the prediction's sensitivity (N, n_out, n_p). The proof of match fits the held-out
segment's own initial state and output biases, which take up part of that move; with
S_a their sensitivities and W the inverse measurement-noise variance per output, what is
left is the projection

    S_perp = S - S_a (S_a^T W S_a)^+ S_a^T W S

and the prediction's std from a parameter covariance P is sqrt(diag(S_perp P S_perp^T))
per sample and output (:func:`prediction_std`). Pointwise: each sample's std, not a band
the whole time history stays inside with a given probability.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from estimators.integrators import DEFAULT_INPUTS
from estimators.layout import Layout
from estimators.model import Model, Segment
from estimators.simulation import simulate_batch

__all__ = ["parameter_sensitivity", "prediction_std", "variance_shares"]


def parameter_sensitivity(
    model: Model,
    segment: Segment,
    values: Mapping[str, float],
    names: Sequence[str],
    adjusted: Sequence[str] = (),
    *,
    weights: Sequence[float] | None = None,
    integrator: str = "rk4",
    inputs: str = DEFAULT_INPUTS,
    rel_step: float = 1e-6,
) -> np.ndarray:
    """dy/dtheta (N, n_out, len(names)) of ``model``'s simulation of ``segment`` (one
    segment: per-segment parameters and initial states by their layout names,
    ``bias_az[0]``, ``x0_q[0]``), at ``values`` (layout names; the model's values and the
    segment's initial state elsewhere), for the parameters ``names`` with those of
    ``adjusted`` refitted to the segment (the projection of the module docstring; ``weights``
    (n_out,) the inverse measurement-noise variance per output, default 1; samples with a
    NaN measurement carry no weight). Forward differences, all parameters in one batched
    simulation, step ``rel_step`` x max(|value|, 1) (model units)."""
    lay = Layout.build(model, [segment], estimate_x0=True, values=values)
    idx = {n: i for i, n in enumerate(lay.names)}
    missing = [n for n in [*names, *adjusted] if n not in idx]
    if missing:
        raise ValueError(f"not parameters of the model on this segment: {missing} (layout names: {lay.names})")
    cols = [idx[n] for n in [*names, *adjusted]]
    h = rel_step * np.maximum(np.abs(lay.values[cols]), 1.0)
    theta = np.repeat(lay.values[None, :], len(cols) + 1, axis=0)
    theta[np.arange(1, len(cols) + 1), cols] += h
    Y = simulate_batch(model, segment, theta, lay, 0, integrator, inputs=inputs)  # (N, m, B)
    S = (Y[:, :, 1:] - Y[:, :, :1]) / h
    S_theta, S_a = S[:, :, : len(names)], S[:, :, len(names) :]
    if not len(adjusted):
        return S_theta
    w = np.ones(len(model.outputs)) if weights is None else np.asarray(weights, dtype=float)
    w = np.where(np.isfinite(segment.z), w[None, :], 0.0)  # (N, m)
    A = np.einsum("nma,nm,nmb->ab", S_a, w, S_a)
    B = np.einsum("nma,nm,nmp->ap", S_a, w, S_theta)
    return S_theta - np.einsum("nma,ap->nmp", S_a, np.linalg.pinv(A) @ B)


def prediction_std(S: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """sqrt(diag(S P S^T)) per sample and output, (N, n_out), for sensitivities S
    (N, n_out, n_p) and a parameter covariance P (n_p, n_p) in the same order."""
    S = np.asarray(S, dtype=float)
    return np.sqrt(np.clip(np.einsum("nmi,ij,nmj->nm", S, np.asarray(cov, dtype=float), S), 0.0, None))


def variance_shares(s: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Each parameter's share of the variance s^T P s of one predicted value, (n_p,):
    s_i (P s)_i / (s^T P s), summing to 1 (a share is negative where a correlation with
    the others lowers the variance). ``s`` (n_p,) its sensitivities, ``cov`` P (n_p, n_p).
    Zeros when the variance is 0."""
    s = np.asarray(s, dtype=float)
    Ps = np.asarray(cov, dtype=float) @ s
    var = float(s @ Ps)
    return s * Ps / var if var > 0 else np.zeros_like(s)
