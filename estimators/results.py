"""The result type shared by every estimation method (OEM, FEM, EKF, UKF, least squares)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from estimators.covariance.cluster import maneuver_scatter
from estimators.defaults import CLUSTER_FLAG_RATIO, CORR_FLAG
from estimators.model import Model, Segment

#: column label of ``std`` per ``EstimationResult.std_method`` (summary, report.md)
STD_LABELS = {
    "crb": "std (CRB)",
    "filter-covariance": "std (filter P)",
    "propagated": "std (propagated)",
    "morelli-klein": "std (M-K)",
    "sandwich": "std (sandwich)",
    "crb|scatter": "std (CRB or scatter)",
    "filter-covariance|scatter": "std (filter P or scatter)",
    "crb|sandwich": "std (CRB or sandwich)",
    "crb|sandwich|scatter": "std (CRB, sandwich or scatter)",
}


def std_label(method: str) -> str:
    """The column label of the std for ``std_method`` (unknown methods: "std (<method>)")."""
    return STD_LABELS.get(method, f"std ({method})")


@dataclass(frozen=True)
class EstimationResult:
    """Estimates, Cramér-Rao bounds and fit of one estimation run.

    A result does not change after its fit: what comes later (another covariance, a
    consider part, a note) makes a new result with :meth:`with_cov`, :meth:`with_consider`
    or :meth:`with_extra`, so a result held by one stage reads the same in every other.

    Attributes
    ----------
    method : "oem", "fem", "ekf", ...
    model : the model fitted (start values as given).
    names : (n_all,) expanded parameter names (``Cmq``, ``bias_az[0]``, ``x0_V[1]``).
    values : (n_all,) estimates (fixed parameters at their values).
    free : (n_all,) True where estimated.
    cov : (n_free, n_free) the reported parameter covariance over the free parameters in
        ``names`` order (the one named ``cov_type``); NaN rows/columns for parameters that
        ended at a bound.
    cov_type : the name of ``cov``: "crb" (Cramér-Rao, the inverse information matrix),
        "filter-covariance" (EKF/UKF: the parameter block of P), "morelli-klein",
        "propagated", "crb|scatter" (widened by the maneuver scatter), ...
    covariances : every covariance the result carries, by name (``cov`` among them; the
        fit's own first): views chosen by name like statsmodels' ``cov_type``.
    R : (n_outputs, n_outputs) measurement-noise (residual) covariance.
    converged, iterations, message : optimiser outcome.
    history : one row per iteration: cost, step length, and the free parameters.
    predicted, residuals : per segment, DataFrames on t with one column per output.
    at_bounds : names of parameters that ended on a bound (their std is NaN).
    information : (n_free, n_free) Fisher information matrix at the optimum.
    sensitivities : per segment the output sensitivities, when kept: a
        :class:`~estimators.sensitivity.Sensitivity` (the free parameters the segment depends
        on; ``np.asarray`` gives the dense (N, n_outputs, n_free) array).
    extra : method-specific details (filter gain, process noise, parameter trajectories).
    consider_cov : (n_free, n_free) covariance added to ``cov`` by uncertain quantities the
        fit held as exact ("consider" parameters in the sense of Schmidt: e.g. the sensor
        corrections applied to the data before the fit), in ``free_names`` order; None
        when there are none. ``std`` stays the Cramér-Rao bound; ``total_std`` includes it.
    consider_source : what ``consider_cov`` accounts for (one line, for reports).
    """

    method: str
    model: Model
    names: list[str]
    values: np.ndarray
    free: np.ndarray
    cov: np.ndarray
    R: np.ndarray
    converged: bool
    iterations: int
    history: pd.DataFrame
    predicted: list[pd.DataFrame]
    residuals: list[pd.DataFrame]
    segments: list[Segment] = field(default_factory=list)
    at_bounds: list[str] = field(default_factory=list)
    message: str = ""
    information: np.ndarray | None = None
    sensitivities: list[Any] | None = None
    settings: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    consider_cov: np.ndarray | None = None
    consider_source: str = ""
    cov_type: str = "crb"
    covariances: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.cov_type not in self.covariances:
            object.__setattr__(self, "covariances", {**self.covariances, self.cov_type: self.cov})

    # -- new results from this one ----------------------------------------------------------
    def replace(self, **changes: Any) -> EstimationResult:
        """A copy with ``changes`` (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def with_cov(self, cov: np.ndarray, cov_type: str, note: str = "") -> EstimationResult:
        """A copy that reports ``cov`` (n_free, n_free), named ``cov_type``, instead of the
        current covariance, which stays a view by its name; ``note`` is appended to the
        message."""
        message = (self.message + "; " if self.message and note else self.message) + note
        return dataclasses.replace(
            self, cov=cov, cov_type=cov_type, covariances={**self.covariances, cov_type: cov}, message=message
        )

    def with_cov_type(self, cov_type: str) -> EstimationResult:
        """A copy that reports the covariance view named ``cov_type`` (one of
        ``covariances``, or "total")."""
        return dataclasses.replace(self, cov=self.cov_of(cov_type), cov_type=cov_type)

    def with_consider(self, cov: np.ndarray, source: str) -> EstimationResult:
        """A copy with ``cov`` (n_free, n_free) added to the consider covariance and
        ``source`` to what it accounts for."""
        total = cov if self.consider_cov is None else self.consider_cov + cov
        return dataclasses.replace(
            self, consider_cov=total, consider_source="; ".join(x for x in (self.consider_source, source) if x)
        )

    def with_extra(self, **items: Any) -> EstimationResult:
        """A copy with ``items`` added to ``extra``."""
        return dataclasses.replace(self, extra={**self.extra, **items})

    # -- covariance views -----------------------------------------------------------------
    @property
    def fit_cov_type(self) -> str:
        """The name of the fit's own covariance ("crb" or "filter-covariance")."""
        return next(iter(self.covariances))

    @property
    def fit_cov(self) -> np.ndarray:
        """The fit's own covariance (Cramér-Rao bound or filter P), whatever ``cov`` reports."""
        return self.covariances[self.fit_cov_type]

    def cov_of(self, cov_type: str) -> np.ndarray:
        """The covariance view named ``cov_type``: one of ``covariances``, or "total" (the
        reported covariance plus the consider covariance)."""
        if cov_type == "total":
            return self.cov if self.consider_cov is None else self.cov + self.consider_cov
        if cov_type not in self.covariances:
            raise KeyError(f"no covariance {cov_type!r}: this result has {', '.join(self.covariances)} and total")
        return self.covariances[cov_type]

    def std_of(self, cov_type: str) -> pd.Series:
        """Standard deviations of the view ``cov_type`` by expanded name (NaN for fixed
        parameters and those at a bound)."""
        return self._std(self.cov_of(cov_type), cov_type)

    def _std(self, cov: np.ndarray, name: str = "std") -> pd.Series:
        s = pd.Series(np.nan, index=self.names, name=name)
        d = np.diag(cov)
        s.loc[self.free_names] = np.sqrt(np.where(d >= 0, d, np.nan))
        return s

    # -- parameter tables -----------------------------------------------------------------
    @property
    def free_names(self) -> list[str]:
        return [n for n, f in zip(self.names, self.free) if f]

    @property
    def params(self) -> pd.Series:
        """All parameters (free and fixed) by expanded name."""
        return pd.Series(self.values, index=self.names, name="estimate")

    @property
    def std(self) -> pd.Series:
        """Standard deviations from ``cov`` (the view ``cov_type``); NaN for fixed parameters
        and those at a bound."""
        return self._std(self.cov)

    @property
    def std_method(self) -> str:
        """How ``std`` was computed: ``cov_type``."""
        return self.cov_type

    @property
    def consider_std(self) -> pd.Series | None:
        """Standard deviations from ``consider_cov`` alone (None without one)."""
        if self.consider_cov is None:
            return None
        s = pd.Series(np.nan, index=self.names, name="consider_std")
        s.loc[self.free_names] = np.sqrt(np.clip(np.diag(self.consider_cov), 0.0, None))
        return s

    @property
    def total_std(self) -> pd.Series:
        """sqrt(CRB variance + consider variance): the uncertainty to judge an estimate by
        (equal to ``std`` when nothing was held as exact)."""
        if self.consider_cov is None:
            return self.std.rename("total_std")
        return np.sqrt(self.std**2 + self.consider_std**2).rename("total_std")

    @property
    def rel_std(self) -> pd.Series:
        """Relative standard deviation in percent, 100 std / |estimate|."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return (100.0 * self.std / self.params.abs()).rename("rel_std_pct")

    @property
    def corr(self) -> pd.DataFrame:
        """Correlation coefficients of the free estimates."""
        d = np.sqrt(np.diag(self.cov))
        with np.errstate(divide="ignore", invalid="ignore"):
            c = self.cov / np.outer(d, d)
        return pd.DataFrame(c, index=self.free_names, columns=self.free_names)

    @property
    def flagged_correlations(self) -> list[tuple[str, str, float]]:
        """Pairs with |rho| > 0.9: estimates that the data cannot separate well."""
        c = self.corr.to_numpy()
        names = self.free_names
        i, j = np.triu_indices(len(names), 1)
        hit = np.abs(c[i, j]) > CORR_FLAG
        return [(names[a], names[b], float(c[a, b])) for a, b in zip(i[hit], j[hit])]

    @property
    def cost(self) -> float:
        """det(R), the maximum-likelihood cost with R estimated."""
        return float(np.linalg.det(self.R))

    @property
    def outputs(self) -> list[str]:
        return list(self.model.outputs)

    @property
    def n_samples(self) -> int:
        return int(sum(len(r) for r in self.residuals))

    def table(self, truth: dict[str, float] | None = None) -> pd.DataFrame:
        """Free parameters: estimate, std (CRB), rel. std %, with a ``consider_cov`` also
        consider_std and total_std, and with ``truth`` the error in (total) std."""
        names = self.free_names
        df = pd.DataFrame({"estimate": self.params[names], "std": self.std[names], "rel_std_pct": self.rel_std[names]})
        if self.consider_cov is not None:
            df["consider_std"] = self.consider_std[names]
            df["total_std"] = self.total_std[names]
        df["at_bound"] = [n in self.at_bounds for n in names]
        if truth:
            df["truth"] = [truth.get(n, np.nan) for n in names]
            df["error_in_std"] = (df["estimate"] - df["truth"]).abs() / self.total_std[names]
        return df

    def model_with_estimates(self) -> Model:
        """The model with its shared parameters set to the estimates, all held fixed -
        for proof of match on data not used in the fit."""
        vals = {n: v for n, v in zip(self.names, self.values) if "[" not in n}
        return self.model.with_values(vals, free=False)

    # -- text -----------------------------------------------------------------------------
    def summary(self, truth: dict[str, float] | None = None) -> str:
        """A text table in the manner of statsmodels' summary()."""
        width = 78
        s = self.settings
        head = [
            f"{self.method.upper()} estimation results".center(width),
            "=" * width,
            f"Model: {self.model.name:<22} Method: {self.method.upper()}"
            + (f" ({s.get('integrator')}, {s.get('optimizer')})" if s.get("integrator") else ""),
            f"Segments: {len(self.residuals):<19} Samples: {self.n_samples:<10} Outputs: {len(self.outputs)}",
            f"Converged: {'yes' if self.converged else 'NO':<18} Iterations: {self.iterations:<7} det(R): {self.cost:.4e}",
        ]
        if self.message:
            head.append(f"Note: {self.message}")
        head.append("-" * width)
        cols = f"{'parameter':<16}{'estimate':>13}{std_label(self.std_method):>13}{'rel std %':>11}"
        consider = self.consider_cov is not None
        if consider:
            cols += f"{'std (total)':>13}"
        if truth:
            cols += f"{'truth':>12}{'|err|/std':>10}"
        head.append(cols)
        head.append("-" * width)
        tab = self.table(truth)
        for name, row in tab.iterrows():
            line = f"{name:<16}{row['estimate']:>13.5g}"
            line += f"{row['std']:>13.4g}" if np.isfinite(row["std"]) else f"{'-':>13}"
            line += f"{row['rel_std_pct']:>11.2f}" if np.isfinite(row["rel_std_pct"]) else f"{'-':>11}"
            if consider:
                line += f"{row['total_std']:>13.4g}" if np.isfinite(row["total_std"]) else f"{'-':>13}"
            if truth:
                line += f"{row['truth']:>12.5g}" if np.isfinite(row["truth"]) else f"{'':>12}"
                line += f"{row['error_in_std']:>10.2f}" if np.isfinite(row["error_in_std"]) else f"{'':>10}"
            if row["at_bound"]:
                line += "  at bound"
            head.append(line)
        fixed = [n for n, f in zip(self.names, self.free) if not f and not n.startswith("x0_")]
        if fixed:
            head.append("-" * width)
            head.append("fixed: " + ", ".join(f"{n}={v:.4g}" for n, v in zip(self.names, self.values) if n in fixed))
        if consider:
            head.append("std (total) = sqrt(CRB^2 + consider^2), consider: " + self.consider_source)
        head.append("-" * width)
        sd = np.sqrt(np.diag(self.R))
        head.append("residual std: " + "  ".join(f"{o}={v:.3g}" for o, v in zip(self.outputs, sd)))
        flags = self.flagged_correlations
        if flags:
            head.append(f"|correlation| > {CORR_FLAG}: " + ", ".join(f"{a}~{b} ({r:+.3f})" for a, b, r in flags))
        head += self._scatter_lines()
        head.append("=" * width)
        return "\n".join(head)

    def _scatter_lines(self) -> list[str]:
        """The maneuver-to-maneuver scatter against the Cramér-Rao bounds (2+ segments,
        estimators.validation.maneuver_scatter), for summary()."""
        cl = maneuver_scatter(self)
        r = cl.ratio_summary() if cl is not None else {}
        if r.get("max_ratio") is None:
            return []
        out = [
            f"maneuver scatter / CRB ({cl.n_segments} segments): median {r['median_ratio']:.2f}, "
            f"largest {r['max_ratio']:.2f} ({r['max_parameter']})"
        ]
        if r["flagged"]:
            out.append(
                f"  above {CLUSTER_FLAG_RATIO:g}x (the bound understates them): "
                + ", ".join(f"{n} {v:.1f}x" for n, v in r["flagged"].items())
            )
        return out

    def __repr__(self) -> str:  # pragma: no cover - convenience
        return self.summary()

    def to_dict(self, truth: dict[str, float] | None = None) -> dict[str, Any]:
        """JSON-ready numbers: parameters with estimate/std/rel std (and truth), R, fit."""
        tab = self.table(truth)
        params = {}
        for name, row in tab.iterrows():
            d = {k: (None if not np.isfinite(v) else float(v)) for k, v in row.items() if k != "at_bound"}
            d["at_bound"] = bool(row["at_bound"])
            params[name] = d
        return {
            "method": self.method,
            "model": self.model.name,
            "converged": bool(self.converged),
            "iterations": int(self.iterations),
            "message": self.message,
            "det_R": self.cost,
            "R": np.asarray(self.R).tolist(),
            "outputs": self.outputs,
            "n_samples": self.n_samples,
            "parameters": params,
            "correlations_flagged": [list(f) for f in self.flagged_correlations],
            "settings": {k: v for k, v in self.settings.items() if isinstance(v, (str, int, float, bool))},
        }


def frames(t_list: Sequence[np.ndarray], arrays: Sequence[np.ndarray], columns: Sequence[str]) -> list[pd.DataFrame]:
    """Per-segment DataFrames on t from (N, n) arrays."""
    return [pd.DataFrame(a, index=pd.Index(t, name="t"), columns=list(columns)) for t, a in zip(t_list, arrays)]
