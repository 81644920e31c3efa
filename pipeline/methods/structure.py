"""What structure the data ask for (``fsid estimate --method ls --structure stepwise|mof``):
each of a problem's coefficient regressions (CL, CD, Cm; CY, Cl, Cn) searched over a pool
of candidate terms - the built-in model's own and nonlinear ones made of the same
variables (alpha^2, alpha^3, alpha*de, alpha*q, beta^2, beta*dr, ...) - by stepwise
regression (:class:`estimators.StepwiseRegression`) or multivariate orthogonal functions
(:class:`estimators.OrthogonalFunctions`). The report says, per coefficient, which terms
the data select, which of them the model lacks and which model terms they do not need.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import pandas as pd

from estimators import EstimationError, OrthogonalFunctions, StepwiseRegression
from pipeline.problems import Problem

#: the structure searches the command line offers
STRUCTURES = ("stepwise", "mof")
#: stepwise regression's F to enter and to leave: a partial F of a term that carries
#: nothing is F(1, N - p) distributed; with the thousands of correlated samples of a
#: flight (fewer independent ones) 4 admits spurious terms, 20 does not (p ~ 1e-5)
STRUCTURE_F = 20.0
#: the variables whose powers join the pool (angles whose aerodynamics bend)
CURVED = ("alpha", "beta")
#: multivariate orthogonal functions: the highest power of a curved variable, of the others
#: and the highest total order
MOF_DEGREE, MOF_OTHER_DEGREE, MOF_ORDER = 3, 1, 3


def _variables(coef: str, names: list, X: np.ndarray) -> dict[str, np.ndarray]:
    """The regression's variables by name (its parameter names less the coefficient's:
    CLalpha -> alpha), the intercept and the model's own powers (CDalpha2) left out."""
    out = {}
    for i, n in enumerate(names):
        if n is None or not n.startswith(coef):
            continue
        v = n[len(coef) :]
        if v and v != "0" and not v[-1].isdigit():
            out[v] = X[:, i]
    return out


def _pool(coef: str, names: list, X: np.ndarray) -> tuple[pd.DataFrame, dict[str, str]]:
    """(the candidate columns, model parameter -> its candidate's name) of one regression:
    the model's terms (by variable, its own powers as x^k) and the nonlinear ones."""
    var = _variables(coef, names, X)
    cols: dict[str, np.ndarray] = dict(var)
    own = {}
    for n in names:
        if n is None or not n.startswith(coef):
            continue
        v = n[len(coef) :]
        if v in var:
            own[n] = v
        elif v and v[-1].isdigit() and v.rstrip("0123456789") in var:  # CDalpha2: alpha^2
            base, k = v.rstrip("0123456789"), int(v[len(v.rstrip("0123456789")) :])
            cols[f"{base}^{k}"] = var[base] ** k
            own[n] = f"{base}^{k}"
    for v in (v for v in CURVED if v in var):
        for k in (2, 3):
            cols.setdefault(f"{v}^{k}", var[v] ** k)
    for a, b in itertools.combinations(var, 2):
        if a in CURVED or b in CURVED:
            cols[f"{a}*{b}"] = var[a] * var[b]
    return pd.DataFrame(cols), own


def structure_search(problem: Problem, how: str) -> dict[str, Any]:
    """Per coefficient regression of ``problem``: the terms ``how`` selects from the pool
    (module docstring), those the model lacks (``added``) and the model's terms not selected
    (``not_needed``), with the selection steps (stepwise: action, term, F, R2, PSE; mof:
    term and PSE as each joined)."""
    out = {}
    for reg in problem.regressions:
        X, own = _pool(reg.coef, list(reg.names), np.asarray(reg.X, dtype=float))
        if X.empty:
            continue
        try:
            if how == "stepwise":
                res = StepwiseRegression(list(X.columns), f_in=STRUCTURE_F, f_out=STRUCTURE_F).fit(X, reg.y)
                selected, steps = list(res.extra["selected"]), res.extra["steps"]
            else:
                var = [c for c in X.columns if "^" not in c and "*" not in c]
                degree = [MOF_DEGREE if v in CURVED else MOF_OTHER_DEGREE for v in var]
                res = OrthogonalFunctions(max_degree=degree, max_order=MOF_ORDER).fit(X[var], reg.y)
                selected, steps = [n for n in res.names if n != "bias"], res.extra["ranked"]
        except (EstimationError, np.linalg.LinAlgError) as exc:
            out[reg.coef] = {"error": str(exc)}
            continue
        model_terms = set(own.values())
        out[reg.coef] = {
            "method": how,
            "candidates": list(X.columns),
            "selected": selected,
            "added": [t for t in selected if t not in model_terms],
            "not_needed": [p for p, t in own.items() if t not in selected],
            "estimates": {n: float(res.params[n]) for n in res.names},
            "std": {n: float(res.std[n]) for n in res.names},
            "pse": float(res.extra["pse"]),
            "steps": steps.replace({np.nan: None}).to_dict("records"),
        }
    return out
