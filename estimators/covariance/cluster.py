"""Maneuver-to-maneuver scatter: the parameter covariance with each maneuver a cluster.

The Cramér-Rao bound M^-1 is the scatter the estimates would have if the model were exact
and its residuals white. On flight data the estimates from different maneuvers scatter
more (Jategaonkar's course notes: "use a fudge factor of 5-10"); the Morelli-Klein
correction covers residuals coloured within a maneuver, not a model that fits one
maneuver differently from the next. The cluster-robust (sandwich) covariance measures that
on the flight itself, from each maneuver's share of the fit - no refit:

    Cov = M^-1 ( sum_j s~_j s~_j^T ) M^-1,    s~_j = M^(1/2) (I - B_j)^(-1/2) M^(-1/2) s_j,

with M = sum_j M_j the information (plus any prior's), M_j = S_j^T W S_j maneuver j's part,
s_j = S_j^T W e_j its part of the gradient at the estimate (S sensitivities, e residuals,
W the inverse residual / innovation covariance) and B_j = M^(-1/2) M_j M^(-1/2), whose
eigenvalues (0..1) are the maneuver's leverage. The factor (I - B_j)^(-1/2) is the
Bell-McCaffrey ("CR2") correction: a fitted maneuver's residuals are smaller than its
noise by its leverage, and without it a maneuver that carries most of the information on a
parameter would hide its own scatter. For a linear model with white residuals E[Cov] is
then exactly M^-1, however unequal the maneuvers (unlike the delete-one-maneuver
jackknife, which inflates the bounds when the maneuvers excite different derivatives);
when the estimates really differ between maneuvers, Cov grows with that difference - less
than fully where one maneuver carries most of a parameter's information, since a
maneuver's own offset sits in its estimate more than in its residuals.

:func:`maneuver_scatter` gives it for a fit's result (output error from its sensitivities;
filter error and equation error keep their own), to report beside the Cramér-Rao and
Morelli-Klein std.

What it cannot do:
- a parameter that one maneuver alone identifies (that maneuver carries more than
  ``limit``, 0.95, of its information: a per-maneuver bias or initial state, a derivative
  only one maneuver excites) has no scatter to measure: NaN;
- it has about G - 1 degrees of freedom (G maneuvers): with 2 or 3, one parameter's value
  is a rough figure (for an exact bound the ratio of the std lies within 0.06-1.96 (2
  maneuvers) or 0.23-1.73 (3) in 90 % of cases and exceeds 3 with probability 0.003 or
  1e-4). The median over parameters pools them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from estimators.defaults import CLUSTER_FLAG_RATIO, CLUSTER_MIN_SEGMENTS, CLUSTER_SHARE_LIMIT
from estimators.sensitivity import add_block, as_sensitivity

__all__ = ["ClusterResult", "cluster_covariance", "maneuver_scatter", "segment_block", "segment_parts"]


@dataclass(frozen=True)
class ClusterResult:
    """Cluster-robust covariance (n_p, n_p) (NaN rows and columns where not estimable),
    the Cramér-Rao std sqrt(diag M^-1), and ``share`` (G, n_p): the part of each
    parameter's information that maneuver j alone carries, 1 - (M^-1)_kk /
    ((M - M_j)^-1)_kk (1 where the other maneuvers cannot identify it); ``std`` and
    ``ratio`` = std / crb_std follow from them."""

    names: list[str]
    cov: np.ndarray
    crb_std: np.ndarray
    share: np.ndarray
    limit: float = CLUSTER_SHARE_LIMIT

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    @property
    def ratio(self) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.std / np.where(self.crb_std > 0, self.crb_std, np.nan)

    @property
    def n_segments(self) -> int:
        return self.share.shape[0]

    def ratio_summary(self, flag: float = CLUSTER_FLAG_RATIO) -> dict:
        """Over the system parameters (not the per-segment ``name[k]``) with a ratio:
        ``median_ratio``, ``max_ratio``, ``max_parameter`` (None without any) and
        ``flagged`` ({name: ratio} above ``flag``, largest first)."""
        r = pd.Series(self.ratio, index=self.names)
        r = r[[not (n.endswith("]") and "[" in n) for n in r.index]].dropna()
        if r.empty:
            return {"median_ratio": None, "max_ratio": None, "max_parameter": None, "flagged": {}}
        return {
            "median_ratio": float(r.median()),
            "max_ratio": float(r.max()),
            "max_parameter": str(r.idxmax()),
            "flagged": {n: float(v) for n, v in r[r > flag].sort_values(ascending=False).items()},
        }

    def to_frame(self) -> pd.DataFrame:
        """Rows per parameter: ``crb_std``, ``cluster_std``, ``ratio``, ``max_share``."""
        return pd.DataFrame(
            {
                "crb_std": self.crb_std,
                "cluster_std": self.std,
                "ratio": self.ratio,
                "max_share": self.share.max(axis=0),
            },
            index=pd.Index(self.names, name="parameter"),
        )


def segment_block(
    S: Any, e: np.ndarray, Winv: np.ndarray
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """One maneuver's information M_j = sum_i S_i^T W S_i and gradient part
    s_j = sum_i S_i^T W e_i for the parameters it depends on: ((cols, (m, m)), (cols, (m,))).

    S : (N, n_out, n_p) sensitivities of the outputs (or innovations) to the parameters,
        or a :class:`~estimators.sensitivity.Sensitivity` (the maneuver's own columns).
    e : (N, n_out) residuals; a non-finite residual leaves its sample's output out.
    Winv : (n_out, n_out) inverse residual covariance W, or (N, n_out, n_out) per sample.
    """
    b = as_sensitivity(S)
    e = np.asarray(e, dtype=float)
    ok = np.isfinite(e) & np.all(np.isfinite(b.values), axis=2)
    e0 = np.where(ok, e, 0.0)
    S0 = np.where(ok[:, :, None], b.values, 0.0)
    WS = np.matmul(np.asarray(Winv, dtype=float), S0)
    return (
        (b.cols, np.einsum("nip,niq->pq", S0, WS, optimize=True)),
        (b.cols, np.einsum("nip,ni->p", WS, e0, optimize=True)),
    )


def segment_parts(S: Any, e: np.ndarray, Winv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`segment_block` as dense ((n_p, n_p), (n_p,)) arrays."""
    (cols, A), (_, g) = segment_block(S, e, Winv)
    n_p = as_sensitivity(S).n_free
    M, s = np.zeros((n_p, n_p)), np.zeros(n_p)
    add_block(M, cols, A)
    add_block(s, cols, g)
    return M, s


def _inverse_diagonal(A: np.ndarray, rtol: float = 1e-10) -> np.ndarray:
    """diag(A^-1) of a symmetric positive semi-definite A, +inf for a parameter with a part
    in A's null space (not identifiable from the information A)."""
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    null = w <= rtol * max(w.max(initial=0.0), 1e-300)
    d = (V[:, ~null] ** 2 / w[~null]).sum(axis=1)
    return np.where((V[:, null] ** 2).sum(axis=1) > 1e-8, np.inf, d)


def _block(Mj: Any, sj: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cols, M_j block, s_j block) of one maneuver's information and score for the
    parameters it informs (M_j's diagonal > 0: a segment's sensitivity columns include
    parameters it does not move, e.g. the rudder derivatives on an aileron doublet), from
    a (cols, block) pair and a (cols, vector) pair (:func:`segment_block`) or from dense
    (n_p, n_p), (n_p,) arrays."""
    if isinstance(Mj, tuple):
        cols, A = np.asarray(Mj[0], dtype=int), np.asarray(Mj[1], dtype=float)
        if not (isinstance(sj, tuple) and np.array_equal(sj[0], cols)):
            raise ValueError("an information block (cols, M_j) needs its score as (cols, s_j)")
        b = np.asarray(sj[1], dtype=float)
    else:
        cols = np.arange(np.shape(Mj)[0])
        A, b = np.asarray(Mj, dtype=float), np.asarray(sj, dtype=float)
    keep = np.diag(A) > 0
    return cols[keep], 0.5 * (A + A.T)[np.ix_(keep, keep)], b[keep]


def _pinv_scaled(A: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of a symmetric information block, taken on the matrix scaled to unit
    diagonal (a derivative's information and an initial state's differ by 1e10: unscaled,
    the small directions fell under pinv's cut-off)."""
    d = np.diag(A)
    D = np.where(d > 0, 1.0 / np.sqrt(np.where(d > 0, d, 1.0)), 0.0)
    return np.linalg.pinv(A * np.outer(D, D), hermitian=True) * np.outer(D, D)


def _core(Mj: np.ndarray, sj: np.ndarray, M: np.ndarray, limit: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cov (p, p), crb std (p,), share (G, p)) of the module doc from the maneuvers'
    information Mj (G, p, p), scores sj (G, p) and the whole information M (p, p)."""
    G, p = sj.shape
    # worked in parameters scaled to unit information (derivatives, noise std and biases
    # differ by orders of magnitude); the result does not depend on the scaling
    d = np.diag(M)
    if np.any(~(d > 0)):
        raise np.linalg.LinAlgError("the information matrix is singular: no covariance")
    D = 1.0 / np.sqrt(d)
    M, Mj, sj = M * np.outer(D, D), Mj * np.outer(D, D), sj * D
    w, V = np.linalg.eigh(M)
    if w.min(initial=np.inf) <= 1e-12 * max(w.max(initial=0.0), 1e-300):
        raise np.linalg.LinAlgError("the information matrix is singular: no covariance")
    W = (V / np.sqrt(w)) @ V.T  # M^-1/2
    Wi = (V * np.sqrt(w)) @ V.T  # M^1/2
    Minv = W @ W
    share = np.stack([1.0 - np.diag(Minv) / _inverse_diagonal(M - Mj[j]) for j in range(G)])
    C = np.zeros((p, p))
    for j in range(G):
        B = W @ Mj[j] @ W
        lam, U = np.linalg.eigh(0.5 * (B + B.T))
        lam = np.clip(lam, 0.0, limit)
        st = Wi @ (U * (1.0 - lam) ** -0.5) @ U.T @ W @ sj[j]
        C += np.outer(st, st)
    cov = (Minv @ C @ Minv) * np.outer(D, D)
    return 0.5 * (cov + cov.T), np.sqrt(np.diag(Minv)) * D, share


def cluster_covariance(
    M_parts: Sequence[Any],
    scores: Sequence[Any],
    M: np.ndarray | None = None,
    *,
    names: Sequence[str] | None = None,
    limit: float = CLUSTER_SHARE_LIMIT,
) -> ClusterResult:
    """The cluster-robust covariance of the module doc, each maneuver a cluster.

    M_parts : per maneuver its information M_j, (n_p, n_p) or a pair (cols, block (m, m))
        for the parameters it informs (:func:`segment_block`).
    scores : per maneuver its gradient part s_j at the estimate, (n_p,) or (cols, (m,)).
    M : the whole information (default sum M_j; give it when a prior adds to it; needed
        with blocks unless ``names`` gives n_p).
    limit : a parameter whose information one maneuver carries more than this share of
        (``share``) is not estimable here (NaN).

    Parameters that one maneuver alone informs (its own initial states and biases; a
    derivative only it excites) are profiled out first (Schur complement: exact for the
    sandwich of the others, and their leverage is that of the others alone): their share
    is 1 and their covariance NaN, and the rest is worked in the space of the parameters
    several maneuvers share. Without that, G maneuvers with k own parameters each cost
    O(G (p + G k)^3) time and G (p + G k)^2 memory, which a long log of a hundred maneuvers
    or more cannot afford.
    """
    G = len(M_parts)
    if G < 2 or len(scores) != G:
        raise ValueError(
            f"need one information part and one score per maneuver and at least 2 maneuvers (got {G} and {len(scores)})"
        )
    parts = [_block(Mj, sj) for Mj, sj in zip(M_parts, scores)]
    if M is not None:
        n_p = np.shape(M)[0]
    elif not isinstance(M_parts[0], tuple):
        n_p = np.shape(M_parts[0])[0]
    elif names is not None:
        n_p = len(names)
    else:
        n_p = 1 + max(int(c.max(initial=-1)) for c, _, _ in parts)
    if M is None:
        M = np.zeros((n_p, n_p))
        for c, A, _ in parts:
            add_block(M, c, A)
    M = 0.5 * (np.asarray(M, float) + np.asarray(M, float).T)
    count = np.zeros(n_p, dtype=int)
    for c, _, _ in parts:
        count[c] += 1
    own = count == 1
    shared = np.flatnonzero(~own)
    p = shared.size
    Mj = np.zeros((G, p, p))
    sj = np.zeros((G, p))
    Mr = M[np.ix_(shared, shared)].copy()
    owned: list[tuple[int, np.ndarray, np.ndarray]] = []  # (maneuver, own cols, M_oo^-1)
    for j, (c, A, b) in enumerate(parts):
        o = own[c]
        pos = np.searchsorted(shared, c[~o])
        Acc, Aco, Aoo = A[np.ix_(~o, ~o)], A[np.ix_(~o, o)], A[np.ix_(o, o)]
        K = Aco @ _pinv_scaled(Aoo) if o.any() else np.zeros((pos.size, 0))
        Mj[j][np.ix_(pos, pos)] = Acc - K @ Aco.T
        sj[j][pos] = b[~o] - K @ b[o]
        if o.any():
            co = c[o]
            Moo_inv = _pinv_scaled(M[np.ix_(co, co)])
            Mco = M[np.ix_(shared, co)]
            Mr -= Mco @ Moo_inv @ Mco.T
            owned.append((j, co, Moo_inv))
    Mr = 0.5 * (Mr + Mr.T)
    cov = np.full((n_p, n_p), np.nan)
    crb = np.full(n_p, np.nan)
    share = np.zeros((G, n_p))
    if p:
        cov_s, crb_s, share_s = _core(Mj, sj, Mr, limit)
        cov[np.ix_(shared, shared)] = cov_s
        crb[shared] = crb_s
        share[:, shared] = share_s
    Mr_inv = _pinv_scaled(Mr) if p else np.zeros((0, 0))
    for j, co, Moo_inv in owned:
        # the own parameters' Cramér-Rao variance: the block inverse's diagonal
        share[j, co] = 1.0
        X = Moo_inv @ M[np.ix_(co, shared)]
        crb[co] = np.sqrt(np.clip(np.diag(Moo_inv + X @ Mr_inv @ X.T), 0.0, None))
    bad = share.max(axis=0) > limit
    cov[bad, :] = np.nan
    cov[:, bad] = np.nan
    names = list(names) if names is not None else [f"p{k}" for k in range(n_p)]
    return ClusterResult(names=names, cov=cov, crb_std=crb, share=share, limit=limit)


def maneuver_scatter(result, min_segments: int = CLUSTER_MIN_SEGMENTS) -> ClusterResult | None:
    """The maneuver cluster covariance of an :class:`~estimators.EstimationResult`: the one
    the fit kept (``extra["cluster"]``: filter error from its own per-segment information,
    an equation-error fit from its regression windows), else from output error's
    sensitivities, residuals and R; None with fewer than ``min_segments`` segments, for a
    method that keeps neither (EKF, UKF), or when the information is singular."""
    if len(result.segments or []) < min_segments:
        return None
    if "cluster" in (result.extra or {}):
        return result.extra["cluster"]
    if not result.sensitivities or len(result.sensitivities) != len(result.segments):
        return None
    try:
        Rinv = np.linalg.pinv(np.atleast_2d(np.asarray(result.R, dtype=float)))
        parts = [segment_block(S, e.to_numpy(), Rinv) for S, e in zip(result.sensitivities, result.residuals)]
        M = result.information
        if M is None or np.shape(M)[0] != len(result.free_names):
            M = None  # the sensitivities' own information
        return cluster_covariance([p[0] for p in parts], [p[1] for p in parts], M, names=result.free_names)
    except (ValueError, IndexError, np.linalg.LinAlgError):
        return None  # a diagnostic: never the reason a fit fails
