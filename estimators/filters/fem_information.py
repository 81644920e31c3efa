"""The filter-error estimate's information and covariances: the Gauss-Newton information
and gradient from a batch of perturbed filter runs (forward differences of the one-step
predictions, the gain's gradients included), and at the estimate the Cramér-Rao covariance
(the inverse of the final information for the innovation covariance there, as the
reference software's; with the full R of the likelihood, the information with R estimated
too), its Morelli-Klein correction for coloured
innovations and the maneuvers' scatter (each segment a cluster).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from estimators import statistics as st
from estimators.covariance.cluster import ClusterResult, cluster_covariance
from estimators.covariance.uncertainty import coloured_information
from estimators.filters.fem_problem import FemProblem, SegmentFilter
from estimators.sensitivity import Sensitivity, add_block


@dataclass
class SegmentScore:
    """One segment's part of the scoring (:func:`scoring`): the innovation sensitivities
    ``S`` and innovations ``E`` on the samples where every output is measured (``rows``,
    (N,) bool; zero elsewhere), R^-1 ``Rinv`` (m, m), the part of the information M from
    those samples ``M_full`` and from all of the segment's samples ``M`` (n_phi, n_phi),
    and its part of the gradient ``g`` (n_phi,)."""

    S: Sensitivity
    E: np.ndarray
    Rinv: np.ndarray
    rows: np.ndarray
    M_full: np.ndarray
    M: np.ndarray
    g: np.ndarray


@dataclass
class FemCovariance:
    """The information and covariances at the filter-error estimate phi (n_phi,): the
    filter runs there (``batch``, column 0 the estimate), the information ``M`` for the
    innovation covariance there (with a full R: R estimated too), the Cramér-Rao covariance ``cov`` and its Morelli-Klein correction
    ``mk_cov`` (NaN rows and columns for phi on a bound, ``on_bound``), the lag of the
    innovations' autocorrelation used per segment ``mk_lags``, and the maneuvers'
    scatter ``cluster`` (None with one segment)."""

    batch: list[SegmentFilter]
    M: np.ndarray
    cov: np.ndarray
    mk_cov: np.ndarray
    mk_lags: list[int]
    cluster: ClusterResult | None
    on_bound: np.ndarray


def coloured_innovation_cov(M: np.ndarray, M_S: np.ndarray, parts: list) -> tuple[np.ndarray, list[int]]:
    """Covariance of the filter-error estimates when the innovations are not white
    (Morelli-Klein on the innovations): M^-1 (M - M_S + M_S~) M^-1, where M_S = sum S^T
    B^-1 S is the part of the information M carried by the innovation sensitivities S (as
    :func:`scoring` summed it) and M_S~ the same sum with the innovations' own
    autocorrelation in place of B
    (:func:`estimators.covariance.uncertainty.coloured_information`). The part of M from
    the innovation covariance's dependence on the parameters (dB/dtheta) is kept as it is.
    White innovations give M^-1 back; a filter model that misses some of the process
    (coloured innovations) gets wider bounds. parts: per segment (S (N, m, n_p), E (N, m),
    B^-1 (m, m), rows used (N,)). Returns ((n_p, n_p), lag per segment)."""
    mid, lags = coloured_information(
        [p[0] for p in parts],
        [p[1] for p in parts],
        [p[2] for p in parts],
        [np.repeat(p[3][:, None], p[1].shape[1], axis=1) for p in parts],
    )
    Minv = st.covariance(M)
    cov = Minv @ (M - M_S + mid) @ Minv
    return 0.5 * (cov + cov.T), lags


def scoring(
    prob: FemProblem, res, R: np.ndarray, hsteps: np.ndarray, rows: Sequence[np.ndarray], keep: list | None = None
):
    """Information M = sum S^T R^-1 S and gradient g = sum S^T R^-1 nu (of -J) for the
    fixed innovation covariance R, plus the gradient of diag(K C) per segment
    (list of (n, nphi)), from a batch (column 0 = base). Each sample counts on the outputs
    measured there. ``keep`` receives per segment its :class:`SegmentScore` for the
    coloured-innovation and maneuver-scatter covariances. Returns
    (M, g, dCK, per segment S (n_cols, N, m) on its batch columns)."""
    nphi = hsteps.size
    M = np.zeros((nphi, nphi))
    g = np.zeros(nphi)
    dCK = []
    sens = []
    for k, (seg, r) in enumerate(zip(prob.segments, res)):
        cols = rows[k][1:] - 1
        npk = cols.size
        Y = r.Y
        E = seg.z - Y[0]
        S = (Y[1:] - Y[:1]) / hsteps[cols, None, None]  # (npk, N, m)
        S = np.where(np.isfinite(S), S, 0.0)
        sens.append(S)
        G = np.zeros((r.CK.shape[1], nphi))
        G[:, cols] = ((r.CK[1:] - r.CK[:1]) / hsteps[cols, None]).T
        dCK.append(np.where(np.isfinite(G), G, 0.0))
        masks, pat = prob.patterns[k]
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
                SegmentScore(
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


def marginal_information(
    prob: FemProblem,
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
    segment the innovation sensitivities of :func:`scoring` and their batch columns."""
    m = R.shape[0]
    pairs = [(i, j) for i in range(m) for j in range(i, m) if i == j or prob.full_R]
    nphi = phi.size
    nr = len(pairs)
    Mpr = np.zeros((nphi, nr))
    Mrr = np.zeros((nr, nr))
    Es = []
    for i, j in pairs:
        E = np.zeros((m, m))
        E[i, j] = E[j, i] = 1.0
        Es.append(E)
    for k, (seg, r) in enumerate(zip(prob.segments, batch)):
        Y0 = r.Y[0]
        S_phi = np.zeros((nphi, seg.n, m))
        S_phi[rows[k][1:] - 1] = S[k]
        S_r = np.zeros((nr, seg.n, m))
        for a, (i, j) in enumerate(pairs):
            d = rel_step * np.sqrt(R[i, i] * R[j, j])
            rr = prob.filter(phi[None, :], R + d * Es[a])
            if prob.constraint_ok(rr):  # else its gain over-corrects: no gradient
                S_r[a] = (rr[k].Y[0] - Y0) / d
        S_r = np.where(np.isfinite(S_r), S_r, 0.0)
        masks, pat = prob.patterns[k]
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


