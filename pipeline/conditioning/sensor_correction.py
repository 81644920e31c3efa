"""The compatibility stage of a run: which of the sensor errors the reconstruction
(:mod:`pipeline.conditioning.compatibility`) estimates are removed from the data that
estimation sees, by a significance rule, and the document that says what was done."""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence

import numpy as np

from estimators.errors import EstimationError
from pipeline.conditioning.compatibility import CompatibilityResult, reconstruct
from pipeline.conditioning.flight_path_model import AIR_PARAMS, IMU_PARAMS, UNITS
from pipeline.errors import FsidError
from pipeline.ingest.flightdata import FlightData

#: what the main run estimates: every IMU bias and scale factor and every air-data error
#: (without the IMU scale factors, an accelerometer's scale factor is booked on its bias)
RUN_ESTIMATE = tuple(IMU_PARAMS + AIR_PARAMS)
#: a sensor error is applied to the data only when |estimate| >= SIGNIFICANCE * std
SIGNIFICANCE = 3.0
#: ... and only when no air-data output's residual std exceeds ADEQUACY x its noise std
#: (:func:`residual_to_noise`): otherwise the calm-air kinematic model does not explain the
#: air data (turbulence, wind) and books the gusts on the sensor errors
ADEQUACY = 1.5


def correct_for_estimation(
    fd: FlightData,
    *,
    imu_position: Sequence[float] = (0.0, 0.0, 0.0),
    boom_position: Sequence[float] = (0.0, 0.0, 0.0),
    estimate: Sequence[str] = RUN_ESTIMATE,
    threshold: float = SIGNIFICANCE,
    truth: Mapping[str, float] | None = None,
    wind: tuple[float, float] | None = None,
    unsteady: str | None = None,
    **kw,
) -> tuple[dict, FlightData]:
    """The compatibility stage of a run: estimate the sensor errors, correct the data that
    estimation will see by the significant ones, and say exactly what was done.

    Rule (what a flight-test engineer does with a compatibility check):

    1. Reconstruct with every sensor error of ``estimate`` free (default: all IMU biases
       and scale factors, air-data biases, scale factors and delay).
    2. A sensor error counts as present when ``|estimate| >= threshold * std`` (default 3;
       std the Cramér-Rao bound with the IMU noise carried through the kinematics,
       :func:`pipeline.conditioning.compatibility._carry_imu_noise`): an estimate
       indistinguishable from zero is not applied, since applying it would only add its
       estimation noise to the data. None is applied when the fit does not explain the air
       data: an air-data output (V, alpha, beta) with residuals above ``ADEQUACY`` (1.5)
       times its noise level (turbulence or wind, which the calm-air kinematic model
       lacks, would otherwise be booked as sensor errors).
    3. When some are present, reconstruct again with only those free and the others held
       at zero, so that correlated errors take up what the held ones carried (over the
       narrow airspeed range of a flight, bias_V and scale_V are nearly one parameter: with
       bias_V held, scale_V carries the whole airspeed error), and apply that refit's
       estimates: IMU (x - bias) / (1 + scale), air data likewise and read ``delay_air``
       earlier on their own sample times (``CompatibilityResult.corrected(keep_times=True)``).
    4. Nothing present, the fit not converged, or the stage impossible (no forward flight,
       missing channels): the data go to estimation as logged, and the document says why.

    A steady wind is estimated with the sensor errors and kept when significant (the same
    rule), else the fit in calm air is used. The flat-Earth model lacks the Coriolis force
    of a rotating Earth, which a real IMU feels: an applied ``bias_ay`` can stand in for it.

    ``wind`` (north, east) m/s: held instead of estimated (a log without vanes: the air-data-
    angle stage's wind). ``unsteady``: why the air is known not to be steady (the airspeed
    off a steady-wind fit: gusts no air-data residual shows without vanes); then nothing is
    applied, and the significant errors are listed under ``not_applied``.

    Returns (JSON-ready document, flight data for estimation). The document is the full
    fit's ``to_dict`` (every estimate with std, and truth / error_std when ``truth``, in
    this module's parameter names, is given) plus ``applied`` (name -> value removed from
    the data, with its std and the full fit's significance), ``refit`` (the second fit's
    parameters), ``rule``, ``data_for_estimation`` and ``seconds``.
    """
    t0 = time.perf_counter()
    rule = (
        f"a sensor error is applied when |estimate| >= {threshold:g} std in the fit with all "
        f"errors free and that fit leaves the air-data residuals within {ADEQUACY:g} x their "
        "noise level; the applied values come from a refit with only those free"
    )
    kw = {"imu_position": imu_position, "boom_position": boom_position, **kw}
    doc, full = _full_fit(fd, estimate, threshold, wind, kw)
    doc["rule"] = rule
    doc["applied"] = {}
    doc["data_for_estimation"] = "as logged"
    if doc.get("status") != "ok":
        if doc.get("status") == "not converged":
            doc["note"] = "reconstruction did not converge: no correction applied"
        doc["seconds"] = time.perf_counter() - t0
        return doc, fd
    if truth is not None:  # the parameter table with the injected values
        for n, row in doc["parameters"].items():
            tv = truth.get(n)
            row["truth"] = None if tv is None else float(tv)
            row["error_std"] = None if tv is None or not row.get("std") else (row["estimate"] - float(tv)) / row["std"]
    sig = _significant(doc["parameters"], threshold)
    untrusted = _untrusted(doc, full, sig, unsteady)
    if untrusted:
        sig = {}
    for n, row in doc["parameters"].items():
        row["applied"] = n in sig
    if untrusted:
        doc["seconds"] = time.perf_counter() - t0
        return doc, fd
    if not sig:
        doc["note"] = f"no sensor error distinguishable from zero (all |estimate| < {threshold:g} std)"
        doc["seconds"] = time.perf_counter() - t0
        return doc, fd
    out = _refit_and_apply(fd, doc, sig, truth, kw)
    doc["seconds"] = time.perf_counter() - t0
    return doc, out


