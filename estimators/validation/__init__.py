"""Validation of identified models, on plain numpy/pandas arrays so that it applies to the
result of any method (OEM, FEM, EKF, UKF, equation error).

Modules: :mod:`.fit` (det R, Theil inequality coefficient and proportions, R^2, RMS),
:mod:`.residuals` (statistics, autocorrelation, whiteness test, PSD),
:mod:`.uncertainty` (Cramér-Rao bounds, Morelli-Klein correction, correlation flags),
:mod:`.cluster` (maneuver-to-maneuver scatter: the covariance with each maneuver a cluster),
:mod:`.modes` (named modes of a linearised model, numerical linearisation),
:mod:`.frequency` (model frequency response, spectral estimates with coherence, mismatch),
:mod:`.match` (proof of match against tolerance bands), :mod:`.prediction_band` (a
prediction's std from the parameters' covariance), :mod:`.prediction` (the
model driven by its measured air data: proof of match in turbulence, unstable aircraft),
:mod:`.plausibility` (estimates vs a-priori values, and between methods), :mod:`.inverse` (inverse simulation).
Needs numpy, scipy and pandas (and the package's EKF for :mod:`.prediction`).
"""

from __future__ import annotations

from .cluster import FLAG_RATIO as cluster_flag_ratio
from .cluster import ClusterResult, cluster_covariance, maneuver_scatter, segment_parts
from .fit import TheilResult, det_r, fit_metrics, r_squared, residual_covariance, rms, theil
from .frequency import MismatchResult, SpectralEstimate, bode, freq_response, mismatch, spectral_estimate
from .inverse import InverseSimResult, inverse_simulation
from .match import (
    DEFAULT_TOLERANCES,
    NOISE_ALPHA,
    PREDICTION_K,
    default_tolerances,
    noise_reach,
    prediction_uncertainty,
    proof_of_match,
)
from .modes import ModeAnalysis, linearize, mode_properties, modes
from .plausibility import agreement, load_apriori, plausibility
from .prediction import AIR_DATA, DrivenPrediction, air_data_prediction, driving_states
from .prediction_band import parameter_sensitivity, prediction_std, variance_shares
from .residuals import WhitenessResult, autocorrelation, autocovariance, psd, residual_stats, whiteness
from .uncertainty import UncertaintyResult, correlation, correlation_flags, crb, morelli_klein

__all__ = [
    "TheilResult",
    "theil",
    "fit_metrics",
    "det_r",
    "r_squared",
    "rms",
    "residual_covariance",
    "residual_stats",
    "autocovariance",
    "autocorrelation",
    "WhitenessResult",
    "whiteness",
    "psd",
    "UncertaintyResult",
    "crb",
    "morelli_klein",
    "correlation",
    "correlation_flags",
    "ClusterResult",
    "cluster_covariance",
    "maneuver_scatter",
    "segment_parts",
    "cluster_flag_ratio",
    "ModeAnalysis",
    "modes",
    "mode_properties",
    "linearize",
    "freq_response",
    "bode",
    "SpectralEstimate",
    "spectral_estimate",
    "MismatchResult",
    "mismatch",
    "DEFAULT_TOLERANCES",
    "NOISE_ALPHA",
    "PREDICTION_K",
    "default_tolerances",
    "noise_reach",
    "prediction_uncertainty",
    "proof_of_match",
    "load_apriori",
    "plausibility",
    "agreement",
    "InverseSimResult",
    "inverse_simulation",
    "AIR_DATA",
    "DrivenPrediction",
    "air_data_prediction",
    "driving_states",
    "parameter_sensitivity",
    "prediction_std",
    "variance_shares",
]
