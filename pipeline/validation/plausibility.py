"""The plausibility of one fit's estimates against what is known of the aircraft without
flying it: the signs physics and the control sign conventions fix, and the a-priori values
(handbook, DATCOM, wind tunnel) of the aircraft file. Both judge an estimate by its total
std (the Cramér-Rao bound plus what the fit held as exact, ``result.total_std``), so they
are redone when that grows (:func:`refresh_plausibility`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import pandas as pd

from estimators import EstimationResult
from estimators import validation as V
from estimators.defaults import PLAUSIBILITY_K
from pipeline.validation.json_values import frame_dict
from pipeline.validation.verdict import verdict


def plausibility_checks(
    result: EstimationResult, apriori: Any = None, signs: Mapping[str, int] | None = None, k: float = PLAUSIBILITY_K
) -> dict[str, Any]:
    """The validation's ``plausibility`` entries of ``result``'s free parameters (truth
    aside): ``k``; ``signs`` per derivative with an expected sign (columns of
    :func:`estimators.validation.sign_check`; ``signs``: derivative -> +1/-1, default
    :func:`estimators.validation.expected_signs`); ``apriori`` per parameter with an
    a-priori value (columns of :func:`estimators.validation.plausibility`; ``apriori``: a
    TOML path, mapping or DataFrame of :func:`estimators.validation.load_apriori`)."""
    names = result.free_names
    est, std = result.params[names], result.total_std[names]
    out: dict[str, Any] = {"k": k, "signs": frame_dict(V.sign_check(est, std, signs, k))}
    if apriori is not None:
        out["apriori"] = frame_dict(V.plausibility(est, std, apriori, k))
    return out


def refresh_plausibility(validation: dict[str, Any], result: EstimationResult) -> None:
    """Redo the sign and a-priori checks of ``validation`` (in place) with the result's
    present total std, the expected signs and a-priori values those checks hold, and the
    verdict after them."""
    pl = validation.get("plausibility")
    if not pl or "signs" not in pl:
        return
    k = float(pl.get("k", PLAUSIBILITY_K))
    signs = {n: int(d["expected"]) for n, d in pl["signs"].items()}
    ap = pl.get("apriori")
    apriori = (
        pd.DataFrame(
            {"value": [d["apriori"] for d in ap.values()], "std": [d["apriori_std"] for d in ap.values()]},
            index=list(ap),
        )
        if ap
        else None
    )
    pl.update(plausibility_checks(result, apriori, signs, k))
    validation["verdict"] = verdict(validation)
