"""Goodness of fit: det(R), Theil inequality coefficient (TIC) with its bias, variance and
covariance proportions, R^2 and RMS per output.

All functions take the measured outputs ``z`` and the model outputs ``y`` as arrays of
shape (N, n_out) (or (N,) for one output, or lists of per-segment arrays/DataFrames,
concatenated), in any consistent units; they apply to the
result of any method (OEM, FEM, EKF, UKF, equation error).

Definitions (per output, e = z - y, bars are means over the N samples, s are the
population standard deviations (1/N), rho the correlation coefficient of z and y):

    TIC = sqrt(mean(e^2)) / (sqrt(mean(z^2)) + sqrt(mean(y^2)))     in [0, 1]
    UM  = (zbar - ybar)^2          / mean(e^2)   bias proportion
    US  = (s_z - s_y)^2            / mean(e^2)   variance proportion
    UC  = 2 (1 - rho) s_z s_y      / mean(e^2)   covariance proportion
    UM + US + UC = 1 exactly (mean(e^2) = (zbar-ybar)^2 + s_z^2 + s_y^2 - 2 rho s_z s_y).

A good model has TIC small (< 0.1 to 0.3), UM and US < 0.1 and UC near 1.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from estimators.statistics import residual_covariance as _residual_covariance

from ._util import as_2d, output_names

__all__ = ["TheilResult", "theil", "residual_covariance", "det_r", "r_squared", "rms", "fit_metrics"]


@dataclass(frozen=True)
class TheilResult:
    """Theil inequality coefficient per output, each an array of shape (n_out,).

    ``U`` the coefficient (0 perfect fit, 1 worst), ``UM`` bias, ``US`` variance and
    ``UC`` covariance proportions (UM + US + UC = 1; NaN where z == y exactly).
    """

    U: np.ndarray
    UM: np.ndarray
    US: np.ndarray
    UC: np.ndarray


def _pair(z, y) -> tuple[np.ndarray, np.ndarray]:
    z2, y2 = as_2d(z, "z"), as_2d(y, "y")
    if z2.shape != y2.shape:
        raise ValueError(f"z {z2.shape} and y {y2.shape} must have the same shape")
    if z2.shape[0] < 2:
        raise ValueError("need at least 2 samples")
    # a missing measurement (NaN, e.g. a slower channel on a common grid) drops the pair
    return z2, np.where(np.isnan(z2), np.nan, y2)


def theil(z, y) -> TheilResult:
    """Theil inequality coefficient and its proportions per output.

    z, y: measured and model outputs, shape (N, n_out) or (N,), same units per column.
    Returns a :class:`TheilResult` of arrays of shape (n_out,).
    """
    z, y = _pair(z, y)
    e = z - y
    mse = np.nanmean(e * e, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        U = np.sqrt(mse) / (np.sqrt(np.nanmean(z * z, axis=0)) + np.sqrt(np.nanmean(y * y, axis=0)))
        zm, ym = np.nanmean(z, axis=0), np.nanmean(y, axis=0)
        sz, sy = np.nanstd(z, axis=0), np.nanstd(y, axis=0)
        cov = np.nanmean((z - zm) * (y - ym), axis=0)  # = rho s_z s_y
        UM = (zm - ym) ** 2 / mse
        US = (sz - sy) ** 2 / mse
        UC = 2.0 * (sz * sy - cov) / mse
    return TheilResult(U=U, UM=UM, US=US, UC=UC)


def residual_covariance(residuals) -> np.ndarray:
    """R = (1/N) sum_k e_k e_k^T, shape (n_out, n_out), of residuals (N, n_out)
    (the output-error estimate; not mean-removed; NaN samples left out pairwise)."""
    return _residual_covariance([as_2d(residuals, "residuals")], full=True)


def det_r(residuals) -> float:
    """det(R) of residuals (N, n_out): the maximum-likelihood cost at the optimum."""
    return float(np.linalg.det(residual_covariance(residuals)))


def r_squared(z, y) -> np.ndarray:
    """Coefficient of determination per output, 1 - sum(e^2) / sum((z - zbar)^2),
    shape (n_out,) (NaN for a constant measured output)."""
    z, y = _pair(z, y)
    with np.errstate(invalid="ignore", divide="ignore"):
        return 1.0 - np.nansum((z - y) ** 2, axis=0) / np.nansum((z - np.nanmean(z, axis=0)) ** 2, axis=0)


def rms(x) -> np.ndarray:
    """Root mean square per column of x (N, n_out), shape (n_out,), units of x."""
    x = as_2d(x)
    return np.sqrt(np.nanmean(x * x, axis=0))


def fit_metrics(z, y, names: Sequence[str] | None = None) -> pd.DataFrame:
    """Table of fit metrics, one row per output (index: output names).

    z, y: measured and model outputs (N, n_out) (DataFrames give the names).
    Columns: ``TIC``, ``UM``, ``US``, ``UC`` (see module doc), ``R2``, ``RMS`` (of the
    residual z - y, output units), ``NRMS`` (RMS / (max z - min z), dimensionless),
    ``mean`` and ``std`` of the residual (output units). ``df.attrs["det_R"]`` holds det(R).
    """
    z2, y2 = _pair(z, y)
    names = output_names(names, z2.shape[1], z, y)
    t = theil(z2, y2)
    e = z2 - y2
    r = rms(e)
    with np.errstate(invalid="ignore", divide="ignore"):
        nrms = r / (np.nanmax(z2, axis=0) - np.nanmin(z2, axis=0))
    df = pd.DataFrame(
        {
            "TIC": t.U,
            "UM": t.UM,
            "US": t.US,
            "UC": t.UC,
            "R2": r_squared(z2, y2),
            "RMS": r,
            "NRMS": nrms,
            "mean": np.nanmean(e, axis=0),
            "std": np.nanstd(e, axis=0),
        },
        index=pd.Index(names, name="output"),
    )
    df.attrs["det_R"] = det_r(e)
    return df
