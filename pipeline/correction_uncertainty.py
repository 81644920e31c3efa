"""How the uncertainty of the sensor corrections reaches the estimated derivatives.

The compatibility stage (:func:`pipeline.compatibility.correct_for_estimation`) removes the
significant sensor errors from the data before estimation, with estimates c (k values)
that carry their own Cramér-Rao covariance C. Every estimation method then treats the
corrected data as exact, so its Cramér-Rao bound is conditional on c: an alpha-vane scale
factor known to +-0.5 % moves Cmalpha by about as much, which no fit on the corrected data
can see. This module accounts for it as "consider" parameters (Schmidt):

    J[:, j] = (theta(c + s_j e_j) - theta(c)) / s_j      (s_j: std of c_j; one refit each)
    P_consider = J C J^T                                  (added to the CRB: total std)

Each refit corrects the logged data with c_j moved by one std and repeats the run's fits
exactly (same problems, same methods); maximum-likelihood and least-squares methods start
from the run's estimates (``pipeline.run.START_FREE``), the EKF/UKF from their usual start.
A method whose refit fails or changes its parameter list keeps its CRB alone, and the
document says so.

Measured on sensor_errors_calm (13 corrections applied, longitudinal output error):
see tests/test_closed_loop_compat_run.py.
"""
from __future__ import annotations

import io
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pandas as pd

from pipeline.flightdata import FlightData

SOURCE = "the uncertainty of the sensor corrections applied before the fit"


def correction_covariance(doc: Mapping[str, Any]) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(names, estimates (k,), covariance (k, k)) of the applied sensor corrections from
    the compatibility document (``applied`` with estimate/std, ``applied_correlation``;
    uncorrelated when the correlation is missing)."""
    applied = doc.get("applied") or {}
    names = list(applied)
    est = np.array([float(applied[n]["estimate"]) for n in names])
    sd = np.array([float(applied[n]["std"]) for n in names])
    corr = np.eye(len(names))
    ac = doc.get("applied_correlation") or {}
    if ac.get("names"):
        m = np.asarray(ac["matrix"], dtype=float)
        pos = {n: i for i, n in enumerate(ac["names"])}
        idx = [pos.get(n) for n in names]
        for a, ia in enumerate(idx):
            for b, ib in enumerate(idx):
                if ia is not None and ib is not None:
                    corr[a, b] = m[ia, ib]
    return names, est, corr * np.outer(sd, sd)


def propagate(fd_raw: FlightData, doc: Mapping[str, Any], results: Mapping[str, Any],
              refit: Callable[[FlightData, dict[str, pd.Series]], Mapping[str, Any]],
              progress: Any = None) -> dict[str, Any]:
    """Set ``consider_cov`` on every result in ``results`` from the applied corrections of
    ``doc`` (module doc). ``fd_raw``: the data as logged; ``refit(fd, starts)`` repeats the
    run's fits on other flight data (``starts``: key -> the run's estimates) and returns
    key -> result. Returns a JSON-ready document: refits, perturbation, per-key status,
    seconds. Nothing applied: an empty document."""
    from pipeline.compatibility import CompatibilityResult

    names, est, C = correction_covariance(doc)
    if not names or not results:
        return {}
    t0 = time.perf_counter()
    sd = np.sqrt(np.diag(C))
    starts = {key: res.params for key, res in results.items()}
    free = {key: list(res.free_names) for key, res in results.items()}
    J = {key: np.zeros((len(free[key]), len(names))) for key in results}
    status: dict[str, str] = {key: "propagated" for key in results}
    if progress is not None:
        progress.stage(f"sensor-correction uncertainty ({len(names)} refits, one per applied correction)")
    for j, n in enumerate(names):
        if not any(v == "propagated" for v in status.values()):
            break                                   # every fit already failed a refit
        if progress is not None and not progress.quiet:
            print(f" {j + 1}/{len(names)}", end="", file=progress.stream, flush=True)
        v = pd.Series(est, index=names)
        v[n] += sd[j]
        fd_j = CompatibilityResult(None, v, pd.Series(sd, index=names)).corrected(fd_raw, keep_times=True)
        try:
            new = refit(fd_j, starts)
        except Exception as exc:  # noqa: BLE001 - a failed refit must not cost the run
            new = {}
            for key in results:
                status[key] = f"not propagated: the refit with {n} + 1 std failed ({type(exc).__name__}: {exc})"
        for key, res in results.items():
            r = new.get(key)
            if not status[key].startswith("propagated"):
                continue
            if r is None or list(r.free_names) != free[key]:
                status[key] = f"not propagated: the refit with {n} + 1 std failed or changed the parameters"
                continue
            J[key][:, j] = (r.params[free[key]].to_numpy(float)
                            - res.params[free[key]].to_numpy(float)) / sd[j]
    for key, res in results.items():
        if status[key] == "propagated":
            res.consider_cov = J[key] @ C @ J[key].T
            res.consider_source = SOURCE
    seconds = time.perf_counter() - t0
    if progress is not None:
        progress.done(f"{sum(s == 'propagated' for s in status.values())} of {len(status)} fits")
    return {"corrections": names, "refits": len(names),
            "perturbation": "each applied correction moved by +1 std (its Cramér-Rao std), "
                            "all fits repeated; total std = sqrt(CRB^2 + consider^2)",
            "methods": status, "seconds": seconds}


def quiet_progress() -> Any:
    """A Progress that prints nothing (notes of the refits included)."""
    from pipeline.run import Progress

    return Progress(1, stream=io.StringIO(), quiet=True)
