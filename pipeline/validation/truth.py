"""The truth check of a simulated run: each estimate against its known true value."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from estimators import EstimationResult
from pipeline.validation.json_values import num
from pipeline.validation.verdict import verdict

#: |estimate - truth| / std allowed for a truth check to pass
TRUTH_K = 3.0


def truth_check(result: EstimationResult, truth: Mapping[str, float], k: float) -> dict[str, Any]:
    """Each free parameter with a truth: |error| against k x its total std (the Cramér-Rao
    bound plus what the result's ``consider_cov`` adds, e.g. the sensor corrections)."""
    out = {}
    std = result.total_std
    for name in result.free_names:
        if name not in truth:
            continue
        est, sd, tr = float(result.params[name]), float(std[name]), float(truth[name])
        err = est - tr
        ins = abs(err) / sd if sd > 0 and math.isfinite(sd) else math.nan
        out[name] = num(
            {"estimate": est, "std": sd, "truth": tr, "error": err, "error_in_std": ins, "within": bool(ins <= k)}
        )
    return {"k": k, "per_parameter": out, "all_within": bool(out) and all(v["within"] for v in out.values())}


def refresh_truth_check(
    validation: dict[str, Any], result: EstimationResult, truth: Mapping[str, float] | None, truth_k: float = TRUTH_K
) -> None:
    """Redo the truth check and the verdict of ``validation`` (in place) after the result's
    uncertainty changed (a ``consider_cov`` set after validation)."""
    if not truth:
        return
    validation.setdefault("plausibility", {})["truth"] = truth_check(result, truth, truth_k)
    validation["verdict"] = verdict(validation)
