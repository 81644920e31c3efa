"""Parameter uncertainty: Cramér-Rao bounds, the Morelli-Klein correction for coloured
residuals, and correlation flags.

Morelli & Klein (J. Guidance, Control and Dynamics 20(1), 1997): when the residuals are
not white, the output-error covariance M^-1 is optimistic. With W_i = R^-1 S_i and the
residual autocorrelation matrices r(k) = E[v_i v_{i+k}^T] (r(-k) = r(k)^T),

    Cov = M^-1 [ sum_i sum_j W_i^T r(j - i) W_j ] M^-1,    M = sum_i S_i^T R^-1 S_i.

For white residuals r(k) = R delta_k and Cov = M^-1. The double sum is evaluated exactly
for the chosen lag window by FFT convolution (O(N log N), not O(N^2)).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import fft as sfft
from scipy import stats

from estimators.sensitivity import Sensitivity, add_block, as_sensitivity
from estimators.statistics import residual_covariance as _residual_covariance

__all__ = ["UncertaintyResult", "crb", "morelli_klein", "correlation", "correlation_flags"]


@dataclass(frozen=True)
class UncertaintyResult:
    """Corrected and conventional parameter covariances, shape (n_p, n_p), std (n_p,).

    ``cov``/``std`` Morelli-Klein corrected; ``crb_cov``/``crb_std`` conventional
    Cramér-Rao (M^-1); ``ratio`` = std / crb_std; ``max_lag`` the lag used per segment.
    """

    names: list[str]
    cov: np.ndarray
    std: np.ndarray
    crb_cov: np.ndarray
    crb_std: np.ndarray
    ratio: np.ndarray
    max_lag: list[int] = field(default_factory=list)

    def to_frame(self) -> pd.DataFrame:
        """Rows per parameter: ``crb_std``, ``std`` (corrected), ``ratio``."""
        return pd.DataFrame(
            {"crb_std": self.crb_std, "std": self.std, "ratio": self.ratio},
            index=pd.Index(self.names, name="parameter"),
        )


def _segments(S, residuals) -> tuple[list[Sensitivity], list[np.ndarray]]:
    """Per segment the sensitivities (:class:`Sensitivity`) and residuals (N, n_out) of one
    array, a :class:`Sensitivity` or a list of them (one per segment)."""
    if isinstance(S, (np.ndarray, Sensitivity)) or not isinstance(S, Sequence):
        S, residuals = [S], [residuals]
    if len(S) != len(residuals):
        raise ValueError("S and residuals must have the same number of segments")
    Ss, vs = [], []
    for s, v in zip(S, residuals):
        s = as_sensitivity(s)
        v = np.asarray(v.to_numpy() if isinstance(v, pd.DataFrame) else v, dtype=float)
        if v.ndim == 1:
            v = v[:, None]
        if s.values.shape[:2] != v.shape:
            raise ValueError(
                f"S must be (N, n_out, n_p) matching residuals (N, n_out); got S {s.shape}, residuals {v.shape}"
            )
        Ss.append(s)
        vs.append(v)
    return Ss, vs


def coloured_information(
    S: Sequence[np.ndarray],
    v: Sequence[np.ndarray],
    Rinv: Sequence[np.ndarray],
    present: Sequence[np.ndarray] | None = None,
    *,
    max_lag: int | str | None = "auto",
    window: str = "bartlett",
    unbiased: bool = False,
) -> tuple[np.ndarray, list[int]]:
    """The middle term of the Morelli-Klein sandwich, sum over segments of
    sum_i sum_j S_i^T R^-1 r(j-i) R^-1 S_j with r the residual autocorrelation (windowed,
    truncated at max_lag): the covariance of the score when the residuals are coloured.
    It equals sum_i S_i^T R^-1 S_i (the information) for white residuals of covariance R.

    S: per segment (N, n_out, n_p) sensitivities or a :class:`Sensitivity` (zero where a
    measurement is missing); v: per segment (N, n_out) residuals (zero where missing);
    Rinv: per segment (n_out, n_out) inverse residual covariance the fit weighted with;
    present: per segment (N, n_out) bool of the measured samples (default all). max_lag,
    window, unbiased: as in :func:`morelli_klein`. Returns ((n_p, n_p), the lag used per
    segment)."""
    blocks = [as_sensitivity(s) for s in S]
    n_p = blocks[0].n_free
    mid = np.zeros((n_p, n_p))
    lags = []
    for k, (b, r) in enumerate(zip(blocks, v)):
        n = r.shape[0]
        if max_lag is None:
            L = n - 1
        elif isinstance(max_lag, str):
            if max_lag != "auto":
                raise ValueError(f"max_lag must be an int, 'auto' or None, got {max_lag!r}")
            L = _auto_lag(r)
        else:
            L = int(min(max(int(max_lag), 0), n - 1))
        lags.append(L)
        add_block(
            mid, b.cols, _middle(b.values, r, Rinv[k], L, window, unbiased, None if present is None else present[k])
        )
    return mid, lags


def crb(S, R) -> np.ndarray:
    """Conventional Cramér-Rao covariance M^-1, M = sum_i S_i^T R^-1 S_i.

    S: sensitivities dy/dtheta, (N, n_out, n_p) or a list of them (segments);
    R: residual covariance (n_out, n_out). Returns (n_p, n_p) (pseudo-inverse if singular).
    """
    Ss = [as_sensitivity(s) for s in (S if isinstance(S, (list, tuple)) else [S])]
    Rinv = np.linalg.inv(np.atleast_2d(R))
    return np.linalg.pinv(_information(Ss, Rinv), hermitian=True)


def _information(Ss: Sequence[Sensitivity], Rinv: np.ndarray) -> np.ndarray:
    """M = sum_i S_i^T R^-1 S_i over the segments' sensitivities, (n_p, n_p)."""
    M = np.zeros((Ss[0].n_free,) * 2)
    for s in Ss:
        add_block(M, s.cols, np.einsum("nap,ab,nbq->pq", s.values, Rinv, s.values, optimize=True))
    return M


