"""Model structure from the data: which terms a regression needs.

- :class:`StepwiseRegression`: forward selection and backward elimination by partial F
  (Klein, Batterson & Murphy, NASA TP-1916, 1981; Klein & Morelli, *Aircraft System
  Identification*, 2006, ch. 5).
- :class:`OrthogonalFunctions`: multivariate polynomial candidates made mutually orthogonal
  as they are chosen, ranked by how much each reduces the fit error, kept while the
  predicted squared error falls, and returned as ordinary polynomial terms (Morelli,
  "Global nonlinear aerodynamic modeling using multivariate orthogonal functions",
  J. Aircraft 32(2), 1995).

Both report the predicted squared error PSE = MSE + 2 s2max p / N, with MSE the mean
squared fit error, p the number of terms (the bias included), N the samples and
s2max = sum (y - mean y)^2 / N the variance of y about its mean (a bound on the noise
variance): it falls while a term explains more than the noise could, then rises.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from estimators.equation_error import regression_model
from estimators.errors import IdentifiabilityError, ModelDefinitionError
from estimators.results import EstimationResult

#: a term whose Gram-Schmidt remainder keeps less than this share of its norm is already in
#: the span of the chosen ones (not a new direction)
DEPENDENT_RTOL = 1e-10


def _data(X: Any, y: Any, candidates: Sequence[str] | None) -> tuple[np.ndarray, np.ndarray, list[str], Any]:
    """(X (N, n), y (N,), the column names, the index) from a DataFrame or arrays."""
    index = None
    if isinstance(X, pd.DataFrame):
        names = list(candidates) if candidates is not None else [str(c) for c in X.columns]
        missing = [c for c in names if c not in X.columns]
        if missing:
            raise ModelDefinitionError(f"candidates {missing} are not columns of X {list(X.columns)}")
        index = X.index
        Xa = X[names].to_numpy(dtype=float)
    else:
        Xa = np.asarray(X, dtype=float)
        Xa = Xa[:, None] if Xa.ndim == 1 else Xa
        names = list(candidates) if candidates is not None else [f"x{i}" for i in range(Xa.shape[1])]
    ya = np.asarray(y, dtype=float).ravel()
    if Xa.ndim != 2 or Xa.shape[0] != ya.size or len(names) != Xa.shape[1]:
        raise ModelDefinitionError(f"X has shape {Xa.shape}, y {ya.size} samples, {len(names)} candidate names")
    ok = np.all(np.isfinite(Xa), axis=1) & np.isfinite(ya)
    if not ok.all():
        raise ModelDefinitionError(f"{int((~ok).sum())} rows hold NaN or inf: drop or fill them first")
    return Xa, ya, names, index


def pse(sse: float, n_terms: int, N: int, s2max: float) -> float:
    """The predicted squared error MSE + 2 s2max p / N (module docstring)."""
    return sse / N + 2.0 * s2max * n_terms / N


def _ols(A: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """(theta, SSE) of the least-squares fit of y on the columns of A."""
    theta, *_ = np.linalg.lstsq(A, y, rcond=None)
    e = y - A @ theta
    return theta, float(e @ e)


def _identifier(name: str) -> str:
    """A Python identifier for a term's name ("x^2*y" -> "x_2_y") for the result's Model."""
    s = re.sub(r"\W", "_", name)
    return s if s.isidentifier() else f"t_{s}"


def regression_result(
    method: str,
    A: np.ndarray,
    y: np.ndarray,
    names: list[str],
    index: Any,
    *,
    message: str = "",
    extra: dict[str, Any] | None = None,
) -> EstimationResult:
    """The ordinary least-squares fit of y on the columns of A (one per term in ``names``)
    as an EstimationResult: std from s2 (X^T X)^-1 with s2 = SSE / (N - p)."""
    N, p = A.shape
    if N <= p:
        raise ModelDefinitionError(f"{N} samples for {p} terms: a regression needs more samples than terms")
    AtA = A.T @ A
    if np.linalg.matrix_rank(AtA) < p:
        raise IdentifiabilityError("the selected terms are linearly dependent", parameters=names)
    theta, sse = _ols(A, y)
    s2 = sse / (N - p)
    cov = s2 * np.linalg.inv(AtA)
    ids = [_identifier(n) for n in names]
    model = regression_model([i for i in ids if i != "bias"], intercept="bias" in ids, name=f"{method} regression")
    order = [ids.index(n) for n in model.parameter_names]
    theta, cov = theta[order], cov[np.ix_(order, order)]
    t = np.arange(N, dtype=float) if index is None else np.asarray(index, dtype=float)
    yhat = A[:, order] @ theta
    return EstimationResult(
        method=method,
        model=model,
        names=[names[i] for i in order],
        values=theta,
        free=np.ones(p, dtype=bool),
        cov=cov,
        R=np.array([[s2]]),
        converged=True,
        iterations=1,
        history=pd.DataFrame(),
        predicted=[pd.DataFrame({"y": yhat}, index=pd.Index(t, name="t"))],
        residuals=[pd.DataFrame({"y": y - yhat}, index=pd.Index(t, name="t"))],
        message=message,
        information=AtA[np.ix_(order, order)] / s2,
        extra=extra or {},
    )


class StepwiseRegression:
    """Stepwise regression: terms enter while the largest partial F of those out exceeds
    ``f_in`` and leave while the smallest partial F of those in falls below ``f_out``
    (module docstring). The bias (``intercept``) is always in.

    ``fit(X, y)``: X (N, n) array or DataFrame whose columns are the candidates (their
    names: ``candidates``, else the DataFrame's columns, else x0..); returns the OLS fit of
    the selected terms, with ``extra["selected"]`` (their names in candidate order) and
    ``extra["steps"]`` (a DataFrame: action, term, F, R2, PSE per step, R2 a fraction).
    """

    method = "swr"

    def __init__(
        self, candidates: Sequence[str] | None = None, f_in: float = 4.0, f_out: float = 4.0, intercept: bool = True
    ) -> None:
        if f_out > f_in:
            raise ModelDefinitionError(f"f_out {f_out:g} above f_in {f_in:g}: a term could enter and leave forever")
        self.candidates = None if candidates is None else list(candidates)
        self.f_in, self.f_out, self.intercept = float(f_in), float(f_out), bool(intercept)

    def fit(self, X: Any, y: Any) -> EstimationResult:
        Xa, ya, names, index = _data(X, y, self.candidates)
        N, n = Xa.shape
        base = np.ones((N, 1)) if self.intercept else np.zeros((N, 0))
        sst = float(np.sum((ya - ya.mean()) ** 2)) if self.intercept else float(ya @ ya)
        s2max = float(np.sum((ya - ya.mean()) ** 2)) / N

        def sse_of(terms: list[int]) -> float:
            A = np.column_stack([base, Xa[:, terms]]) if terms else base
            return _ols(A, ya)[1] if A.shape[1] else float(ya @ ya)

        inside: list[int] = []
        sse = sse_of(inside)
        steps = [{"action": "start", "term": "bias" if self.intercept else "", "F": np.nan}]
        steps[-1].update(R2=1.0 - sse / sst if sst > 0 else 0.0, PSE=pse(sse, base.shape[1], N, s2max))
        for _ in range(4 * n + 4):  # each pass adds or removes one term; a cycle is impossible with f_out <= f_in
            p = base.shape[1] + len(inside)
            best = None
            for j in (j for j in range(n) if j not in inside):
                s_new = sse_of([*inside, j])
                dof = N - p - 1
                if dof <= 0 or s_new <= 0:
                    continue
                F = (sse - s_new) / (s_new / dof)
                if best is None or F > best[0]:
                    best = (F, j, s_new)
            if best is not None and best[0] > self.f_in:
                inside.append(best[1])
                sse = best[2]
                steps.append(self._step("add", names[best[1]], best[0], sse, sst, p + 1, N, s2max))
            else:
                worst = None
                for j in inside:
                    s_wo = sse_of([k for k in inside if k != j])
                    F = (s_wo - sse) / (sse / max(N - p, 1))
                    if worst is None or F < worst[0]:
                        worst = (F, j, s_wo)
                if worst is None or worst[0] >= self.f_out:
                    break
                inside.remove(worst[1])
                sse = worst[2]
                steps.append(self._step("remove", names[worst[1]], worst[0], sse, sst, p - 1, N, s2max))
                continue
            # after an addition, terms that the newcomer made redundant leave
            while len(inside) > 1:
                p = base.shape[1] + len(inside)
                worst = min(((sse_of([k for k in inside if k != j]) - sse) / (sse / max(N - p, 1)), j) for j in inside)
                if worst[0] >= self.f_out:
                    break
                inside.remove(worst[1])
                sse = sse_of(inside)
                steps.append(self._step("remove", names[worst[1]], worst[0], sse, sst, p - 1, N, s2max))
        selected = [names[j] for j in sorted(inside)]
        A = np.column_stack([base, Xa[:, sorted(inside)]]) if inside else base
        terms = (["bias"] if self.intercept else []) + selected
        if not terms:
            raise IdentifiabilityError("no term entered the model and there is no intercept", parameters=names)
        steps_df = pd.DataFrame(steps, columns=["action", "term", "F", "R2", "PSE"])
        return regression_result(
            self.method,
            A,
            ya,
            terms,
            index,
            message=f"{len(selected)} of {n} candidates selected (F in {self.f_in:g}, F out {self.f_out:g})",
            extra={"selected": selected, "steps": steps_df, "pse": float(steps_df["PSE"].iloc[-1])},
        )

    @staticmethod
    def _step(action: str, term: str, F: float, sse: float, sst: float, p: int, N: int, s2max: float) -> dict:
        return {
            "action": action,
            "term": term,
            "F": float(F),
            "R2": 1.0 - sse / sst if sst > 0 else 0.0,
            "PSE": pse(sse, p, N, s2max),
        }


class OrthogonalFunctions:
    """Multivariate orthogonal functions (module docstring).

    max_degree : the highest power of each column (one number for all, or one per column).
    max_order : the highest total order of a term (the sum of its powers).
    ``fit(X, y)``: X (N, n) array or DataFrame; the candidates are the monomials of its
    columns within those limits. At each step every candidate not chosen is orthogonalised
    against the chosen ones and the one that most reduces the fit error, (p^T y)^2 / p^T p,
    joins; terms are kept while PSE falls. Returns the OLS fit of the kept terms as ordinary
    polynomials, named "x", "x^2", "x*y", "x^2*y" (column names, powers in column order),
    with "bias"; ``extra["pse"]`` the final PSE, ``extra["ranked"]`` the terms in the order
    they joined with the PSE after each.
    """

    method = "mof"

    def __init__(self, max_degree: int | Sequence[int] = 3, max_order: int = 4) -> None:
        self.max_degree, self.max_order = max_degree, int(max_order)

    def candidates(self, names: Sequence[str]) -> list[tuple[int, ...]]:
        """The exponent tuples of the candidate monomials (the constant left out)."""
        n = len(names)
        deg = [int(self.max_degree)] * n if np.ndim(self.max_degree) == 0 else [int(d) for d in self.max_degree]
        if len(deg) != n:
            raise ModelDefinitionError(f"max_degree has {len(deg)} entries for {n} columns {list(names)}")
        out = [e for e in itertools.product(*(range(d + 1) for d in deg)) if 0 < sum(e) <= self.max_order]
        return sorted(out, key=lambda e: (sum(e), [-x for x in e]))

    @staticmethod
    def term_name(exponents: Sequence[int], names: Sequence[str]) -> str:
        """The term's name: "x", "x^2", "x*y", "x^2*y" for exponents over ``names``."""
        return "*".join(n if e == 1 else f"{n}^{e}" for n, e in zip(names, exponents) if e)

    def fit(self, X: Any, y: Any) -> EstimationResult:
        Xa, ya, names, index = _data(X, y, None)
        N = Xa.shape[0]
        exps = self.candidates(names)
        P = np.column_stack([np.prod(Xa ** np.array(e)[None, :], axis=1) for e in exps]) if exps else np.zeros((N, 0))
        s2max = float(np.sum((ya - ya.mean()) ** 2)) / N
        basis = [np.ones(N) / np.sqrt(N)]  # orthonormal functions chosen so far (the bias first)
        resid = ya - basis[0] * (basis[0] @ ya)
        sse = float(resid @ resid)
        best_pse, chosen, ranked = pse(sse, 1, N, s2max), [], [("bias", pse(sse, 1, N, s2max))]
        R = P - np.outer(basis[0], basis[0] @ P)  # the candidates' remainders against the basis
        norms0 = np.linalg.norm(P, axis=0)
        left = list(range(len(exps)))
        while left:
            nr = np.linalg.norm(R[:, left], axis=0)
            ok = nr > DEPENDENT_RTOL * np.maximum(norms0[left], 1e-300)
            if not ok.any():
                break
            gain = np.where(ok, (R[:, left].T @ resid) ** 2 / np.where(ok, nr**2, 1.0), -np.inf)
            k = left[int(np.argmax(gain))]
            q = R[:, k] / np.linalg.norm(R[:, k])
            new_sse = sse - float(q @ resid) ** 2
            new_pse = pse(new_sse, len(basis) + 1, N, s2max)
            if new_pse >= best_pse:
                break
            basis.append(q)
            resid = resid - q * (q @ resid)
            R -= np.outer(q, q @ R)
            chosen.append(k)
            left.remove(k)
            sse, best_pse = new_sse, new_pse
            ranked.append((self.term_name(exps[k], names), new_pse))
        kept = sorted(chosen, key=lambda k: exps.index(exps[k]))
        A = np.column_stack([np.ones(N), P[:, kept]])
        terms = ["bias"] + [self.term_name(exps[k], names) for k in kept]
        return regression_result(
            self.method,
            A,
            ya,
            terms,
            index,
            message=f"{len(kept)} of {len(exps)} candidate terms kept (PSE {best_pse:.4g})",
            extra={
                "pse": float(best_pse),
                "ranked": pd.DataFrame(ranked, columns=["term", "PSE"]),
                "candidates": [self.term_name(e, names) for e in exps],
            },
        )
