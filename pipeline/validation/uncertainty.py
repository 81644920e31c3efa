"""How far the estimates' std can be trusted: Cramér-Rao bounds against the Morelli-Klein
correction for coloured residuals and the maneuver-to-maneuver scatter, and the scatter
made the reported std where it significantly exceeds the bound."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd
from scipy.stats import chi2

from estimators import EstimationResult
from estimators import validation as V
from pipeline.validation.json_values import frame_dict, num

#: confidence of the test that a parameter's maneuver scatter exceeds its Cramér-Rao bound
SCATTER_CONFIDENCE = 0.95
#: fewest maneuvers whose scatter may widen a bound (two degrees of freedom)
SCATTER_MIN_SEGMENTS = 3
#: ``std_method`` of a result whose bounds the maneuver scatter widened, by the method of
#: the bounds it widened (the Cramér-Rao bound; a Kalman filter's parameter covariance)
SCATTER_STD_METHOD = {
    "crb": "crb|scatter",
    "filter-covariance": "filter-covariance|scatter",
    "crb|sandwich": "crb|sandwich|scatter",
}


def parameter_uncertainty(result: EstimationResult) -> dict[str, Any] | None:
    """The ``uncertainty`` section: per free parameter ``crb_std``, ``mk_std`` (Morelli-Klein
    corrected) and their ``ratio``, plus the maneuver scatter (``cluster_std``,
    ``cluster_ratio``, ``max_share``, and ``cluster``) with 2 or more maneuvers; None when
    the result kept neither sensitivities, filter-error innovations nor a regression's
    window scatter; ``{"error": ...}`` when the correction cannot be computed."""
    extra: dict[str, Any] = {}
    if result.sensitivities:
        names = result.free_names
        try:
            u = V.morelli_klein(
                result.sensitivities,
                [r.to_numpy() for r in result.residuals],
                R=result.R,
                info=result.information,
                names=names,
                prior_info=(result.extra or {}).get("prior_information"),
            )
        except (ValueError, np.linalg.LinAlgError) as exc:
            return {"error": str(exc)}
        mk, max_lag = u.std, u.max_lag
    elif "mk_cov" in result.extra:
        # filter error: Morelli-Klein on the innovations, computed by the fit (estimators.filters.filter_error)
        names = list(result.extra["mk_names"])
        mk = np.sqrt(np.clip(np.diag(result.extra["mk_cov"]), 0.0, None))
        max_lag, extra = result.extra.get("mk_max_lag"), {"residuals": "innovations"}
    elif result.extra.get("cluster") is not None:
        # equation error: its regressions' window scatter, no Morelli-Klein
        names = list(result.extra["cluster"].names)
        mk, max_lag = np.full(len(names), np.nan), None
    else:
        return None
    crb = result.std[names].to_numpy()
    if result.cov_type != result.fit_cov_type:  # std is not the bound (stabilised output error, widened)
        crb = result.std_of(result.fit_cov_type)[names].to_numpy()
    df = pd.DataFrame({"crb_std": crb, "mk_std": mk, "ratio": mk / crb}, index=pd.Index(names, name="parameter"))
    cl = V.maneuver_scatter(result)
    if cl is not None:
        c = cl.to_frame().reindex(names)
        df["cluster_std"] = c["cluster_std"].to_numpy()
        df["cluster_ratio"] = c["ratio"].to_numpy()
        df["max_share"] = c["max_share"].to_numpy()
        extra["cluster"] = {
            "n_segments": cl.n_segments,
            "limit": cl.limit,
            "flag_ratio": V.cluster_flag_ratio,
            **cl.ratio_summary(),
        }
    return num({"per_parameter": frame_dict(df), "max_lag": max_lag, **extra})


def scatter_threshold(n_segments: int) -> float:
    """The maneuver-scatter / Cramér-Rao ratio that an exact bound exceeds with probability
    1 - SCATTER_CONFIDENCE: sqrt(chi2_q(G - 1) / (G - 1)) for G maneuvers (1.73 for 3,
    1.61 for 4, 1.54 for 5)."""
    df = n_segments - 1
    return float(np.sqrt(chi2.ppf(SCATTER_CONFIDENCE, df) / df))


def widen_by_scatter(result: EstimationResult, unc: dict[str, Any] | None) -> EstimationResult:
    """Where the maneuvers of a fit scatter significantly more than its Cramér-Rao bounds
    allow (the ratio of :func:`parameter_uncertainty`'s ``cluster_std`` to the bound above
    :func:`scatter_threshold`, with at least SCATTER_MIN_SEGMENTS maneuvers), report the
    scatter as that parameter's std: ``unc["widened"]`` lists them and the result returned
    reports the covariance scaled on those rows and columns (correlations kept; the bound
    stays a view, ``cov_type`` SCATTER_STD_METHOD). Only results whose std is the Cramér-Rao
    bound or, for the EKF and UKF, the filter's parameter covariance (whose scatter the
    filter keeps from each segment's information, estimators.filters.kalman) are widened.

    The bound assumes the model exact; flight data scatter more from maneuver to maneuver
    (Jategaonkar: "a fudge factor of 5-10")."""
    if result.std_method not in SCATTER_STD_METHOD or not unc or not unc.get("cluster"):
        return result
    n_seg = int(unc["cluster"]["n_segments"])
    if n_seg < SCATTER_MIN_SEGMENTS:
        return result
    t = scatter_threshold(n_seg)
    names = result.free_names
    wide = {
        n: float(d["cluster_ratio"])
        for n, d in unc["per_parameter"].items()
        if n in names
        and d.get("cluster_ratio") is not None
        and math.isfinite(d["cluster_ratio"])
        and d["cluster_ratio"] > t
    }
    if not wide:
        return result
    unc["widened"] = {"threshold": t, "confidence": SCATTER_CONFIDENCE, "parameters": wide}
    return widened(result, unc)


def widened(result: EstimationResult, unc: Mapping[str, Any] | None) -> EstimationResult:
    """``result`` reporting the covariance its validation's uncertainty (``unc``, as
    :func:`widen_by_scatter` left it) widened to the maneuver scatter; ``result`` itself when
    nothing was widened or it is widened already."""
    wide = ((unc or {}).get("widened") or {}).get("parameters")
    if not wide or result.std_method not in SCATTER_STD_METHOD:
        return result
    names = result.free_names
    D = np.ones(len(names))
    for n, r in wide.items():
        D[names.index(n)] = r
    return result.with_cov(D[:, None] * result.cov * D[None, :], SCATTER_STD_METHOD[result.std_method])
