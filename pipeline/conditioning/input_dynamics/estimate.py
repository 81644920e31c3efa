"""The equation-error estimate of each control input's delay and lag, with its std, and
which of them are applied (the method: :mod:`pipeline.conditioning.input_dynamics`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from estimators.covariance.uncertainty import morelli_klein
from pipeline.conditioning.input_dynamics.refinement import REFINE_METHOD
from pipeline.conditioning.input_dynamics.regression import (
    AT_END_S,
    DELAY_RANGE_S,
    LAG_RANGE_S,
    MAX_EVALUATIONS,
    Maneuvers,
    grid_start,
    jackknife,
    joint,
    moment_regressors,
)
from pipeline.conditioning.input_smoothing import control_input_corners
from pipeline.ingest.flightdata import CONTROL_INPUTS, FlightData

#: the rate each control input's moment equation is regressed on
AXIS_RATE = {"de": "q", "da": "p", "dr": "r"}
#: |equivalent delay| / std from which a surface's dynamics are applied
SIGNIFICANT = 3.0
#: the smallest equivalent delay applied [s]: one 100 Hz sample. Below it a shift is
#: within the logs' time-stamp resolution and the equation's own bias; servo lags are
#: 20-100 ms
MIN_APPLIED_S = 0.01
#: highest rate of the regression grid [Hz]
MAX_RATE_HZ = 100.0
#: lowest gyro rate the delays are estimated from [Hz]: a 10-50 ms delay is a fraction of
#: a sample below it; a step between slow samples is timed from the kink the surface's
#: motion puts in the gyros instead (pipeline.conditioning.input_sampling)
MIN_RATE_HZ = 40.0
#: why the aileron's and rudder's dynamics are not estimated without a sideslip angle
LATERAL_NEEDS = (
    "needs the sideslip angle (a vane, or rebuilt from the flight path): with "
    "the lateral accelerometer instead the rudder's 50 ms lag came out 187 ms "
    "(the default scenario, ad hoc)"
)


def estimate_input_dynamics(fd: FlightData, *, surfaces: Sequence[str] = CONTROL_INPUTS) -> dict[str, Any]:
    """The delay and lag of each control input with maneuvers in ``fd`` (module doc).
    Returns a JSON-ready document: ``surfaces`` (name -> delay_s, lag_s, their std
    (delay_std, lag_std: Morelli-Klein widened to the jackknife; std_from says which)
    and correlation, equivalent_delay_s (d + tau) and equivalent_std, crb_std and mk_std
    of both, response (the rate whose derivative was regressed), maneuvers, samples,
    rate_hz, at_bound, significant, applied), ``applied`` (name -> {"delay_s", "lag_s"}),
    ``covariance`` (names "<surface> delay|lag" and the joint matrix), ``converged``,
    ``smoothed_hz`` (the regressors low-passed at their noise floor), ``method``,
    ``regressors``, and ``not_estimated`` (name -> why) for surfaces without maneuvers,
    gyro or sideslip."""
    doc: dict[str, Any] = {
        "method": (
            "equation error of the rate derivatives, all surfaces and axes at once; "
            f"delays {DELAY_RANGE_S[0] * 1e3:g}..{DELAY_RANGE_S[1] * 1e3:g} ms, first-order "
            f"lags {LAG_RANGE_S[0] * 1e3:g}..{LAG_RANGE_S[1] * 1e3:g} ms; Morelli-Klein std, "
            "widened to the maneuvers' jackknife"
        ),
        "surfaces": {},
        "applied": {},
        "not_estimated": {},
    }
    regs = moment_regressors(fd)
    doc["regressors"] = regs
    present = [s for s in surfaces if s in fd and len(fd[s]) > 1]
    # noisy measured variables are low-passed where their white noise floor begins: the
    # noise of a regressor biases least squares (errors in variables)
    corners = control_input_corners(fd, [c for c in (*regs, *present) if c not in AXIS_RATE.values()])
    doc["smoothed_hz"] = corners
    axes = _equations(fd, present, regs, corners, doc["not_estimated"])
    if not axes:
        return doc
    # start: each equation's best with all its surfaces at one (delay, lag) (a grid
    # profile); then every surface's own pair over every equation at once
    start: dict[str, tuple[float, float]] = {s: (0.0, 0.0) for s in present}
    for s, m in axes.items():
        start[s] = grid_start(m)
    dyn, weights, S, v, converged = joint(axes, start)
    doc["converged"] = converged
    unc = morelli_klein(S, v)
    crb = np.sqrt(np.clip(np.diag(unc.crb_cov), 0.0, None))
    mk_all = np.sqrt(np.clip(np.diag(unc.cov), 0.0, None))
    widen = np.ones(mk_all.size)
    jk = jackknife(axes, dyn, weights)
    if jk is not None:
        spread = np.sqrt(np.clip(np.diag(jk), 0.0, None))
        ok = mk_all > 1e-9  # (a lag at 0 has no std of its own)
        widen = np.where(ok, np.maximum(1.0, spread / np.where(ok, mk_all, 1.0)), 1.0)
    cov = unc.cov * np.outer(widen, widen)
    doc["covariance"] = {"names": [f"{s} {k}" for s in axes for k in ("delay", "lag")], "matrix": cov.tolist()}
    for i, s in enumerate(axes):
        k = slice(2 * i, 2 * i + 2)
        doc["surfaces"][s] = _surface(s, axes[s], dyn[s], cov[k, k], crb[k], mk_all[k], widen[k], converged)
        if doc["surfaces"][s]["applied"]:
            doc["applied"][s] = {"delay_s": dyn[s][0], "lag_s": dyn[s][1]}
    return doc


def _equations(
    fd: FlightData,
    present: Sequence[str],
    regs: Sequence[str],
    corners: Mapping[str, float],
    not_estimated: dict[str, str],
) -> dict[str, Maneuvers]:
    """Surface -> the maneuvers of its axis's moment equation, for each surface of
    ``present`` that can be estimated (else why not, into ``not_estimated``)."""
    axes: dict[str, Maneuvers] = {}
    for s in present:
        rate = AXIS_RATE[s]
        # its own maneuvers, and spans given without an axis (user or mode segments)
        spans = [(sg.t0, sg.t1) for sg in fd.segments if sg.axis in (s, None)]
        if rate not in fd:
            not_estimated[s] = f"no {rate} gyro channel"
            continue
        if s in ("da", "dr") and "beta" not in fd:
            not_estimated[s] = LATERAL_NEEDS
            continue
        if fd[rate].rate_hz < MIN_RATE_HZ:
            not_estimated[s] = (
                f"needs the {rate} gyro at >= {MIN_RATE_HZ:g} Hz, the log has "
                f"it at {fd[rate].rate_hz:.3g} Hz: a servo's 10-50 ms are a "
                "fraction of its sample interval (telemetry? use the onboard "
                "log; else log the IMU faster)"
            )
            continue
        if not spans:
            not_estimated[s] = "no maneuver on it"
            continue
        m = Maneuvers(
            fd,
            spans,
            rate,
            [r for r in regs if r != rate] + [rate],
            present,
            float(min(fd[rate].rate_hz, MAX_RATE_HZ)),
            corners,
        )
        if len(m) == 0:
            not_estimated[s] = "its maneuvers lack samples of the needed channels"
            continue
        axes[s] = m
    return axes


def _surface(
    s: str,
    m: Maneuvers,
    dyn: tuple[float, float],
    C: np.ndarray,
    crb: np.ndarray,
    mk: np.ndarray,
    widen: np.ndarray,
    converged: bool,
) -> dict[str, Any]:
    """The document of surface ``s``: its (delay, lag) [s] ``dyn`` with their covariance
    ``C`` (2, 2), Cramér-Rao and Morelli-Klein std (2,), the jackknife's widening (2,),
    whether it is significant and applied."""
    d, tau = dyn
    sd, sl = np.sqrt(np.clip(np.diag(C), 0.0, None))
    eq, eq_sd = d + tau, float(np.sqrt(max(C.sum(), 0.0)))
    inside = DELAY_RANGE_S[0] + AT_END_S < d < DELAY_RANGE_S[1] - AT_END_S and tau < LAG_RANGE_S[1] - AT_END_S
    significant = bool(converged and inside and np.isfinite(eq_sd) and eq_sd > 0 and abs(eq) >= SIGNIFICANT * eq_sd)
    applied = significant and eq >= MIN_APPLIED_S
    return {
        "delay_s": d,
        "delay_std": float(sd),
        "lag_s": tau,
        "lag_std": float(sl),
        "corr": float(C[0, 1] / (sd * sl)) if sd > 0 and sl > 0 else None,
        "equivalent_delay_s": eq,
        "equivalent_std": eq_sd,
        "crb_std": [float(crb[0]), float(crb[1])],
        "mk_std": [float(x) for x in mk],
        "std_from": ("jackknife over maneuvers" if np.any(widen > 1.0) else "Morelli-Klein"),
        "response": f"d{AXIS_RATE[s]}/dt",
        "maneuvers": len(m),
        "samples": int(sum(t.size for t in m.t)),
        "rate_hz": 1.0 / m.h,
        "at_bound": not inside,
        "significant": significant,
        "applied": bool(applied),
    }


def covariance(doc: Mapping[str, Any]) -> tuple[list[str], np.ndarray, dict[str, tuple[str, str]]]:
    """(names, covariance, name -> (surface, "delay_s" | "lag_s")) of the applied
    dynamics of ``doc``: each applied surface's delay and lag with their joint covariance
    (``doc["covariance"]``; a value without a std - a lag at its bound 0 - left out)."""
    given = doc.get("covariance") or {"names": [], "matrix": []}
    pos = {n: k for k, n in enumerate(given["names"])}
    full = np.asarray(given["matrix"], dtype=float)
    names, where = [], {}
    for s in doc.get("applied") or {}:
        for key in ("delay_s", "lag_s"):
            name = f"{s} {key[:-2]}"
            if name in pos and full[pos[name], pos[name]] > 0:
                names.append(name)
                where[name] = (s, key)
    if not names:
        return [], np.zeros((0, 0)), {}
    idx = [pos[n] for n in names]
    return names, full[np.ix_(idx, idx)], where


def summary(doc: Mapping[str, Any]) -> str:
    """One line for report.md from the document of :func:`estimate_input_dynamics` or of
    the run's stage (skipped, given, failed)."""
    status = doc.get("status", "estimated")
    if status == "skipped":
        return f"not estimated: {doc.get('reason', 'skipped')}"
    if status == "failed":
        return f"estimate failed ({doc.get('reason', '')}); inputs as logged"
    if status == "given":
        return (
            ", ".join(
                f"{s} delay {v['delay_s'] * 1e3:+.1f} ms, lag {v['lag_s'] * 1e3:.1f} ms"
                for s, v in doc["applied"].items()
            )
            + " (given)"
        )
    parts = []
    for s, d in (doc.get("surfaces") or {}).items():
        state = (
            "applied"
            if d["applied"]
            else "withdrawn: " + d["withdrawn"]
            if d.get("withdrawn")
            else "at the search bound, not applied"
            if d["at_bound"]
            else "the log lagging its surface, not applied"
            if d["significant"] and d["equivalent_delay_s"] < 0
            else f"below {MIN_APPLIED_S * 1e3:g} ms, not applied"
            if d["significant"]
            else "not significant"
        )
        ref = d.get("refined") or {}
        if ref:  # (a surface no output-error fit sees keeps equation error's values)
            apart = [k for k in ("delay", "lag") if ref.get(f"{k}_widened")]
            state = (
                f"{REFINE_METHOD}; equation error {d['delay_s'] * 1e3:+.1f} and "
                f"{d['lag_s'] * 1e3:.1f} ms"
                + (f", the two apart on the {' and '.join(apart)}: std widened to the difference" if apart else "")
                + f"; {state}"
            )
        v = {k: ref[k] if ref.get(k) is not None else d[k] for k in ("delay_s", "delay_std", "lag_s", "lag_std")}
        parts.append(
            f"{s} delay {v['delay_s'] * 1e3:+.1f} +- {v['delay_std'] * 1e3:.1f} ms, lag "
            f"{v['lag_s'] * 1e3:.1f} +- {v['lag_std'] * 1e3:.1f} ms ({state})"
        )
    parts += [f"{s}: {why}" for s, why in (doc.get("not_estimated") or {}).items()]
    line = "; ".join(parts) or "no control input with maneuvers"
    if not doc.get("converged", True):
        line += (
            f"; the least squares did not converge in {MAX_EVALUATIONS} evaluations (strong gusts?): nothing applied"
        )
    refinement = doc.get("refined") or {}
    if refinement.get("status") == "not refined":
        line += f"; not refined by {REFINE_METHOD} ({refinement.get('reason', '')})"
    unc = doc.get("uncertainty") or {}
    if unc:
        bad = {k: v for k, v in unc["methods"].items() if v != "propagated"}
        line += "; their std carried to the estimates' std as a consider part" + (
            f" (except {'; '.join(f'{k}: {v}' for k, v in bad.items())})" if bad else ""
        )
    return line
