"""The methods of one run checked against each other: without a truth, the run's own check
of its estimates."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import pandas as pd

from estimators import EstimationResult
from estimators import validation as V
from pipeline.validation.json_values import num
from pipeline.validation.names import is_segment_parameter, method_group
from pipeline.validation.truth import TRUTH_K
from pipeline.validation.verdict import verdict


def cross_check_methods(
    results: Mapping[str, EstimationResult], validations: dict[str, dict[str, Any]], k: float = TRUTH_K
) -> dict[str, Any]:
    """Every pair of methods fitted to the same axis, compared on the parameters both
    estimate (:func:`estimators.validation.agreement`, with each result's total std: the
    Cramér-Rao bound plus its consider part). Run it once all uncertainties are final.
    Without a truth this is the run's own check of its estimates: a flag means a method's
    assumptions do not hold for the flight (e.g. output error in turbulence, or an EKF whose
    process noise carries the response it should leave to the parameters).

    Sets ``agreement`` in each compared method's validation and redoes its verdict: a FAIL
    reason for an EKF/UKF that disagrees with a converged filter-error fit (the method to
    trust in turbulence, :data:`pipeline.validation.verdict.REASON_LEVELS`), a note for any
    other disagreeing pair. The test is |a - b| / sqrt(std_a^2 + std_b^2) > k, k = TRUTH_K
    (3). Returns, per axis with at least two methods (key "" when the keys carry no axis):
    ``methods``, ``k``, ``table`` (one record per parameter and pair, the columns of
    :func:`~estimators.validation.agreement`), ``n_flagged`` and ``odd_one_out``: the
    method that disagrees with every other one while those agree among themselves (three
    methods or more; None otherwise) - the one whose assumptions to doubt first."""
    groups: dict[str, list[str]] = {}
    for key in results:
        groups.setdefault(method_group(key), []).append(key)
    out = {}
    for axis, keys in groups.items():
        if len(keys) < 2:
            continue
        est = {}
        for key in keys:
            r = results[key]
            names = [n for n in r.free_names if not n.startswith("x0_") and not is_segment_parameter(n)]
            est[key] = (r.params[names], r.total_std[names])
        table = V.agreement(est, k)
        for key in keys:
            if key in validations:
                _set_agreement(validations[key], key, table, results, k)
        pairs = {frozenset((r.method_a, r.method_b)) for r in table[table["flag"]].itertuples()}
        odd = [
            m
            for m in keys
            if len(keys) > 2
            and all(frozenset((m, o)) in pairs for o in keys if o != m)
            and not any(m not in pr for pr in pairs)
        ]
        out[axis] = {
            "methods": keys,
            "k": k,
            "n_flagged": int(table["flag"].sum()),
            "odd_one_out": odd[0] if odd else None,
            "table": num(table.to_dict(orient="records")),
        }
    return out


def _set_agreement(
    validation: dict[str, Any], key: str, table: pd.DataFrame, results: Mapping[str, EstimationResult], k: float
) -> None:
    """Set ``agreement`` of method ``key``'s validation from the pairwise ``table`` (``k``,
    ``flagged``: per other method the parameters and their z, ``against``: its method name
    and convergence) and redo its verdict."""
    flagged: dict[str, dict[str, float]] = {}
    for row in table[table["flag"]].itertuples():
        if key in (row.method_a, row.method_b):
            other = row.method_b if key == row.method_a else row.method_a
            flagged.setdefault(other, {})[row.parameter] = float(row.z)
    validation["agreement"] = {
        "k": k,
        "flagged": flagged,
        "against": {o: {"method": results[o].method, "converged": bool(results[o].converged)} for o in flagged},
    }
    validation["verdict"] = verdict(validation)