def _significant(parameters: Mapping[str, Mapping], threshold: float) -> dict[str, float]:
    """Name -> |estimate| / std of the parameters at least ``threshold`` std from zero."""
    return {
        n: abs(row["estimate"]) / row["std"]
        for n, row in parameters.items()
        if row.get("std")
        and np.isfinite(row["std"])
        and row["std"] > 0
        and abs(row["estimate"]) >= threshold * row["std"]
    }


def _full_fit(
    fd: FlightData, estimate: Sequence[str], threshold: float, wind: tuple[float, float] | None, kw: dict
) -> tuple[dict, CompatibilityResult | None]:
    """The reconstruction with every error of ``estimate`` free, with the steady wind
    ``wind`` held, or estimated and kept when some component is ``threshold`` std from
    zero (else the calm-air fit): (its document with ``wind_note``, the result). ``kw``,
    the reconstruction's options, gets the wind the refit is to use."""
    # a steady wind is estimated first; indistinguishable from calm (every component within
    # ``threshold`` std of zero), the calm-air fit is used: the same rule as the sensor errors.
    # A wind given (the air-data-angle stage's, for a log without vanes, where the cross wind
    # of a straight flight is unobservable here) is held
    held = tuple(wind) if wind is not None else None
    doc, full = _reconstruct_or_reason(fd, estimate=list(estimate), wind=held or True, **kw)
    wind = (full.settings.get("wind_mps") or {}) if full is not None else {}
    sig_wind = {n: round(v / s, 1) for n, (v, s) in wind.items() if s and np.isfinite(s) and abs(v) >= threshold * s}
    said = ", ".join(
        f"{'north' if n == 'wind_n' else 'east'} {v:.2f} +- {s:.2f} m/s" for n, (v, s) in wind.items() if s is not None
    )
    if held:
        kw["wind"] = held
        doc["wind_note"] = f"wind held at north {held[0]:.2f}, east {held[1]:.2f} m/s (the air-data-angle stage's)"
    elif full is not None and not sig_wind:
        doc, full = _reconstruct_or_reason(fd, estimate=list(estimate), **kw)
        doc["wind_note"] = f"wind {said}: within {threshold:g} std of zero, calm air assumed"
    elif full is not None:
        kw["wind"] = True
        doc["wind_note"] = f"steady wind estimated with the sensor errors: {said}"
    return doc, full


def _untrusted(doc: dict, full: CompatibilityResult, sig: Mapping[str, float], unsteady: str | None) -> str | None:
    """Why the full fit's estimates are not trusted (its air-data residuals above
    ADEQUACY x their noise, or the air known to be unsteady while some error is
    significant ``sig``), or None; an untrusted fit's std are withdrawn in ``doc``."""
    ratio = residual_to_noise(full)
    doc["residual_to_noise"] = ratio
    poor = {c: round(x, 2) for c, x in ratio.items() if c in ("V", "alpha", "beta") and x > ADEQUACY}
    untrusted = None
    if poor:
        untrusted = (
            f"air-data residuals {poor} times their noise level (> {ADEQUACY:g}): the "
            "calm-air kinematic model does not explain the air data (turbulence or wind?)"
        )
    elif unsteady and sig:
        # the kinematic model has no gusts, and without vanes no air-data residual shows them
        doc["not_applied"] = {
            n: {
                "estimate": doc["parameters"][n]["estimate"],
                "std": doc["parameters"][n]["std"],
                "significance_std": float(x),
            }
            for n, x in sig.items()
        }
        untrusted = f"{unsteady}; the calm-air kinematic model does not hold"
    if untrusted:
        doc["note"] = f"no correction applied: {untrusted}, so its sensor-error estimates are not trusted"
        # nor their std: the residuals carry what the model lacks, not white noise, and the
        # Cramér-Rao bound (and significance) of such a fit understates the errors many times
        for row in doc["parameters"].values():
            row["std_withdrawn"] = row.get("std")
            row["std"] = None
            row["error_std"] = None
        doc["std_note"] = (
            "no std: the fit does not explain the data (" + untrusted + "), so its "
            "Cramér-Rao bound does not hold; std_withdrawn keeps it for reference"
        )
    return untrusted


