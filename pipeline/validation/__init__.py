"""pipeline.validation: one estimation result judged - fit, residuals, uncertainty, the
linearised model's checks, the proof of match on held-out maneuvers, the truth, the
methods' cross-check, and the verdict (:func:`validate`, module doc of
:mod:`pipeline.validation.validate` for the keys of its dict)."""

from pipeline.validation.agreement import cross_check_methods
from pipeline.validation.fit import NOISE_FLOOR_RATIO, TIC_LIMIT
from pipeline.validation.json_values import json_ready, num
from pipeline.validation.names import is_segment_parameter
from pipeline.validation.plausibility import refresh_plausibility
from pipeline.validation.proof_of_match import POM_MODES, pom_mode, refresh_prediction_uncertainty
from pipeline.validation.settings import ValidationSettings
from pipeline.validation.truth import TRUTH_K, refresh_truth_check
from pipeline.validation.uncertainty import widen_by_scatter, widened
from pipeline.validation.units import display_unit
from pipeline.validation.validate import validate
from pipeline.validation.verdict import FILTER_ERROR_TRUST, LEVELS, REASON_LEVELS, verdict

__all__ = [
    "FILTER_ERROR_TRUST",
    "LEVELS",
    "NOISE_FLOOR_RATIO",
    "POM_MODES",
    "REASON_LEVELS",
    "TIC_LIMIT",
    "TRUTH_K",
    "ValidationSettings",
    "cross_check_methods",
    "display_unit",
    "is_segment_parameter",
    "json_ready",
    "num",
    "pom_mode",
    "refresh_plausibility",
    "refresh_prediction_uncertainty",
    "refresh_truth_check",
    "validate",
    "verdict",
    "widen_by_scatter",
    "widened",
]
