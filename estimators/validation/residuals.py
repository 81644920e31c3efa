"""Residual analysis: mean, std, autocorrelation, a whiteness test, power spectral density.

Residuals are arrays of shape (N, n_out) (or (N,)) of e = z - y in output units, sampled
uniformly; any method's residuals (output error, filter innovations) apply.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import fft as sfft
from scipy import signal, stats

from estimators.defaults import WHITENESS_ALPHA

from ._util import as_2d, output_names

__all__ = ["residual_stats", "autocovariance", "autocorrelation", "WhitenessResult", "whiteness", "psd"]


def residual_stats(residuals, names: Sequence[str] | None = None) -> pd.DataFrame:
    """Per output: ``mean``, ``std`` (population), ``rms`` (units of the residual),
    ``mean_over_std`` (a bias indicator, dimensionless) and ``N``. Index: output names."""
    e = as_2d(residuals, "residuals")
    names = output_names(names, e.shape[1], residuals)
    m, s = np.nanmean(e, axis=0), np.nanstd(e, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = m / s
    return pd.DataFrame(
        {
            "mean": m,
            "std": s,
            "rms": np.sqrt(np.nanmean(e * e, axis=0)),
            "mean_over_std": ratio,
            "N": np.isfinite(e).sum(axis=0),
        },
        index=pd.Index(names, name="output"),
    )


def autocovariance(x, max_lag: int | None = None, *, demean: bool = True) -> np.ndarray:
    """Biased autocovariance c(k) = (1/N) sum_{i=0}^{N-1-k} x_i x_{i+k} per column.

    x: (N, n) or (N,). Returns shape (max_lag + 1, n) for lags 0..max_lag (default N-1),
    in units of x squared. Computed by FFT (O(N log N)).
    """
    x = as_2d(x)
    n = x.shape[0]
    max_lag = n - 1 if max_lag is None else int(min(max_lag, n - 1))
    if demean:
        x = x - x.mean(axis=0)
    nfft = sfft.next_fast_len(2 * n - 1, real=True)
    X = sfft.rfft(x, nfft, axis=0)
    c = sfft.irfft(X * np.conj(X), nfft, axis=0)[: max_lag + 1]
    return c / n


def autocorrelation(x, max_lag: int | None = None) -> np.ndarray:
    """Normalised autocorrelation rho(k) = c(k) / c(0) of each column of x (N, n),
    shape (max_lag + 1, n), rho(0) = 1 (NaN for a constant column)."""
    c = autocovariance(x, max_lag)
    with np.errstate(invalid="ignore", divide="ignore"):
        return c / c[0]


@dataclass(frozen=True)
class WhitenessResult:
    """Ljung-Box portmanteau test per output (arrays of shape (n_out,) unless noted).

    ``statistic`` Q = N (N+2) sum_{k=1}^{m} rho_k^2 / (N-k); under whiteness Q ~ chi^2(m).
    ``threshold`` the chi^2(m) quantile at 1 - alpha; ``white`` = Q <= threshold;
    ``p_value``; ``acf`` (m + 1, n_out) the autocorrelation at lags 0..m; ``band`` the
    approximate 1 - alpha confidence half-width for rho_k of white noise, z / sqrt(N);
    ``frac_outside`` the fraction of lags 1..m with |rho_k| > band.
    """

    names: list[str]
    statistic: np.ndarray
    threshold: float
    p_value: np.ndarray
    white: np.ndarray
    max_lag: int
    alpha: float
    acf: np.ndarray
    band: float
    frac_outside: np.ndarray

    def to_frame(self) -> pd.DataFrame:
        """One row per output: Q, threshold, p_value, white, frac_outside."""
        return pd.DataFrame(
            {
                "Q": self.statistic,
                "threshold": self.threshold,
                "p_value": self.p_value,
                "white": self.white,
                "frac_outside": self.frac_outside,
            },
            index=pd.Index(self.names, name="output"),
        )


def whiteness(
    residuals, max_lag: int | None = None, alpha: float = WHITENESS_ALPHA, names: Sequence[str] | None = None
) -> WhitenessResult:
    """Whiteness test of residuals (N, n_out) by the Ljung-Box statistic over lags 1..max_lag.

    residuals may also be a list of (N_s, n_out) arrays, one per segment: each is demeaned
    on its own, lag products never cross segments, and N is the total sample count.
    max_lag defaults to min(20, N // 5). alpha is the significance level (probability of
    rejecting truly white residuals). Returns a :class:`WhitenessResult`.
    """
    segs = (
        [as_2d(r, "residuals") for r in residuals]
        if isinstance(residuals, (list, tuple))
        else [as_2d(residuals, "residuals")]
    )
    if any(np.isnan(s).any() for s in segs):
        # multi-rate data: each output is tested on its own samples (NaN = not measured),
        # lags counted in that output's sample intervals
        cols = [
            _column_whiteness([s[np.isfinite(s[:, j]), j] for s in segs], max_lag, alpha)
            for j in range(segs[0].shape[1])
        ]
        first = residuals[0] if isinstance(residuals, (list, tuple)) else residuals
        m = min(c[4] for c in cols)
        return WhitenessResult(
            names=output_names(names, segs[0].shape[1], first),
            statistic=np.array([c[0] for c in cols]),
            threshold=float(stats.chi2.ppf(1 - alpha, m)),
            p_value=np.array([c[1] for c in cols]),
            white=np.array([c[2] for c in cols]),
            max_lag=m,
            alpha=alpha,
            acf=np.column_stack([c[3][: m + 1] for c in cols]),
            band=float(max(c[5] for c in cols)),
            frac_outside=np.array([c[6] for c in cols]),
        )
    n = sum(s.shape[0] for s in segs)
    if n < 10:
        raise ValueError("whiteness test needs at least 10 samples")
    m = int(min(20, n // 5) if max_lag is None else max_lag)
    if not 1 <= m < min(s.shape[0] for s in segs):
        raise ValueError(f"max_lag must be in [1, shortest segment - 1], got {m}")
    c = sum(autocovariance(s, m) * s.shape[0] for s in segs)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = c / c[0]
    k = np.arange(1, m + 1)[:, None]
    q = n * (n + 2) * np.sum(rho[1:] ** 2 / (n - k), axis=0)
    thr = float(stats.chi2.ppf(1.0 - alpha, m))
    band = float(stats.norm.ppf(1.0 - alpha / 2) / np.sqrt(n))
    first = residuals[0] if isinstance(residuals, (list, tuple)) else residuals
    return WhitenessResult(
        names=output_names(names, segs[0].shape[1], first),
        statistic=q,
        threshold=thr,
        p_value=stats.chi2.sf(q, m),
        white=q <= thr,
        max_lag=m,
        alpha=alpha,
        acf=rho,
        band=band,
        frac_outside=np.mean(np.abs(rho[1:]) > band, axis=0),
    )


def _column_whiteness(segs: list[np.ndarray], max_lag: int | None, alpha: float):
    """Ljung-Box on one output given as per-segment 1-D arrays of its present samples:
    (Q, p, white, acf, max_lag, band, frac_outside)."""
    segs = [s for s in segs if s.size > 2]
    n = sum(s.size for s in segs)
    if n < 10:
        raise ValueError("whiteness test needs at least 10 samples per output")
    m = int(min(20, n // 5) if max_lag is None else max_lag)
    m = max(1, min(m, min(s.size for s in segs) - 1))
    c = sum(autocovariance(s, m)[:, 0] * s.size for s in segs)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = c / c[0]
    k = np.arange(1, m + 1)
    q = float(n * (n + 2) * np.sum(rho[1:] ** 2 / (n - k)))
    thr = float(stats.chi2.ppf(1.0 - alpha, m))
    band = float(stats.norm.ppf(1.0 - alpha / 2) / np.sqrt(n))
    return q, float(stats.chi2.sf(q, m)), q <= thr, rho, m, band, float(np.mean(np.abs(rho[1:]) > band))


def psd(x, fs: float, nperseg: int | None = None, *, method: str = "welch") -> tuple[np.ndarray, np.ndarray]:
    """One-sided power spectral density of each column of x (N, n) sampled at fs (Hz).

    method "welch" (Hann window, 50 % overlap, nperseg default min(N, 256)) or
    "periodogram" (Hann window over the whole record). Linear trends are not removed; the
    mean is. Returns f (n_f,) in Hz and Pxx (n_f, n) in units of x^2/Hz.
    """
    x = as_2d(x)
    if method == "welch":
        nper = min(x.shape[0], 256) if nperseg is None else int(nperseg)
        f, p = signal.welch(x, fs=fs, window="hann", nperseg=nper, detrend="constant", axis=0)
    elif method == "periodogram":
        f, p = signal.periodogram(x, fs=fs, window="hann", detrend="constant", axis=0)
    else:
        raise ValueError(f"method must be 'welch' or 'periodogram', got {method!r}")
    return f, p