def _refit_and_apply(
    fd: FlightData, doc: dict, sig: Mapping[str, float], truth: Mapping[str, float] | None, kw: dict
) -> FlightData:
    """The refit with only the significant errors ``sig`` free; its estimates removed from
    ``fd`` and recorded in ``doc`` (``refit``, ``applied``, ``applied_correlation``). A
    refit that fails or does not converge applies nothing and says so."""
    try:
        refit = reconstruct(fd, estimate=list(sig), **kw)
    except Exception as exc:  # noqa: BLE001 - a failed refit must not cost the run
        doc["note"] = f"refit with the significant errors failed ({type(exc).__name__}: {exc}): no correction applied"
        return fd
    if not getattr(refit.result, "converged", False):
        doc["note"] = "refit with the significant errors did not converge: no correction applied"
        return fd
    doc["refit"] = {
        k: v for k, v in refit.to_dict(truth).items() if k in ("status", "parameters", "iterations", "cost")
    }
    # the refit holds the insignificant errors at 0, which the data know only to within the
    # full fit's std: considered so, the refit's covariance is the full fit's (Schur
    # complement), so its estimates are reported with the larger of the two std
    for n, row in doc["refit"]["parameters"].items():
        full_sd = (doc["parameters"].get(n) or {}).get("std")
        if row.get("std") is not None and full_sd is not None and full_sd > row["std"]:
            row["std_held_exact"] = row["std"]
            row["std"] = float(full_sd)
            if row.get("truth") is not None:
                row["error_std"] = (row["estimate"] - row["truth"]) / row["std"]
    doc["refit"]["std_note"] = (
        "std: the others held at 0 only as well as the full fit knows them (its std); std_held_exact takes them as exactly 0"
    )
    doc["applied"] = {
        n: {
            "estimate": float(refit.params[n]),
            "std": float(refit.std[n]),
            "unit": UNITS.get(n, ""),
            "significance_std": float(sig[n]),
        }
        for n in refit.params.index
    }
    doc["applied_correlation"] = applied_correlation(refit)
    doc["data_for_estimation"] = "compatibility-corrected"
    return refit.corrected(fd, keep_times=True)


def applied_correlation(res: CompatibilityResult) -> dict:
    """Correlation matrix of a reconstruction's sensor-error estimates (JSON-ready:
    ``names``, ``matrix``), from its fit's covariance (with the IMU noise carried,
    :func:`pipeline.conditioning.compatibility._carry_imu_noise`, when it could be); the identity for names the fit does not
    carry."""
    names = list(res.params.index)
    corr = getattr(res.result, "corr", None)
    m = np.eye(len(names))
    if corr is not None:
        have = [n for n in names if n in corr.index]
        idx = [names.index(n) for n in have]
        sub = corr.loc[have, have].to_numpy(dtype=float)
        m[np.ix_(idx, idx)] = np.where(np.isfinite(sub), sub, np.eye(len(have)))
    return {"names": names, "matrix": m.tolist()}


def residual_to_noise(res: CompatibilityResult) -> dict[str, float]:
    """Per output: std of the reconstruction's residuals / the output's measurement-noise
    std (std of second differences / sqrt(6) over the fitted samples). About 1 when the
    kinematic model explains the data down to the noise; well above 1 on air data in
    turbulence or wind, which the calm-air model does not have."""
    r = res.result
    out = {}
    for k, c in enumerate(res.outputs):
        e, d2 = [], []
        for seg, resid in zip(r.segments, r.residuals):
            z = np.asarray(seg.z[:, k], float)
            z = z[np.isfinite(z)]
            if z.size > 3:
                d2.append(np.diff(z, 2))
            v = resid[c].to_numpy(dtype=float)
            e.append(v[np.isfinite(v)])
        ev, dv = np.concatenate(e) if e else np.zeros(0), np.concatenate(d2) if d2 else np.zeros(0)
        noise = float(np.std(dv) / np.sqrt(6.0)) if dv.size else np.nan
        out[c] = float(np.std(ev) / noise) if ev.size and noise > 0 else float("nan")
    return out


def compatibility_report(fd: FlightData, **kw) -> dict:
    """``reconstruct`` for ``fsid check``: a JSON-ready dict, or why it was skipped."""
    return _reconstruct_or_reason(fd, **kw)[0]


def _reconstruct_or_reason(fd: FlightData, **kw) -> tuple[dict, CompatibilityResult | None]:
    """(``reconstruct(fd, **kw).to_dict()``, the result), or ({status: skipped|failed,
    reason}, None) when the log cannot be reconstructed."""
    try:
        res = reconstruct(fd, **kw)
    except FsidError as exc:
        return {"status": "skipped", "reason": str(exc)}, None
    except Exception as exc:  # estimator failures are findings, not crashes
        if isinstance(exc, EstimationError):
            return {"status": "failed", "reason": f"{type(exc).__name__}: {exc}"}, None
        raise
    return res.to_dict(), res
