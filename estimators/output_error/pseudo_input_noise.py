"""Covariance of estimates from a model fed its own noisy measurements (pseudo-inputs).

Stabilised output error and equation decoupling (:mod:`estimators.output_error.stabilized`) feed
measured outputs back into the model. The measurement noise v then enters the residuals
twice: directly, and through the model's response to the noisy pseudo-inputs,

    e = v - G v_pseudo,     G = C (zI - A)^-1 B_pseudo + D_pseudo,

so the residuals are coloured by the model itself and the Cramér-Rao bounds, which
assume white residuals, are too small (several times for the moment derivatives of an
unstable aircraft). To first order in the noise the
estimation error is theta_hat - theta = M^-1 sum_n T_n v_n with

    T_n[:, j] = a_n[j] - sum_k J_n[k, j] sum_{l>=0} sum_i g_l[i, k] a_{n+l}[i],
    a_n = R^-1 S_n  (S_n: output sensitivities at sample n),

(g_l the impulse response of G, J_n[k, j] = d pseudo_k / d z_j at sample n), hence

    Cov(theta_hat) = M^-1 (sum_n T_n diag(s^2) T_n^T) M^-1.

The anti-causal sum is a backward (adjoint) recursion over each segment
(:func:`adjoint_sums`), vectorised over the parameters; it runs over the segment only, so
a mildly unstable fed model (equation decoupling leaves the phugoid free) or a chain of
integrators (a kinematic model driven by the IMU) is handled as well as a stable one. G
is the model linearised at the estimate at each segment's first sample and discretised
with a zero-order hold. Where a channel has no measurement (a 50 Hz vane on a 100 Hz
grid) the pseudo-input was filled by linear interpolation; its coefficients go back to
the two measured samples it came from. Inputs that are measurements themselves
(``noisy_inputs``: the IMU of flight-path reconstruction) add their noise through G
only. The noise variances s^2 come from the measurements themselves
(:func:`estimators.statistics.difference_noise_std`, robust), not from the residuals,
which also carry the noise's echo through the feedback.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
from scipy import signal

from estimators import statistics as st
from estimators.defaults import FED_GROWTH_LIMIT, PSEUDO_FD_STEP
from estimators.filters.linearize import linearize_batch
from estimators.layout import Layout
from estimators.model import Model, Segment
from estimators.sensitivity import add_block, as_sensitivity


class PropagationError(ValueError):
    """The fed-back noise cannot be propagated (the fed model diverges over a segment, a
    channel has too few samples to estimate its noise)."""


def pseudo_mixing(
    segment: Segment, outputs: Sequence[str], pseudo_outputs: Sequence[str], pseudo: Callable | None
) -> np.ndarray:
    """J (N, n_pseudo, n_out): d pseudo_k / d z_j per sample. Without a ``pseudo`` callable
    pseudo-input k is the measurement of ``pseudo_outputs[k]`` (J one-hot); with one
    (``pseudo(segment, states) -> (N, n_pseudo)``, a per-sample function of the
    measurements) J comes from central differences on every output channel at once."""
    N, r = segment.n, len(outputs)
    J = np.zeros((N, len(pseudo_outputs), r))
    if pseudo is None:
        for k, o in enumerate(pseudo_outputs):
            J[:, k, outputs.index(o)] = 1.0
        return J
    for j in range(r):
        zj = segment.z[:, j]
        step = PSEUDO_FD_STEP * max(float(np.nanmax(np.abs(zj))) if np.any(np.isfinite(zj)) else 1.0, 1e-3)
        vals = []
        for sgn in (1.0, -1.0):
            z = segment.z.copy()
            z[:, j] = z[:, j] + sgn * step
            s = Segment(t=segment.t, u=segment.u, z=z, x0=segment.x0, constants=segment.constants, name=segment.name)
            vals.append(np.asarray(pseudo(s, list(pseudo_outputs)), dtype=float).reshape(N, -1))
        J[:, :, j] = np.nan_to_num((vals[0] - vals[1]) / (2 * step))
    return J


def onto_measured(c: np.ndarray, t: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """Coefficients c (N, ...) of a pseudo-input sample on the noise of one channel, moved
    from the samples where the channel has no measurement (filled by linear interpolation
    in time, :func:`estimators.output_error.stabilized._fill`) onto the two measured samples the
    filled value came from, with the interpolation weights."""
    if measured.all():
        return c
    idx = np.flatnonzero(measured)
    if not idx.size:
        return np.zeros_like(c)
    miss = np.flatnonzero(~measured)
    pos = np.searchsorted(idx, miss)
    lo = idx[np.clip(pos - 1, 0, idx.size - 1)]
    hi = idx[np.clip(pos, 0, idx.size - 1)]
    span = t[hi] - t[lo]
    w = np.where(span > 0, (t[miss] - t[lo]) / np.where(span > 0, span, 1.0), 0.0)
    w = w.reshape(-1, *([1] * (c.ndim - 1)))
    out = np.where(measured.reshape(-1, *([1] * (c.ndim - 1))), c, 0.0)
    np.add.at(out, lo, (1.0 - w) * c[miss])
    np.add.at(out, hi, w * c[miss])
    return out


def _fed_system(
    model: Model, segment: Segment, values: Mapping[str, float], pseudo_cols: Sequence[int]
) -> tuple[np.ndarray, ...]:
    """G as a discrete system (Ad, Bd, Cd, Dd), inputs the columns ``pseudo_cols``: the fed
    model linearised at the segment's first sample, zero-order hold at its median step.
    Raises PropagationError when G grows more than FED_GROWTH_LIMIT-fold over the segment."""
    lay = Layout.build(model, [segment], values=values)
    P = lay.values[lay.pidx[0]][:, None]
    x0 = lay.values[lay.x0idx[0]][:, None]
    A, B, C, D, _, _ = linearize_batch(model, P, x0, np.nan_to_num(segment.u[0]), model.constants_for(segment))
    A, B, C, D = A[0], B[0][:, pseudo_cols], C[0], D[0][:, pseudo_cols]
    h = float(np.median(np.diff(segment.t)))
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete((A, B, C, D), h, method="zoh")
    rho = float(np.max(np.abs(np.linalg.eigvals(Ad))))
    if segment.n * np.log(max(rho, 1e-300)) > np.log(FED_GROWTH_LIMIT):
        raise PropagationError(
            f"the model fed with its measurements is not stable at the "
            f"estimate: it grows {rho:.4f}x per sample, more than {FED_GROWTH_LIMIT:g}x over "
            f"segment {segment.name or ''} ({segment.n} samples)"
        )
    return Ad, Bd, Cd, Dd


def adjoint_sums(Ad: np.ndarray, Bd: np.ndarray, Cd: np.ndarray, Dd: np.ndarray, a: np.ndarray) -> np.ndarray:
    """back (N, n_in, n_p): back_m = sum_{l>=0} g_l^T a_{m+l} over the rest of the segment,
    g_0 = Dd, g_l = Cd Ad^(l-1) Bd (the discrete system's impulse response), a (N, n_out,
    n_p). The backward (adjoint) recursion mu_{m-1} = Cd^T a_m + Ad^T mu_m, back_m =
    Dd^T a_m + Bd^T mu_m: one small matrix product per sample, vectorised over the
    parameters, and exact for integrators and mildly unstable modes alike (a transfer
    function of the same system loses the integrator chains of a kinematic model)."""
    N, _, n_p = a.shape
    back = np.empty((N, Bd.shape[1], n_p))
    mu = np.zeros((Ad.shape[0], n_p))
    AT, BT, CT, DT = Ad.T, Bd.T, Cd.T, Dd.T
    for m in range(N - 1, -1, -1):
        back[m] = DT @ a[m] + BT @ mu
        mu = CT @ a[m] + AT @ mu
    return back


def propagated_covariance(
    model: Model,
    segments: Sequence[Segment],
    values: Mapping[str, float],
    sensitivities: Sequence[np.ndarray],
    residuals: Sequence[np.ndarray],
    R: np.ndarray,
    info: np.ndarray,
    pseudo_outputs: Sequence[str],
    pseudo: Callable | None = None,
    noisy_inputs: Sequence[str] = (),
    prior_info: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(cov (n_p, n_p), s^2) of the estimates of a model fed measurements (see the module
    docstring); s^2 the measurement-noise variances used, (n_out + len(noisy_inputs),):
    the outputs', then the noisy inputs'.

    model: the fed (transformed) model; its last len(pseudo_outputs) inputs are the
        pseudo-inputs, pseudo-input k derived from the measurement of pseudo_outputs[k].
    segments: the fitted segments of that model; values: the estimates (name -> value).
    sensitivities: per segment (N, n_out, n_p) or a
        :class:`~estimators.sensitivity.Sensitivity`; residuals: per segment (N, n_out) (NaN =
        missing); R: the residual covariance the fit weighted with (n_out, n_out); info:
        M = sum S^T R^-1 S (n_p, n_p). pseudo: as :func:`pseudo_mixing`.
    noisy_inputs: other inputs that are measurements with white noise of their own (the
        IMU driving a kinematic model): their noise only echoes, through G.
    prior_info: the a-priori part of ``info`` (output error's priors), added to the middle
        term as :func:`estimators.validation.morelli_klein` does.
    Raises PropagationError when the fed model diverges over a segment at the estimate.
    """
    outs = list(model.outputs)
    npse = len(pseudo_outputs)
    cols = list(range(len(model.inputs) - npse, len(model.inputs)))
    icols = [model.inputs.index(n) for n in noisy_inputs]
    W = np.linalg.inv(np.atleast_2d(R))
    systems = [_fed_system(model, s, values, cols + icols) for s in segments]
    Js = [pseudo_mixing(s, outs, pseudo_outputs, pseudo) for s in segments]
    res = [np.asarray(e, dtype=float) for e in residuals]
    s2 = st.difference_noise_std([s.z for s in segments], robust=True) ** 2
    s2_in = st.difference_noise_std([s.u[:, icols] for s in segments], robust=True) ** 2 if icols else np.zeros(0)
    if not np.all(np.isfinite(s2)) or not np.all(np.isfinite(s2_in)):
        raise PropagationError(
            "too few samples to estimate the measurement noise of "
            + ", ".join(o for o, v in zip(outs + list(noisy_inputs), np.r_[s2, s2_in]) if not np.isfinite(v))
        )
    mid = np.zeros_like(info, dtype=float)
    for seg, S, e, J, sys_ in zip(segments, sensitivities, res, Js, systems):
        ok = np.isfinite(e)
        b = as_sensitivity(S)  # the segment's own columns
        a = np.matmul(W, np.where(ok[:, :, None], np.nan_to_num(b.values), 0.0))
        T = a.copy()  # (N, n_out noise channel, n_p)
        back = adjoint_sums(*sys_, a)  # (N, n_pseudo + n_noisy, n_p)
        for k in range(npse):
            for j in np.flatnonzero(np.any(J[:, k, :] != 0, axis=0)):
                T[:, j, :] -= onto_measured(J[:, k, j, None] * back[:, k], seg.t, ok[:, j])
        # a noisy input's noise only echoes
        add_block(
            mid,
            b.cols,
            np.einsum("nkp,k,nkq->pq", back[:, npse:], s2_in, back[:, npse:]) + np.einsum("njp,j,njq->pq", T, s2, T),
        )
    if prior_info is not None:
        mid += np.asarray(prior_info, dtype=float)
    Minv = st.covariance(info)
    cov = Minv @ mid @ Minv
    return 0.5 * (cov + cov.T), np.r_[s2, s2_in]
