"""Validation of identified models, on plain numpy/pandas arrays so that it applies to the
result of any method (OEM, FEM, EKF, UKF, equation error).

Modules: :mod:`.fit` (det R, Theil inequality coefficient and proportions, R^2, RMS),
:mod:`.residuals` (statistics, autocorrelation, whiteness test, PSD),
:mod:`estimators.covariance` (Cramér-Rao bounds, Morelli-Klein correction, correlation
flags; maneuver-to-maneuver scatter: the covariance with each maneuver a cluster; exported here),
:mod:`.modes` (named modes of a linearised model, numerical linearisation),
:mod:`.frequency` (model frequency response, spectral estimates with coherence, mismatch),
:mod:`.match` (proof of match against tolerance bands), :mod:`.prediction_band` (a
prediction's std from the parameters' covariance), :mod:`.prediction` (the
model driven by its measured air data: proof of match in turbulence, unstable aircraft),
:mod:`.plausibility` (estimates vs a-priori values, and between methods), :mod:`.inverse` (inverse simulation).
Needs numpy, scipy and pandas (and the package's EKF for :mod:`.prediction`). The names
below are imported from their submodules on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from estimators.defaults import CLUSTER_FLAG_RATIO as cluster_flag_ratio
from estimators.defaults import NOISE_ALPHA, PREDICTION_K

# imported now: these submodules share a name with a function of theirs, which must be
# bound here after the submodule (importing it later would bind the module instead)
from .modes import ModeAnalysis, linearize, mode_properties, modes
from .plausibility import SIGN_RULES, agreement, expected_signs, load_apriori, plausibility, sign_check

#: the other public names -> (submodule, name there), imported on first use (PEP 562), so
#: a module that needs one submodule (a result's summary needs :mod:`.cluster`) does not
#: load scipy.signal, scipy.stats and the Kalman filters with the others
_LAZY = {
    "ClusterResult": ("estimators.covariance.cluster", "ClusterResult"),
    "cluster_covariance": ("estimators.covariance.cluster", "cluster_covariance"),
    "maneuver_scatter": ("estimators.covariance.cluster", "maneuver_scatter"),
    "segment_parts": ("estimators.covariance.cluster", "segment_parts"),
    "TheilResult": ("fit", "TheilResult"),
    "det_r": ("fit", "det_r"),
    "fit_metrics": ("fit", "fit_metrics"),
    "r_squared": ("fit", "r_squared"),
    "residual_covariance": ("fit", "residual_covariance"),
    "rms": ("fit", "rms"),
    "theil": ("fit", "theil"),
    "MismatchResult": ("frequency", "MismatchResult"),
    "SpectralEstimate": ("frequency", "SpectralEstimate"),
    "bode": ("frequency", "bode"),
    "freq_response": ("frequency", "freq_response"),
    "mismatch": ("frequency", "mismatch"),
    "spectral_estimate": ("frequency", "spectral_estimate"),
    "InverseSimResult": ("inverse", "InverseSimResult"),
    "inverse_simulation": ("inverse", "inverse_simulation"),
    "DEFAULT_TOLERANCES": ("match", "DEFAULT_TOLERANCES"),
    "default_tolerances": ("match", "default_tolerances"),
    "noise_reach": ("match", "noise_reach"),
    "prediction_uncertainty": ("match", "prediction_uncertainty"),
    "proof_of_match": ("match", "proof_of_match"),
    "AIR_DATA": ("prediction", "AIR_DATA"),
    "DrivenPrediction": ("prediction", "DrivenPrediction"),
    "air_data_prediction": ("prediction", "air_data_prediction"),
    "driving_states": ("prediction", "driving_states"),
    "parameter_sensitivity": ("prediction_band", "parameter_sensitivity"),
    "prediction_std": ("prediction_band", "prediction_std"),
    "variance_shares": ("prediction_band", "variance_shares"),
    "WhitenessResult": ("residuals", "WhitenessResult"),
    "autocorrelation": ("residuals", "autocorrelation"),
    "autocovariance": ("residuals", "autocovariance"),
    "psd": ("residuals", "psd"),
    "residual_stats": ("residuals", "residual_stats"),
    "whiteness": ("residuals", "whiteness"),
    "UncertaintyResult": ("estimators.covariance.uncertainty", "UncertaintyResult"),
    "correlation": ("estimators.covariance.uncertainty", "correlation"),
    "correlation_flags": ("estimators.covariance.uncertainty", "correlation_flags"),
    "crb": ("estimators.covariance.uncertainty", "crb"),
    "morelli_klein": ("estimators.covariance.uncertainty", "morelli_klein"),
}

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs
    from estimators.covariance.cluster import ClusterResult, cluster_covariance, maneuver_scatter, segment_parts
    from estimators.covariance.uncertainty import UncertaintyResult, correlation, correlation_flags, crb, morelli_klein

    from .fit import TheilResult, det_r, fit_metrics, r_squared, residual_covariance, rms, theil
    from .frequency import MismatchResult, SpectralEstimate, bode, freq_response, mismatch, spectral_estimate
    from .inverse import InverseSimResult, inverse_simulation
    from .match import DEFAULT_TOLERANCES, default_tolerances, noise_reach, prediction_uncertainty, proof_of_match
    from .prediction import AIR_DATA, DrivenPrediction, air_data_prediction, driving_states
    from .prediction_band import parameter_sensitivity, prediction_std, variance_shares
    from .residuals import WhitenessResult, autocorrelation, autocovariance, psd, residual_stats, whiteness

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
    "SIGN_RULES",
    "expected_signs",
    "sign_check",
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


def __getattr__(name: str) -> Any:
    """A public name imported from its submodule on first use (then kept as an attribute);
    a submodule (``estimators.validation.match``) imported on first attribute access."""
    where = _LAZY.get(name)
    if where is not None:
        module = where[0] if "." in where[0] else f"{__name__}.{where[0]}"
        value = getattr(importlib.import_module(module), where[1])
        globals()[name] = value
        return value
    if not name.startswith("_"):
        try:
            return importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as e:
            if e.name != f"{__name__}.{name}":
                raise
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