def _auto_lag(v: np.ndarray) -> int:
    """3 x the first lag at which every output's autocorrelation lies inside the 95 %
    white-noise band 1.96/sqrt(N) (at least 1, at most N-1)."""
    n = v.shape[0]
    x = v - v.mean(axis=0)
    nfft = sfft.next_fast_len(2 * n - 1, real=True)
    X = sfft.rfft(x, nfft, axis=0)
    c = sfft.irfft(np.abs(X) ** 2, nfft, axis=0)[:n]
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.abs(c / c[0])
    band = stats.norm.ppf(0.975) / np.sqrt(n)
    inside = np.all(~(rho > band), axis=1)  # NaN (constant output) counts as inside
    inside[0] = False
    first = int(np.argmax(inside)) if inside.any() else n - 1
    return int(min(n - 1, max(1, 3 * first)))


def _middle(
    S: np.ndarray,
    v: np.ndarray,
    Rinv: np.ndarray,
    max_lag: int,
    window: str,
    unbiased: bool,
    present: np.ndarray | None = None,
) -> np.ndarray:
    """sum_i sum_j W_i^T r(j-i) W_j for one segment, r windowed and truncated at max_lag.
    ``present`` (N, n_out) marks measured samples (v and S are zero elsewhere); each r(k)
    is then averaged over the pairs actually measured."""
    n, n_out, _ = S.shape
    L = int(max_lag)
    W = np.einsum("ab,nbp->nap", Rinv, S)  # (N, n_out, n_p)
    # residual cross-correlations r_ab(k) = sum_i v_i[a] v_{i+k}[b] / (N or N-k), k = 0..L
    nfft = sfft.next_fast_len(2 * n - 1, real=True)
    V = sfft.rfft(v, nfft, axis=0)
    r = sfft.irfft(np.conj(V)[:, :, None] * V[:, None, :], nfft, axis=0)[: L + 1]
    k = np.arange(L + 1)
    if present is not None and not present.all():
        Mk = sfft.rfft(present.astype(float), nfft, axis=0)
        cnt = np.rint(sfft.irfft(np.conj(Mk)[:, :, None] * Mk[:, None, :], nfft, axis=0)[: L + 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.where(cnt > 0, r / np.maximum(cnt, 1.0), 0.0)
        if not unbiased:
            r *= ((n - k) / n)[:, None, None]
    else:
        r /= (n - k)[:, None, None] if unbiased else n
    if window == "bartlett":
        r *= (1.0 - k / (L + 1.0))[:, None, None]
    elif window != "none":
        raise ValueError(f"window must be 'bartlett' or 'none', got {window!r}")
    # Y_i = sum_k r(k) W_{i+k} = sum_j h(i-j) W_j with h(m) = r(-m) = r(m)^T (circular, no wrap)
    m = sfft.next_fast_len(n + L, real=True)
    h = np.zeros((m, n_out, n_out))
    h[: L + 1] = np.swapaxes(r, 1, 2)
    if L:
        h[m - L :] = r[1:][::-1]
    Y = sfft.irfft(np.einsum("fab,fbp->fap", sfft.rfft(h, m, axis=0), sfft.rfft(W, m, axis=0)), m, axis=0)[:n]
    mid = np.einsum("nap,naq->pq", W, Y)
    return 0.5 * (mid + mid.T)


def morelli_klein(
    S,
    residuals,
    R=None,
    info=None,
    *,
    names: Sequence[str] | None = None,
    max_lag: int | str | None = "auto",
    window: str = "bartlett",
    unbiased: bool = False,
    prior_info=None,
) -> UncertaintyResult:
    """Cramér-Rao bounds corrected for coloured residuals (Morelli-Klein).

    S: output sensitivities dy/dtheta at the estimate, (N, n_out, n_p) (units of output per
       unit of parameter), or a list of such arrays or :class:`Sensitivity` blocks, one per
       segment (lags never cross segments).
    residuals: z - y, (N, n_out) or a matching list.
    R: residual covariance (n_out, n_out) used in the fit; default (1/N) sum v v^T over all
       segments.
    info: information matrix M (n_p, n_p) used for the conventional bounds; default
       sum S^T R^-1 S (plus ``prior_info``).
    prior_info: (n_p, n_p) information the fit took from a-priori values (output error's
       ``priors``: ``result.extra["prior_information"]``), part of ``info``. It enters
       the middle term as it is: the a-priori values' errors are independent of the
       residuals. Without it the sandwich of a penalised fit, M^-1 (data part) M^-1, falls
       below the Cramér-Rao bound even for white residuals (lateral OEM with its a-priori
       airspeed corrections: 0.55 x on Cnbeta).
    max_lag: lags of r(k) kept: an int; "auto" (3 x the lag where every residual
       autocorrelation first falls inside the 95 % white band); None = all N-1 lags.
    window: "bartlett" (triangular taper, keeps the covariance positive semi-definite with
       the biased estimate) or "none". unbiased: divide r(k) by N-k instead of N (the
       published form is max_lag=None, window="none", unbiased=True).
    Returns an :class:`UncertaintyResult`.
    """
    Ss, vs = _segments(S, residuals)
    n_p = Ss[0].n_free
    if R is None:
        R = _residual_covariance(vs, full=True)
    # missing measurements (NaN): no residual and no sensitivity there
    present = [np.isfinite(v) for v in vs]
    Ss = [Sensitivity(np.where(ok[:, :, None], s.values, 0.0), s.cols, s.n_free) for s, ok in zip(Ss, present)]
    vs = [np.where(ok, v, 0.0) for v, ok in zip(vs, present)]
    Rinv = np.linalg.inv(np.atleast_2d(np.asarray(R, dtype=float)))
    W = np.zeros((n_p, n_p)) if prior_info is None else np.asarray(prior_info, dtype=float)
    if info is None:
        info = _information(Ss, Rinv) + W
    Minv = np.linalg.pinv(np.asarray(info, dtype=float), hermitian=True)
    mid, lags = coloured_information(
        Ss, vs, [Rinv] * len(Ss), present, max_lag=max_lag, window=window, unbiased=unbiased
    )
    mid = mid + W
    cov = Minv @ mid @ Minv
    cov = 0.5 * (cov + cov.T)
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    crb_std = np.sqrt(np.clip(np.diag(Minv), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = std / crb_std
    names = list(names) if names is not None else [f"p{i}" for i in range(n_p)]
    return UncertaintyResult(names=names, cov=cov, std=std, crb_cov=Minv, crb_std=crb_std, ratio=ratio, max_lag=lags)


def correlation(cov, names: Sequence[str] | None = None) -> pd.DataFrame:
    """Correlation matrix rho_ij = P_ij / sqrt(P_ii P_jj) of a covariance (n_p, n_p)."""
    P = np.asarray(cov.to_numpy() if isinstance(cov, pd.DataFrame) else cov, dtype=float)
    if names is None:
        names = list(cov.index) if isinstance(cov, pd.DataFrame) else [f"p{i}" for i in range(len(P))]
    d = np.sqrt(np.diag(P))
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = P / np.outer(d, d)
    return pd.DataFrame(rho, index=list(names), columns=list(names))


def correlation_flags(
    cov_or_corr, names: Sequence[str] | None = None, threshold: float = 0.9, *, is_corr: bool = False
) -> pd.DataFrame:
    """Parameter pairs with |rho| > threshold (default 0.9: near-linear dependence).

    Input: a covariance (or, with is_corr=True, a correlation) matrix, array or DataFrame.
    Returns a DataFrame with columns ``a``, ``b``, ``rho``, sorted by |rho| descending.
    """
    if names is None and not isinstance(cov_or_corr, pd.DataFrame):
        names = [f"p{i}" for i in range(np.shape(cov_or_corr)[0])]
    if is_corr:
        rho = (
            cov_or_corr
            if isinstance(cov_or_corr, pd.DataFrame)
            else pd.DataFrame(np.asarray(cov_or_corr, dtype=float), index=names, columns=names)
        )
    else:
        rho = correlation(cov_or_corr, names)
    R = rho.to_numpy()
    i, j = np.triu_indices(len(R), k=1)
    keep = np.abs(R[i, j]) > threshold
    out = pd.DataFrame(
        {"a": np.asarray(rho.index)[i[keep]], "b": np.asarray(rho.columns)[j[keep]], "rho": R[i, j][keep]}
    )
    return out.iloc[np.argsort(-np.abs(out["rho"].to_numpy()), kind="stable")].reset_index(drop=True)
