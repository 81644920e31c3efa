"""How the uncertainty of what a fit holds as exact reaches its estimates: the sensor
corrections applied before estimation (:func:`propagate`), another fit's estimates
held in the model (:func:`held_estimates`: the 6-DoF lateral output error holds the
longitudinal derivatives) and the wind the air-data angles of a log without vanes were
rebuilt with (:func:`wind`), all by refits (:func:`_refit_jacobians`).

The compatibility stage (:func:`pipeline.conditioning.compatibility.correct_for_estimation`) removes the
significant sensor errors from the data before estimation, with estimates c (k values)
that carry their own Cramér-Rao covariance C. Every estimation method then treats the
corrected data as exact, so its Cramér-Rao bound is conditional on c: an alpha-vane scale
factor known to +-0.5 % moves Cmalpha by about as much, which no fit on the corrected data
can see. This module accounts for it as "consider" parameters (Schmidt):

    J[:, j] = (theta(c + s_j e_j) - theta(c)) / s_j      (s_j: std of c_j; one refit each)
    P_consider = J C J^T                                  (added to the CRB: total std)

Each refit corrects the logged data with c_j moved by one std and repeats the run's fits
exactly (same problems, same methods) through a refit callable the job passes in;
maximum-likelihood and least-squares methods start from the run's estimates
(``Method.start_free`` of :mod:`pipeline.registry`), the EKF/UKF from their usual
start. Output error instead takes one Gauss-Newton step from its estimates with the run's
sensitivities (:meth:`estimators.OutputError.step_from`): the first-order change J needs.
A method whose refit fails or changes its parameter list keeps its CRB alone, and the
document says so.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, MutableMapping
from typing import Any

import numpy as np
import pandas as pd

from pipeline.conditioning.compatibility import CompatibilityResult
from pipeline.conditioning.input_dynamics import covariance
from pipeline.conditioning.input_sampling import with_edges_moved
from pipeline.conditioning.wind_uncertainty import WIND_PARTS, wind_uncertainty
from pipeline.ingest.flightdata import FlightData

SOURCE = "the uncertainty of the sensor corrections applied before the fit"
HELD_SOURCE = "the uncertainty of the other axis' estimates the fit held"
WIND_SOURCE = "the uncertainty of the wind (and the pitot's scale factor) the air-data angles were rebuilt with"
SAMPLING_SOURCE = "the unknown times of the control-input steps between their logged samples"
DYNAMICS_SOURCE = "the uncertainty of the control-input delays and lags applied before the fit"


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
        pos = {n: i for i, n in enumerate(ac["names"])}
        mine = [a for a, n in enumerate(names) if n in pos]  # names the matrix carries
        theirs = [pos[names[a]] for a in mine]
        corr[np.ix_(mine, mine)] = np.asarray(ac["matrix"], dtype=float)[np.ix_(theirs, theirs)]
    return names, est, corr * np.outer(sd, sd)


def _refit_jacobians(
    results: Mapping[str, Any],
    names: list[str],
    step: np.ndarray,
    refit_j: Callable[[int], Mapping[str, Any]],
    what: str,
    progress: Any = None,
) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """(key -> J (n_free, k), key -> "propagated" or why not) with J[:, j] =
    (refit_j(j)[key] - result) / step[j]: ``refit_j(j)`` repeats the fits with the j-th of
    ``names`` moved by ``step[j]``; ``what`` names that move in messages."""
    free = {key: list(res.free_names) for key, res in results.items()}
    J = {key: np.zeros((len(free[key]), len(names))) for key in results}
    status: dict[str, str] = {key: "propagated" for key in results}
    for j, n in enumerate(names):
        if not any(v == "propagated" for v in status.values()):
            break  # every fit already failed a refit
        if progress is not None:
            progress.tick(f"{j + 1}/{len(names)}")
        try:
            new = refit_j(j)
        except Exception as exc:  # noqa: BLE001 - a failed refit must not cost the run
            new = {}
            for key in results:
                status[key] = (
                    f"not propagated: the refit with {what.format(name=n)} failed ({type(exc).__name__}: {exc})"
                )
        for key, res in results.items():
            r = new.get(key)
            if not status[key].startswith("propagated"):
                continue
            if r is None or list(r.free_names) != free[key]:
                status[key] = f"not propagated: the refit with {what.format(name=n)} failed or changed the parameters"
                continue
            J[key][:, j] = (r.params[free[key]].to_numpy(float) - res.params[free[key]].to_numpy(float)) / step[j]
    return J, status


def _add_consider(
    results: MutableMapping[str, Any],
    J: Mapping[str, np.ndarray],
    C: Mapping[str, np.ndarray],
    status: Mapping[str, str],
    source: str,
) -> None:
    """Replace every result whose status is "propagated" by one with J C J^T (C by key)
    added to its consider covariance and ``source`` to what that accounts for."""
    for key, res in list(results.items()):
        if status[key] == "propagated":
            results[key] = res.with_consider(J[key] @ C[key] @ J[key].T, source)


def consider_by_refits(
    results: MutableMapping[str, Any],
    names: list[str],
    C: np.ndarray,
    refit_j: Callable[[int], Mapping[str, Any]],
    what: str,
    source: str,
    progress: Any = None,
) -> dict[str, str]:
    """Add J C J^T to ``consider_cov`` of every result in ``results`` (key -> result), with
    J[:, j] = (refit_j(j)[key] - result) / std_j: ``refit_j(j)`` repeats the fits with the
    j-th of ``names`` (covariance ``C``) moved by its std. ``what`` names the j-th
    perturbation in messages ("{name} + 1 std"); ``source`` is appended to
    ``consider_source``. Returns key -> "propagated" or why not (that result keeps what it
    had)."""
    J, status = _refit_jacobians(results, names, np.sqrt(np.diag(C)), refit_j, what, progress)
    _add_consider(results, J, {key: C for key in results}, status, source)
    return status


def propagate(
    fd_raw: FlightData,
    doc: Mapping[str, Any],
    results: MutableMapping[str, Any],
    refit: Callable[[FlightData, dict[str, Any]], Mapping[str, Any]],
    progress: Any = None,
) -> dict[str, Any]:
    """Add to ``consider_cov`` of every result in ``results`` the part of the applied
    corrections of ``doc`` (module doc). ``fd_raw``: the data as logged; ``refit(fd,
    starts)`` repeats the run's fits on other flight data (``starts``: key -> the run's
    result, its estimates the start) and returns key -> result. Returns a JSON-ready document: refits,
    perturbation, per-key status, seconds. Nothing applied: an empty document."""
    names, est, C = correction_covariance(doc)
    if not names or not results:
        return {}
    t0 = time.perf_counter()
    sd = pd.Series(np.sqrt(np.diag(C)), index=names)
    starts = dict(results)

    def refit_j(j: int) -> Mapping[str, Any]:
        v = pd.Series(est, index=names)
        v.iloc[j] += sd.iloc[j]
        return refit(CompatibilityResult(None, v, sd).corrected(fd_raw, keep_times=True), starts)

    status = consider_by_refits(results, names, C, refit_j, "{name} + 1 std", SOURCE, progress)
    return {
        "corrections": names,
        "refits": len(names),
        "perturbation": "each applied correction moved by +1 std (its Cramér-Rao std), "
        "all fits repeated; total std = sqrt(CRB^2 + consider^2)",
        "methods": status,
        "seconds": time.perf_counter() - t0,
    }


def fitted_spans(result: Any) -> list[tuple[float, float]]:
    """The (start, end) times [s] of the segments a fit used (its residuals' time spans)."""
    return [(float(r.index[0]), float(r.index[-1])) for r in result.residuals if len(r)]


def wind(
    flow: Mapping[str, Any],
    results: MutableMapping[str, Any],
    refit: Callable[[tuple[float, float, float]], Mapping[str, Any]],
    progress: Any = None,
) -> dict[str, Any]:
    """Add to ``consider_cov`` of every result in ``results`` the uncertainty of the wind
    its air-data angles were rebuilt with (``flow``, the document of
    :func:`pipeline.conditioning.flow_angles.reconstruct_flow_angles`): the fitted horizontal wind and
    the mean vertical wind the reconstruction takes as zero, by key over the segments that
    fit used (:func:`fitted_spans`, :func:`pipeline.conditioning.flow_angles.wind_uncertainty`). Each
    part is moved by its largest std over the keys and ``refit(offset)`` (offset (north,
    east, down) [m/s] added to the wind) repeats the fits; each key then gets J C_key J^T.
    Returns a JSON-ready document (empty when no angle was rebuilt or no part is
    uncertain)."""
    per = {key: wind_uncertainty(flow, fitted_spans(res)) for key, res in results.items()}
    if not results or not any(per.values()):
        return {}
    t0 = time.perf_counter()
    top = {n: max(p[n] for p in per.values()) for n in WIND_PARTS}
    names = [n for n in WIND_PARTS if top[n] > 0.0]
    if not names:
        return {}
    step = np.array([top[n] for n in names])

    def refit_j(j: int) -> Mapping[str, Any]:
        offset = [0.0] * len(WIND_PARTS)
        offset[WIND_PARTS.index(names[j])] = float(step[j])
        return refit(tuple(offset))

    J, status = _refit_jacobians(results, names, step, refit_j, "the {name} moved by its std", progress)
    _add_consider(results, J, {key: np.diag([per[key][n] ** 2 for n in names]) for key in results}, status, WIND_SOURCE)
    speed = [n for n in names if n != "airspeed scale"]
    return {
        "parts": names,
        "refits": len(names),
        "std_mps": {key: {n: per[key][n] for n in speed} for key in results},
        **(
            {"std_airspeed_scale": {key: per[key]["airspeed scale"] for key in results}}
            if "airspeed scale" in names
            else {}
        ),
        "perturbation": "each part of the wind moved by its std (the largest over the "
        "fits), the angles rebuilt and all fits repeated; total std = "
        "sqrt(CRB^2 + consider^2)",
        "methods": status,
        "seconds": time.perf_counter() - t0,
    }


def wind_summary(doc: Mapping[str, Any]) -> str:
    """One line for report.md from the document of :func:`wind`."""
    if not doc:
        return "nothing carried"
    stds = doc["std_mps"]
    parts = []
    for n in doc["parts"]:
        if n == "airspeed scale":  # one value for the flight
            parts.append(f"airspeed scale factor +-{100 * max(doc['std_airspeed_scale'].values()):.2f} %")
            continue
        lo, hi = min(v[n] for v in stds.values()), max(v[n] for v in stds.values())
        what = "flight-mean vertical wind (assumed 0)" if n == "vertical wind" else n
        parts.append(f"{what} +-{lo:.2f}" + (f" to {hi:.2f}" if hi - lo >= 0.005 else "") + " m/s")
    bad = {k: v for k, v in doc["methods"].items() if v != "propagated"}
    return (
        ", ".join(parts)
        + ": carried to the estimates' std as a consider part"
        + (f" (except {'; '.join(f'{k}: {v}' for k, v in bad.items())})" if bad else "")
    )


def held_estimates(
    results: MutableMapping[str, Any],
    key: str,
    held: Any,
    refit: Callable[[dict[str, float]], Any],
    progress: Any = None,
) -> dict[str, Any]:
    """Add to the consider covariance of ``results[key]`` the uncertainty of another fit's
    estimates it held fixed (``held``: that fit's result, e.g. the longitudinal output error whose
    derivatives the 6-DoF lateral fit holds): each held estimate with a Cramér-Rao std is
    moved by one std and ``refit(values)`` (the held values -> the refit result) repeats
    the fit. Returns a JSON-ready document."""
    t0 = time.perf_counter()
    names = [n for n in held.free_names if "[" not in n and np.isfinite(held.std[n])]
    idx = [held.free_names.index(n) for n in names]
    C = np.asarray(held.cov, dtype=float)[np.ix_(idx, idx)]
    base = {n: float(v) for n, v in held.params.items() if "[" not in n}
    sd = np.sqrt(np.diag(C))

    def refit_j(j: int) -> Mapping[str, Any]:
        return {"r": refit({**base, names[j]: base[names[j]] + sd[j]})}

    one = {"r": results[key]}
    status = consider_by_refits(one, names, C, refit_j, "the held {name} + 1 std", HELD_SOURCE, progress)["r"]
    results[key] = one["r"]
    return {"held": names, "refits": len(names), "status": status, "seconds": time.perf_counter() - t0}


def input_dynamics(
    doc: Mapping[str, Any],
    results: MutableMapping[str, Any],
    refit: Callable[[dict[str, dict[str, float]]], Mapping[str, Any]],
    progress: Any = None,
) -> dict[str, Any]:
    """Add to ``consider_cov`` of every result in ``results`` the uncertainty of the
    control-input dynamics applied before the fits (``doc``: the document of
    :func:`pipeline.conditioning.input_dynamics.estimate_input_dynamics`; each applied surface's delay
    and lag with their Morelli-Klein covariance, :func:`pipeline.conditioning.input_dynamics.covariance`):
    ``refit(dynamics)`` (surface -> {"delay_s", "lag_s"}) repeats the fits with one of
    them moved by its std. Returns a JSON-ready document (empty when nothing was applied)."""
    names, C, where = covariance(doc)
    if not names or not results:
        return {}
    t0 = time.perf_counter()
    applied = {s: dict(v) for s, v in doc["applied"].items()}
    sd = np.sqrt(np.diag(C))

    def refit_j(j: int) -> Mapping[str, Any]:
        s, key = where[names[j]]
        moved = {k: dict(v) for k, v in applied.items()}
        moved[s][key] = moved[s][key] + float(sd[j])
        return refit(moved)

    status = consider_by_refits(results, names, C, refit_j, "the {name} + 1 std", DYNAMICS_SOURCE, progress)
    return {
        "parameters": names,
        "refits": len(names),
        "perturbation": "each applied delay and lag moved by +1 std (Morelli-Klein), all "
        "fits repeated; total std = sqrt(CRB^2 + consider^2)",
        "methods": status,
        "seconds": time.perf_counter() - t0,
    }


#: the most refit pairs the step-timing part takes: more steps are moved in this many
#: groups, each step of a group by its std with a random sign (the variance then known to
#: about sqrt(2 / 12) = 41 %; a refit pair each, on logs where a refit takes seconds)
MAX_STEP_GROUPS = 12


def fitted_steps(steps: list, results: Mapping[str, Any]) -> list:
    """The control-input steps (:class:`pipeline.conditioning.input_sampling.Edge`) in a window some fit
    of ``results`` used."""
    spans = [s for res in results.values() for s in fitted_spans(res)]
    return [e for e in steps if any(e.t1 > a and e.t0 < b for a, b in spans)]


def input_sampling(
    fd: FlightData,
    results: MutableMapping[str, Any],
    refit: Callable[[FlightData], Mapping[str, Any]],
    steps: list,
    progress: Any = None,
) -> dict[str, Any]:
    """Add to ``consider_cov`` of every result in ``results`` the uncertainty of the times
    of the control-input steps logged more slowly than the fits' grid (``steps``: the
    :class:`pipeline.conditioning.input_sampling.Edge` list of :func:`pipeline.conditioning.input_sampling.time_steps`,
    as they are in ``fd``, the data before the input dynamics): each step ``j`` in a
    fitted window, time std s_j (timed from the gyros, else h_j / sqrt(12) of its sample
    interval h_j), is moved by +s_j and by -s_j and ``refit(data)`` repeats the fits; the
    central difference gives J's column, C = I (the steps' times independent, in units of
    their std). The part of a timed step's std that comes from its kink model
    (``Edge.form_std``, systematic: the model's misfit is alike for every step of a
    surface) is moved for all of a surface's steps at once, one more column per surface;
    s_j is then the rest. More than
    MAX_STEP_GROUPS steps: that many groups, every step of a group moved at once with a
    random sign (fixed seed), which estimates J J^T without bias (the groups' cross terms
    have mean zero). Returns a JSON-ready document (empty when no input is slow or has no
    step in a fitted window)."""
    edges = fitted_steps(steps, results)
    if not edges:
        return {}
    t0 = time.perf_counter()
    m = len(edges)
    n_groups = min(m, MAX_STEP_GROUPS)
    signs = np.ones(m) if n_groups == m else np.random.default_rng(0).choice([-1.0, 1.0], m)
    group = np.arange(m) % n_groups
    form = np.array([e.form_std for e in edges])
    own = np.sqrt(np.maximum(np.array([e.std for e in edges]) ** 2 - form**2, 0.0))
    shared = sorted({e.channel for e, f in zip(edges, form) if f > 0})
    names = [edges[g].name if n_groups == m else f"step group {g + 1} of {n_groups}" for g in range(n_groups)] + [
        f"{c} steps' shared timing" for c in shared
    ]

    def moved(sign: float):
        def refit_j(j: int) -> Mapping[str, Any]:
            if j < n_groups:  # steps on their own
                mine = group == j
                return refit(
                    with_edges_moved(fd, [e for e, k in zip(edges, mine) if k], list(sign * signs[mine] * own[mine]))
                )
            mine = [
                k
                for k, e in enumerate(edges)  # a surface's steps together
                if e.channel == shared[j - n_groups] and form[k] > 0
            ]
            return refit(with_edges_moved(fd, [edges[k] for k in mine], list(sign * form[mine])))

        return refit_j

    n = len(names)
    Jp, sp = _refit_jacobians(results, names, np.ones(n), moved(1.0), "the {name} moved later by its std", progress)
    Jm, sm = _refit_jacobians(results, names, -np.ones(n), moved(-1.0), "the {name} moved earlier by its std", progress)
    status = {key: sp[key] if sp[key] != "propagated" else sm[key] for key in results}
    J = {key: 0.5 * (Jp[key] + Jm[key]) for key in results}
    _add_consider(results, J, {key: np.eye(n) for key in results}, status, SAMPLING_SOURCE)
    chans = sorted({e.channel for e in edges})
    return {
        "steps": m,
        "channels": {
            c: {
                "steps": sum(e.channel == c for e in edges),
                "timed": sum(e.channel == c and e.time_std is not None for e in edges),
                "time_std_s": float(np.sqrt(np.mean([e.std**2 for e in edges if e.channel == c]))),
            }
            for c in chans
        },
        "groups": n_groups,
        "shared": shared,
        "refits": 2 * n,
        "perturbation": (
            "each step moved by +1 and -1 std of its time (timed from the "
            "gyros, else h / sqrt(12) of its sample interval h), all fits "
            "repeated, the central difference; "
            + ("" if n_groups == m else f"{m} steps in {n_groups} groups moved with random signs; ")
            + (
                "the part of a timed step's std from its kink model moved with the surface's other steps at once; "
                if shared
                else ""
            )
            + "total std = sqrt(CRB^2 + consider^2)"
        ),
        "methods": status,
        "seconds": time.perf_counter() - t0,
    }