def covariances(prob: FemProblem, phi: np.ndarray, R: np.ndarray, rows: Sequence[np.ndarray]) -> FemCovariance:
    """The information and covariances at the estimate phi for the innovation covariance
    R there; ``rows`` per segment the sensitivity batch's columns
    (:meth:`~estimators.filters.fem_problem.FemProblem.segment_rows`)."""
    batch, hsteps = prob.sensitivity_batch(phi, R, rows)
    parts: list[SegmentScore] = []
    M, _, _, sens = scoring(prob, batch, R, hsteps, rows, keep=parts)
    if prob.full_R:  # the likelihood's bound: R estimated too
        M = marginal_information(prob, M, phi, batch, R, sens, rows)
    names = prob.names
    nphi = phi.size
    span = np.maximum(1.0, np.abs(phi))
    on_bound = (phi <= prob.lo + 1e-9 * span) | (phi >= prob.hi - 1e-9 * span)
    inner = np.flatnonzero(~on_bound)
    cov = np.full((nphi, nphi), np.nan)
    cov_mk = np.full((nphi, nphi), np.nan)
    mk_lags: list[int] = []
    if inner.size:
        st.check_identifiable(M[np.ix_(inner, inner)], [names[i] for i in inner], " at the estimates")
        cov[np.ix_(inner, inner)] = st.covariance(M[np.ix_(inner, inner)])
        cov_mk[np.ix_(inner, inner)], mk_lags = coloured_innovation_cov(
            M[np.ix_(inner, inner)],
            sum(p.M_full for p in parts)[np.ix_(inner, inner)],
            [(p.S.take(inner), p.E, p.Rinv, p.rows) for p in parts],
        )
    cluster = _maneuver_scatter(parts, inner, M, cov, names, prob.lay.free_idx.size)
    return FemCovariance(batch, M, cov, cov_mk, mk_lags, cluster, on_bound)


def _maneuver_scatter(
    parts: list[SegmentScore], inner: np.ndarray, M: np.ndarray, cov: np.ndarray, names: list[str], n_model: int
) -> ClusterResult | None:
    """The maneuvers' scatter over the model's parameters (the first ``n_model`` of phi)
    not on a bound (``inner``), each segment a cluster; None with fewer than 2 segments
    or when it cannot be had. The process noise is left out: it is the air's, whose
    intensity differs between maneuvers without any fault of the model."""
    nphi = M.shape[0]
    cov_cl = np.full((nphi, nphi), np.nan)
    share = np.full((len(parts), nphi), np.nan)
    if inner.size and len(parts) >= 2:
        # each segment's score at the optimum of the whole: g_k - M_k M^-1 sum g (the
        # iterations stop with a small gradient left, which is not the maneuvers'
        # disagreement)
        mi = inner[inner < n_model]
        Mi = [p.M[np.ix_(mi, mi)] for p in parts]
        try:
            step = np.linalg.solve(sum(Mi), sum(p.g[mi] for p in parts))
        except np.linalg.LinAlgError:
            step = np.zeros(mi.size)
        try:
            cl = cluster_covariance(Mi, [p.g[mi] - Mk @ step for p, Mk in zip(parts, Mi)], M[np.ix_(mi, mi)])
            cov_cl[np.ix_(mi, mi)], share[:, mi] = cl.cov, cl.share
        except np.linalg.LinAlgError:
            pass
    if len(parts) < 2 or not np.any(np.isfinite(share)):
        return None
    return ClusterResult(names=names, cov=cov_cl, crb_std=np.sqrt(np.clip(np.diag(cov), 0.0, None)), share=share)
