"""Proof of match: compare a held-fixed model's simulation with measured data of a
maneuver not used in the fit, against tolerance bands, pass/fail per channel.

Default bands (SI, canonical channel names of DESIGN.md section 3): 1.5 deg/s on body
rates (p, q, r), 0.1 g on specific forces (ax, ay, az), 1.5 deg on angles (phi, theta,
psi, alpha, beta). Other channels have no default and are reported but not judged unless
a tolerance is given.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from scipy.stats import norm

from estimators.defaults import NOISE_ALPHA, POM_ACCEL_G, POM_ANGLE_DEG, POM_RATE_DEG_S, PREDICTION_K

from ._util import as_2d, output_names

__all__ = ["G0", "DEFAULT_TOLERANCES", "prediction_uncertainty", "default_tolerances", "noise_reach", "proof_of_match"]

G0 = 9.80665  # m/s^2
_DEG = np.pi / 180.0
DEFAULT_TOLERANCES: Mapping[str, float] = {
    **{k: POM_RATE_DEG_S * _DEG for k in ("p", "q", "r")},  # rad/s
    **{k: POM_ACCEL_G * G0 for k in ("ax", "ay", "az")},  # m/s^2
    **{k: POM_ANGLE_DEG * _DEG for k in ("phi", "theta", "psi", "alpha", "beta")},  # rad
}


def prediction_uncertainty(
    excess: np.ndarray, prediction_std: np.ndarray, k: float = PREDICTION_K
) -> tuple[np.ndarray, np.ndarray]:
    """(std_max, beyond) per channel, (n_out,) each, over the judged samples (finite
    ``excess``): the prediction's largest std there, and how far the proof of match's
    misses reach beyond ``k`` of it, max(0, excess - k std) at worst (NaN for a channel
    with no judged sample). ``excess`` (N, n_out): each sample's error beyond its band
    (negative inside; ``proof_of_match``'s ``attrs["excess"]``); ``prediction_std`` (N,
    n_out), the same units. beyond 0: every miss is within the uncertainty the estimates'
    covariance gives the prediction (:mod:`estimators.validation.prediction_band`)."""
    excess = np.asarray(excess, dtype=float)
    ps = np.asarray(prediction_std, dtype=float)
    judged = np.isfinite(excess) & np.isfinite(ps)

    def worst(a: np.ndarray) -> np.ndarray:
        m = np.max(np.where(judged, a, -np.inf), axis=0)
        return np.where(np.isfinite(m), m, np.nan)

    return worst(ps), worst(np.clip(excess - k * ps, 0.0, None))


def noise_reach(n: int, alpha: float = NOISE_ALPHA) -> float:
    """z such that n independent N(0, 1) samples all lie within +-z with probability
    1 - alpha: z = -Phi^-1((1 - (1 - alpha)^(1/n)) / 2) (n = 1: 1.96; 1000: 4.05 for 5 %);
    0 for n < 1."""
    if n < 1:
        return 0.0
    return float(-norm.ppf(-np.expm1(np.log1p(-alpha) / n) / 2.0))


def default_tolerances(
    rate_deg_s: float = POM_RATE_DEG_S, accel_g: float = POM_ACCEL_G, angle_deg: float = POM_ANGLE_DEG
) -> dict[str, float]:
    """Tolerance per canonical channel in SI units (rad/s, m/s^2, rad) from the bands
    given in deg/s, g and deg."""
    return {
        **{k: rate_deg_s * _DEG for k in ("p", "q", "r")},
        **{k: accel_g * G0 for k in ("ax", "ay", "az")},
        **{k: angle_deg * _DEG for k in ("phi", "theta", "psi", "alpha", "beta")},
    }


def _errors(
    z: np.ndarray,
    y: np.ndarray,
    names: Sequence[str],
    allowed_bias: Mapping[str, float] | None,
    envelope: tuple[object, object] | None,
) -> tuple[np.ndarray, ...]:
    """(e, bias, nominal, width) for measured z and predicted y (N, n_out): the error judged
    (N, n_out) after removing the allowed bias (n_out,), as the distance from the
    envelope when one is given; the nominal error |z - bias - y| and the envelope's width
    (zeros without one)."""
    e = z - y
    bmax = np.array([(allowed_bias or {}).get(n, 0.0) for n in names], dtype=float)
    bias = np.clip(np.nanmean(e, axis=0), -bmax, bmax)
    e = e - bias
    nominal = np.abs(e)
    width = np.zeros_like(e)
    if envelope is not None:
        lo, hi = (as_2d(a, f"envelope {w}") for a, w in zip(envelope, ("lower", "upper")))
        if lo.shape != y.shape or hi.shape != y.shape:
            raise ValueError(f"envelope {lo.shape}, {hi.shape} must have the predicted shape {y.shape}")
        lo, hi = np.fmin(lo, y), np.fmax(hi, y)  # NaN bounds: the prediction alone
        zb = z - bias
        e = zb - np.clip(zb, lo, hi)
        width = hi - lo
    return e, bias, nominal, width


def _noise_allowance(
    present: np.ndarray, names: Sequence[str], noise_std: Mapping[str, float] | None, noise_alpha: float
) -> np.ndarray:
    """(n_out,) what the band widens by for white measurement noise: :func:`noise_reach`
    over each channel's measured samples (``present`` (N, n_out)) times its std; 0 for a
    channel without a positive std."""
    sd = np.array([(noise_std or {}).get(n, np.nan) for n in names], dtype=float)
    return np.where(
        np.isfinite(sd) & (sd > 0),
        [noise_reach(int(k), noise_alpha) for k in present.sum(axis=0)] * np.nan_to_num(sd),
        0.0,
    )


def proof_of_match(
    measured,
    predicted,
    names: Sequence[str] | None = None,
    tolerances: Mapping[str, float] | None = None,
    *,
    required_fraction: float = 1.0,
    allowed_bias: Mapping[str, float] | None = None,
    envelope: tuple[object, object] | None = None,
    noise_std: Mapping[str, float] | None = None,
    noise_alpha: float = NOISE_ALPHA,
    prediction_std: object | None = None,
    prediction_k: float = PREDICTION_K,
) -> pd.DataFrame:
    """Pass/fail per channel of predicted vs measured time histories.

    measured, predicted: (N, n_out) arrays or DataFrames (columns give the names), SI units.
    tolerances: band half-width per channel name (SI); merged over the defaults (see
    :func:`default_tolerances`); a channel with no tolerance is reported with pass = NA.
    required_fraction: share of samples that must lie inside the band (1.0: all of them).
    allowed_bias: per channel, the largest constant offset (SI) that may be removed first
    (the mean error, clipped to +/- this value), for "small allowed biases".
    envelope: (lower, upper), each shaped as ``predicted``: the range the prediction spans
        under an uncertainty of the inputs themselves (a control step's unknown time
        between two slow samples of the surface: the prediction with the step at either
        end of its interval). A sample is then judged by its distance from that range
        (0 inside it; the range always includes ``predicted``), and ``max_abs_error`` /
        ``rms_error`` are that distance; ``nominal_max_abs_error`` is the error of
        ``predicted`` itself and ``envelope_max_width`` the range's widest point. Without
        it the two columns are the error's and 0.
    noise_std: per channel, the white measurement-noise std (SI) of ``measured``: the band
        a sample is judged against is the tolerance plus the noise's reach over the
        channel's n measured samples, :func:`noise_reach` (n, ``noise_alpha``) x std, so
        that noise alone fails a channel in ``noise_alpha`` (5 %) of segments instead of
        almost surely over a long one. ``noise_allowance`` says how much was added.
    prediction_std: shaped as ``predicted``, the prediction's own std from the estimates'
        covariance (:func:`estimators.validation.prediction_band.prediction_std`). It does
        not change pass/fail; it says why a channel fails: ``prediction_std_max`` (its
        largest value) and ``beyond_prediction`` (:func:`prediction_uncertainty` with
        ``prediction_k``: 0 when every miss is within that many std, so the estimates'
        imprecision explains the failure; more: the model's form, its inputs, or estimates
        biased beyond their std). NaN without.
    Returns a DataFrame indexed by channel with ``tolerance``, ``bias_removed``,
    ``max_abs_error``, ``rms_error``, ``fraction_within``, ``pass``,
    ``nominal_max_abs_error``, ``envelope_max_width``, ``noise_allowance``,
    ``prediction_std_max``, ``beyond_prediction``; the attribute ``df.attrs["all_pass"]``
    is True when every judged channel passes, ``df.attrs["excess"]`` (N, n_out) is each
    sample's error beyond its band (negative inside; NaN unmeasured or not judged).
    """
    z, y = as_2d(measured, "measured"), as_2d(predicted, "predicted")
    if z.shape != y.shape:
        raise ValueError(f"measured {z.shape} and predicted {y.shape} must have the same shape")
    names = output_names(names, z.shape[1], measured, predicted)
    tol_map = {**DEFAULT_TOLERANCES, **(tolerances or {})}
    tol = np.array([tol_map.get(n, np.nan) for n in names], dtype=float)
    e, bias, nominal, width = _errors(z, y, names, allowed_bias, envelope)
    ae = np.abs(e)
    present = np.isfinite(e)  # NaN: no measurement at this sample
    allow = _noise_allowance(present, names, noise_std, noise_alpha)
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.sum((ae <= tol + allow) & present, axis=0) / present.sum(axis=0)
    judged = np.isfinite(tol)
    excess = np.where(present & judged, ae - (tol + allow), np.nan)
    pstd_max = beyond = np.full(len(names), np.nan)
    if prediction_std is not None:
        ps = as_2d(prediction_std, "prediction_std")
        if ps.shape != y.shape:
            raise ValueError(f"prediction_std {ps.shape} must have the predicted shape {y.shape}")
        pstd_max, beyond = prediction_uncertainty(excess, ps, prediction_k)
    passed = pd.array(np.where(judged, frac >= required_fraction, False), dtype="boolean")
    passed[~judged] = pd.NA
    df = pd.DataFrame(
        {
            "tolerance": tol,
            "bias_removed": bias,
            "max_abs_error": np.nanmax(ae, axis=0),
            "rms_error": np.sqrt(np.nanmean(e * e, axis=0)),
            "fraction_within": np.where(judged, frac, np.nan),
            "pass": passed,
            "nominal_max_abs_error": np.nanmax(nominal, axis=0),
            "envelope_max_width": np.max(np.where(present, width, 0.0), axis=0),
            "noise_allowance": allow,
            "prediction_std_max": pstd_max,
            "beyond_prediction": beyond,
        },
        index=pd.Index(names, name="channel"),
    )
    df.attrs["all_pass"] = bool(judged.any() and df["pass"][judged].all())
    df.attrs["excess"] = excess
    return df
