"""Plausibility: estimates against a-priori values (wind tunnel, handbook) that carry
their own uncertainty; flagged where |estimate - a priori| > k * sqrt(std^2 + std_ap^2).
:func:`agreement` applies the same test between methods: each pair of methods' estimates
of the same parameters from the same flight.

A-priori TOML, one table per parameter (values per radian as in DESIGN.md section 3):

    [Cmq]
    value = -25.0
    std = 5.0            # or rel_std = 0.2 (fraction of |value|)
    source = "DATCOM"    # optional

An optional top-level table ``[apriori]`` holding these tables is also accepted.

:func:`sign_check` judges the derivatives whose sign physics or the control-surface sign
convention fixes (:data:`SIGN_RULES`, :func:`expected_signs`): flagged where the estimate
lies on the wrong side of zero by more than k of its own std, so an estimate near zero
within its uncertainty is never flagged.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from estimators.defaults import PLAUSIBILITY_K

__all__ = [
    "CONTROL_DERIVATIVES",
    "SIGN_REASONS",
    "SIGN_RULES",
    "agreement",
    "expected_signs",
    "load_apriori",
    "plausibility",
    "sign_check",
]

#: derivative -> the sign physics fixes (+1 positive, -1 negative) for a conventional
#: aircraft: lift rises with alpha, side force opposes sideslip, dihedral effect,
#: weathercock stability, roll, yaw and pitch damping, static stability in pitch
#: (Cmalpha, dropped for an aircraft declared statically unstable), and the control
#: derivatives in DESIGN.md's convention (de > 0 trailing edge down: more lift, nose
#: down; da > 0 right aileron trailing edge up: roll right; dr > 0 trailing edge left:
#: side force to the right, nose left)
SIGN_RULES: dict[str, int] = {
    "CLalpha": 1,
    "CYbeta": -1,
    "Clbeta": -1,
    "Clp": -1,
    "Cnbeta": 1,
    "Cnr": -1,
    "Cmq": -1,
    "Cmalpha": -1,
    "CLde": 1,
    "Cmde": -1,
    "Clda": 1,
    "CYdr": 1,
    "Cndr": -1,
}
#: what fixes each sign of :data:`SIGN_RULES`, for the verdict's sentences
SIGN_REASONS: dict[str, str] = {
    "CLalpha": "lift rises with angle of attack",
    "CYbeta": "side force opposes sideslip",
    "Clbeta": "dihedral effect",
    "Clp": "roll damping",
    "Cnbeta": "weathercock stability",
    "Cnr": "yaw damping",
    "Cmq": "pitch damping",
    "Cmalpha": "static stability in pitch",
    "CLde": "the elevator's sign convention",
    "Cmde": "the elevator's sign convention",
    "Clda": "the aileron's sign convention",
    "CYdr": "the rudder's sign convention",
    "Cndr": "the rudder's sign convention",
}
#: control input -> the derivatives of :data:`SIGN_RULES` whose sign its convention sets
CONTROL_DERIVATIVES: dict[str, tuple[str, ...]] = {"de": ("CLde", "Cmde"), "da": ("Clda",), "dr": ("CYdr", "Cndr")}


def load_apriori(source: str | Path | Mapping) -> pd.DataFrame:
    """Read a-priori values from a TOML file (or an already parsed mapping).

    Returns a DataFrame indexed by parameter with ``value``, ``std`` and ``source``.
    Raises ValueError naming the entry when a value or its uncertainty is missing.
    """
    if isinstance(source, Mapping):
        data = dict(source)
    else:
        with open(source, "rb") as fh:
            data = tomllib.load(fh)
    if isinstance(data.get("apriori"), Mapping):
        data = data["apriori"]
    rows = {}
    for name, entry in data.items():
        if not isinstance(entry, Mapping) or "value" not in entry:
            raise ValueError(
                f"a-priori entry {name!r}: needs a table with 'value' and 'std' (or 'rel_std'); got {entry!r}"
            )
        v = float(entry["value"])
        if "std" in entry:
            s = float(entry["std"])
        elif "rel_std" in entry:
            s = abs(v) * float(entry["rel_std"])
        else:
            raise ValueError(f"a-priori entry {name!r}: give 'std' or 'rel_std'")
        if not s >= 0:
            raise ValueError(f"a-priori entry {name!r}: std must be >= 0, got {s}")
        rows[name] = {"value": v, "std": s, "source": str(entry.get("source", ""))}
    return pd.DataFrame.from_dict(rows, orient="index", columns=["value", "std", "source"]).rename_axis("parameter")


def plausibility(estimates, std, apriori, k: float = PLAUSIBILITY_K) -> pd.DataFrame:
    """Compare estimates (Series/dict by name) and their std with a-priori values.

    apriori: DataFrame from :func:`load_apriori` (``value``, ``std``), a TOML path or
    mapping. Only parameters present in both are compared. k: number of combined standard
    deviations allowed. Returns a DataFrame indexed by parameter: ``estimate``, ``std``,
    ``apriori``, ``apriori_std``, ``diff`` (estimate - a priori), ``combined_std``,
    ``z`` = |diff| / combined_std, ``flag`` (z > k).
    """
    ap = apriori if isinstance(apriori, pd.DataFrame) else load_apriori(apriori)
    est, sd = pd.Series(estimates, dtype=float), pd.Series(std, dtype=float)
    names = [n for n in est.index if n in ap.index]
    e, s = est[names].to_numpy(), sd.reindex(names).fillna(0.0).to_numpy()
    a, sa = ap.loc[names, "value"].to_numpy(float), ap.loc[names, "std"].to_numpy(float)
    diff = e - a
    comb = np.sqrt(s**2 + sa**2)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.abs(diff) / comb
    z = np.where((comb == 0) & (diff == 0), 0.0, z)
    return pd.DataFrame(
        {
            "estimate": e,
            "std": s,
            "apriori": a,
            "apriori_std": sa,
            "diff": diff,
            "combined_std": comb,
            "z": z,
            "flag": z > k,
        },
        index=pd.Index(names, name="parameter"),
    )


def agreement(estimates: Mapping[str, tuple[Any, Any]], k: float = PLAUSIBILITY_K) -> pd.DataFrame:
    """Cross-check of several methods' estimates of the same parameters.

    estimates: {method: (estimates, std)}, each a Series/dict by parameter name (std: the
    method's own bound, e.g. the Cramér-Rao bound or a total std). Every pair of methods is
    compared on the parameters both have, as :func:`plausibility` compares an estimate with
    an a-priori value: z = |a - b| / sqrt(std_a^2 + std_b^2), flagged when z > k.

    Two fits of one flight share its noise, so their errors are positively correlated and
    the std of their difference is below sqrt(std_a^2 + std_b^2) (for an efficient method a
    and a consistent one b it is sqrt(std_b^2 - std_a^2), Hausman's test): the test is
    conservative, and a flag means at least one of the two methods' assumptions (model
    structure, noise, process noise) does not hold for these data.

    Returns a DataFrame, one row per parameter and pair (in the order given): ``parameter``,
    ``method_a``, ``method_b``, ``estimate_a``, ``std_a``, ``estimate_b``, ``std_b``,
    ``diff`` (a - b), ``combined_std``, ``z``, ``flag``. Parameters whose std is missing or
    not finite in either method are left out.
    """
    cols = [
        "parameter",
        "method_a",
        "method_b",
        "estimate_a",
        "std_a",
        "estimate_b",
        "std_b",
        "diff",
        "combined_std",
        "z",
        "flag",
    ]
    series = {m: (pd.Series(e, dtype=float), pd.Series(s, dtype=float)) for m, (e, s) in estimates.items()}
    parts = []
    names = list(series)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            (ea, sa), (eb, sb) = series[a], series[b]
            ok = [
                n
                for n in ea.index
                if n in eb.index and np.isfinite(sa.get(n, np.nan)) and np.isfinite(sb.get(n, np.nan))
            ]
            if not ok:
                continue
            ap = pd.DataFrame({"value": eb[ok], "std": sb[ok]})
            pl = plausibility(ea[ok], sa[ok], ap, k).reset_index()
            parts.append(
                pd.DataFrame(
                    {
                        "parameter": pl["parameter"],
                        "method_a": a,
                        "method_b": b,
                        "estimate_a": pl["estimate"],
                        "std_a": pl["std"],
                        "estimate_b": pl["apriori"],
                        "std_b": pl["apriori_std"],
                        "diff": pl["diff"],
                        "combined_std": pl["combined_std"],
                        "z": pl["z"],
                        "flag": pl["flag"],
                    }
                )
            )
    if not parts:
        return pd.DataFrame(columns=cols)
    return pd.concat(parts, ignore_index=True)[cols]


def expected_signs(
    reversed_inputs: tuple[str, ...] | list[str] = (),
    *,
    unstable: bool = False,
    declared: Mapping[str, float] | None = None,
) -> dict[str, int]:
    """The sign each derivative is expected to have: :data:`SIGN_RULES`, the control
    derivatives of ``reversed_inputs`` (de, da, dr whose positive deflection is the
    opposite of DESIGN.md's convention) negated, Cmalpha left out for an aircraft
    declared statically ``unstable``; a ``declared`` value (a truth set's derivative
    table, which defines its aircraft) sets its derivative's sign, 0 drops the rule."""
    bad = [a for a in reversed_inputs if a not in CONTROL_DERIVATIVES]
    if bad:
        raise ValueError(f"reversed inputs {bad}: use {', '.join(CONTROL_DERIVATIVES)}")
    signs = dict(SIGN_RULES)
    for a in reversed_inputs:
        for n in CONTROL_DERIVATIVES[a]:
            signs[n] = -signs[n]
    if unstable:
        signs.pop("Cmalpha")
    for n, v in (declared or {}).items():
        if n in signs:
            if float(v) == 0.0:
                signs.pop(n)
            else:
                signs[n] = 1 if float(v) > 0 else -1
    return signs


def sign_check(estimates, std, signs: Mapping[str, int] | None = None, k: float = PLAUSIBILITY_K) -> pd.DataFrame:
    """Each estimate whose sign is expected (``signs``: derivative -> +1/-1, default
    :func:`expected_signs`) judged against it.

    estimates, std: Series/dicts by name (per rad, as in DESIGN.md section 3); names without
    an expected sign or without a finite std > 0 (a held parameter) are left out.
    Returns a DataFrame indexed by parameter: ``estimate``, ``std``, ``expected`` (+1/-1),
    ``margin`` = expected * estimate / std (how many std the estimate lies on the expected
    side of zero; negative: the wrong side) and ``flag`` (margin < -k: wrong sign beyond
    its own uncertainty).
    """
    signs = expected_signs() if signs is None else signs
    est, sd = pd.Series(estimates, dtype=float), pd.Series(std, dtype=float)
    names = [n for n in est.index if n in signs and sd.get(n, np.nan) > 0 and np.isfinite(sd[n] * est[n])]
    e, s = est[names].to_numpy(), sd[names].to_numpy()
    sign = np.array([signs[n] for n in names], dtype=int)
    margin = sign * e / s
    return pd.DataFrame(
        {"estimate": e, "std": s, "expected": sign, "margin": margin, "flag": margin < -k},
        index=pd.Index(names, name="parameter"),
    )
