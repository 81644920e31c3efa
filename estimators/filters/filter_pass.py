"""One filter pass of the parameter-estimating filters, piece by piece: what a segment's
run starts from and returns (its compiled run in the model's filter kernel module), what
the pass collects over its segments, and the maneuvers' scatter from each segment's part of
the parameters' information.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from estimators.covariance.cluster import cluster_covariance
from estimators.filters.augmented import AugmentedModel
from estimators.filters.kernels import output_kernel
from estimators.filters.noise import NoiseMatch
from estimators.integrators import INPUT_MODES
from estimators.layout import Layout
from estimators.model import Model, Segment


def information_form(P: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P^-1, P^-1 theta) of a parameter estimate theta (m,) with covariance P (m, m): the
    information form, in which a segment's contribution to a filter pass adds up."""
    Pinv = np.linalg.pinv(0.5 * (P + P.T))
    return Pinv, Pinv @ theta


def segment_scatter(info: list[tuple[np.ndarray, np.ndarray]], P: np.ndarray, theta: np.ndarray, names: Sequence[str]):
    """The maneuvers' scatter of one filter pass (:mod:`estimators.covariance.cluster`,
    each segment a cluster), or None with fewer than 2 segments or a failed inversion.

    A segment j adds A_j = P_after^-1 - P_before^-1 to the parameters' information and
    b_j = P_after^-1 theta_after - P_before^-1 theta_before = A_j theta_j to its weighted
    estimate (exact for a linear model with Gaussian noise, each segment's states started
    anew: theta_j is what the segment alone says); its part of the gradient at the pass's
    estimate theta is s_j = b_j - A_j theta, and M = P^-1 (the initial covariance's prior
    included). When the segments disagree more than their information allows, the
    cluster covariance grows beyond P, as filter error's does."""
    if len(info) < 2:
        return None
    try:
        M = np.linalg.pinv(0.5 * (P + P.T))
        return cluster_covariance(
            [0.5 * (A + A.T) for A, _ in info], [b - A @ theta for A, b in info], 0.5 * (M + M.T), names=list(names)
        )
    except (ValueError, np.linalg.LinAlgError):
        return None


@dataclass
class SegmentStart:
    """What one segment's filter run starts from: the augmented model ``aug``, s (L,) =
    [x0; theta], its covariance P (L, L), the process noise F (n, n), the measurement-noise
    covariance R (n_out, n_out), the parameters' random-walk variance per second qth (m,)
    and the pass's covariance-matching sums ``match`` (None: not summed)."""

    aug: AugmentedModel
    s: np.ndarray
    P: np.ndarray
    F: np.ndarray
    R: np.ndarray
    qth: np.ndarray
    match: NoiseMatch | None


@dataclass
class SegmentRun:
    """One segment's filter run: the final s (L,) and P (L, L), the a-priori outputs Ypred
    (N, n_out), the a-posteriori states Spost (N, L) and diag(P) Pdiag (N, L), the last
    gain K (L, n_ok) or None, the innovations' negative log-likelihood ``nll`` and count
    ``n_obs``, the bound projections per parameter ``hits`` (m,) and ``fail``, the sample
    where the prediction became non-finite (-1: none)."""

    s: np.ndarray
    P: np.ndarray
    Ypred: np.ndarray
    Spost: np.ndarray
    Pdiag: np.ndarray
    K: np.ndarray | None
    nll: float
    n_obs: int
    hits: np.ndarray
    fail: int


@dataclass
class PassRecord:
    """What one filter pass collects over its segments: per segment the a-priori outputs,
    innovations, parameter trajectories and their std, states and a-posteriori outputs;
    the last gain, the innovations' likelihood and count, bound projections and each
    segment's information (:func:`information_form`) differences."""

    pred: list = field(default_factory=list)
    innov: list = field(default_factory=list)
    traj: list = field(default_factory=list)
    traj_std: list = field(default_factory=list)
    states: list = field(default_factory=list)
    post: list = field(default_factory=list)
    history: list = field(default_factory=list)
    info: list = field(default_factory=list)
    K: np.ndarray | None = None
    nll: float = 0.0
    n_obs: int = 0
    hits: np.ndarray | None = None

    def add(self, seg: Segment, run: SegmentRun, aug: AugmentedModel, lay: Layout, model: Model) -> None:
        """A segment's run's time histories, as DataFrames on t."""
        n = aug.n
        idx = pd.Index(seg.t, name="t")
        self.pred.append(run.Ypred)
        self.innov.append(seg.z - run.Ypred)
        self.traj.append(pd.DataFrame(run.Spost[:, n:], index=idx, columns=lay.free_names))
        self.traj_std.append(pd.DataFrame(np.sqrt(np.maximum(run.Pdiag[:, n:], 0)), index=idx, columns=lay.free_names))
        self.states.append(pd.DataFrame(run.Spost[:, :n], index=idx, columns=model.states))
        self.post.append(pd.DataFrame(aug.outputs_along(run.Spost), index=idx, columns=model.outputs))


@dataclass
class Passes:
    """The passes of a fit so far: the largest parameter move per pass (std), the history
    rows, the noise adaptation's moves, and why the passes ended unsettled ("" if not)."""

    moves: list = field(default_factory=list)
    history: list = field(default_factory=list)
    noise_moves: list = field(default_factory=list)
    left: str = ""


def run_compiled(which: str, start: SegmentStart, *extra) -> SegmentRun | None:
    """One segment's run in ``<which>_segment_<integrator>`` of the model's filter kernel
    module (:func:`estimators.filters.loops.ekf_segment`,
    :func:`~estimators.filters.loops.ukf_segment`), with the filter's own arguments
    ``extra`` before rtol; None when g or f did not compile. The covariance-matching sums
    go into ``start.match``."""
    aug = start.aug
    if aug.gout is None:  # g (or f) did not compile
        return None
    fn = getattr(output_kernel(aug.model), f"{which}_segment_{aug.integrator}", None)
    if fn is None:
        return None
    seg, lay, k = aug.seg, aug.lay, aug.k
    f64 = lambda a: np.ascontiguousarray(a, dtype=float)  # noqa: E731
    i64 = lambda a: np.ascontiguousarray(a, dtype=np.int64)  # noqa: E731
    s, P, Ypred, Spost, Pdiag, gain, last_ok, hits, acc, fail = fn(
        f64(start.s).copy(),
        f64(start.P).copy(),
        f64(seg.t),
        aug.u,
        f64(seg.z),
        f64(start.R),
        f64(start.F @ start.F.T),
        f64(start.qth),
        f64(lay.values),
        i64(lay.free_idx),
        i64(lay.pidx[k]),
        f64(aug.lo[:, 0]),
        f64(aug.hi[:, 0]),
        aug.c_compiled,
        *extra,
        float(aug.rtol),
        float(aug.atol),
        INPUT_MODES[aug.inputs],
        aug.n,
    )
    if start.match is not None:
        start.match.add_sums(acc[2:], len(aug.model.outputs))
    K = gain[:, last_ok] if np.any(last_ok) else None
    return SegmentRun(s, P, Ypred, Spost, Pdiag, K, float(acc[0]), int(acc[1]), hits, int(fail))
