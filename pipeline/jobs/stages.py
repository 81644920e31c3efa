"""The data-preparation stages of the jobs, before the fits: the air-data angles a log lacks
rebuilt from the flight path, the sensor-compatibility reconstruction, the control-input
delays and lags, and the validation flights corrected as the fitted flight was. Each
stage reports on a :class:`pipeline.jobs.progress.Progress` and never ends the job: a
stage that cannot run says why and the data go on as they were."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

from pipeline.conditioning.flight_path_model import IMU_PARAMS
from pipeline.conditioning.flow_angles import calibrated, mean_wind, reconstruct_flow_angles, unsteady
from pipeline.conditioning.flow_angles import summary as flow_summary
from pipeline.conditioning.input_dynamics import (
    estimate_input_dynamics,
    logged_inputs_fit_better,
    refine_by_output_error,
    with_input_dynamics,
)
from pipeline.conditioning.input_dynamics import summary as dynamics_summary
from pipeline.conditioning.sensor_correction import RUN_ESTIMATE, correct_for_estimation
from pipeline.conditioning.sensor_errors import instrument_errors, remove_sensor_errors
from pipeline.errors import FsidError
from pipeline.ingest.constants import AircraftConstants
from pipeline.ingest.flightdata import CONTROL_INPUTS, FlightData
from pipeline.jobs.progress import Progress


def flow_angle_stage(
    fd: FlightData, ac: AircraftConstants | None, pr: Progress, *, airspeed_scale: float | None = None
) -> tuple[FlightData, AircraftConstants | None, FlightData, dict]:
    """The air-data-angle stage: alpha/beta the log lacks (no vane), or holds only as an
    autopilot's estimate (``Channel.derived``: ArduPilot's AOA/SSA, from its EKF velocity
    and wind), rebuilt from the flight path and a fitted wind
    (:mod:`pipeline.conditioning.flow_angles`), whose document names the assumptions and the
    wind. Returns (flight data for estimation, aircraft constants, the logged data without
    derived angles - what the sensor-compatibility stage may use, also when they are kept
    for estimation -, document). Rebuilt angles are the CG's (the navigation filter's
    velocity is the body origin's), so the constants' air-data position becomes (0, 0, 0).
    ``airspeed_scale``: the pitot's scale factor held (a validation flight takes the fitted
    flight's), else estimated with the wind where the headings allow. A log that cannot
    give them (no inertial velocity, no forward flight) goes on as it is: the document says
    why, and a model that needs the angles stops later with the missing channels named."""
    pr.stage("air-data angles")
    derived = {k: f"{fd[k].source}: {fd[k].derived}" for k in ("alpha", "beta") if k in fd and fd[k].derived}
    base = (
        fd
        if not derived
        else FlightData(
            channels={k: c for k, c in fd.channels.items() if k not in derived},
            meta=dict(fd.meta),
            segments=list(fd.segments),
        )
    )
    try:
        out, doc = reconstruct_flow_angles(base, airspeed_scale=airspeed_scale)
    except FsidError as exc:
        kept = f"; the logged estimates kept ({', '.join(derived.values())})" if derived else ""
        pr.done(f"not rebuilt: {exc}{kept}")
        return fd, ac, base, {"status": "not possible", "reason": str(exc) + kept}
    if doc["status"] != "reconstructed":
        pr.done("logged (vanes)")
        return fd, ac, fd, doc
    if derived:
        doc["replaced"] = derived
    if ac is not None and "alpha" in doc["channels"]:
        ac = replace(ac, airdata=(0.0, 0.0, 0.0))
        doc["airdata_position_m"] = [0.0, 0.0, 0.0]
    instead = f" (instead of the logged {', '.join(derived)}: computed from other channels, not vanes)"
    pr.done(flow_summary(doc) + (instead if derived else ""))
    return out, ac, base, doc


def with_flow_angles(
    fd: FlightData, flow: Mapping[str, Any], wind_offset: Sequence[float] = (0.0, 0.0, 0.0)
) -> tuple[FlightData, dict]:
    """(``fd`` with the air-data angles rebuilt as :func:`flow_angle_stage` rebuilt them,
    ``wind_offset`` (north, east, down [m/s], pitot scale factor [-], the last optional)
    added to their wind and scale factor, their document); ``fd`` and ``flow`` unchanged
    when that stage rebuilt nothing."""
    if flow.get("status") != "reconstructed":
        return fd, dict(flow)
    cal = flow.get("airspeed_scale") or {}
    return reconstruct_flow_angles(
        fd, wind_offset=wind_offset, airspeed_scale=cal["estimate"] if cal.get("status") == "held" else None
    )


def compatibility_stage(
    fd: FlightData,
    ac: AircraftConstants | None,
    pr: Progress,
    *,
    enabled: bool = True,
    truth: Mapping[str, float] | None = None,
    imu_only: bool = False,
    unsteady: str | None = None,
    wind: tuple[float, float] | None = None,
    airspeed: Any = None,
    positions: tuple[Sequence[float], Sequence[float]] | None = None,
) -> tuple[FlightData, dict]:
    """The sensor-compatibility stage (flight path reconstruction,
    :func:`pipeline.conditioning.compatibility.correct_for_estimation`): returns (flight
    data for estimation, JSON-ready document). Sensor errors distinguishable from zero
    (|estimate| >= 3 std) are removed from the data estimation sees; the others are reported
    and not applied. Sensor positions from ``ac`` (0,0,0 without one), or ``positions``
    (IMU, boom) [m]. Never ends the run: a log the reconstruction cannot use (no forward
    flight, missing channels) or a failed fit is reported as skipped / failed and
    estimation gets the data as logged. ``enabled=False`` (``--no-compat``): skipped.
    ``truth``: the true sensor errors, compared in the document. ``imu_only``: estimate the
    IMU errors alone (a log without vanes: the airspeed is then the only air data, and with
    a free wind its bias, scale factor and delay are nearly one parameter). ``unsteady`` and
    ``wind`` (the air-data-angle stage's, which its zero-sideslip condition fixes across the
    track) go to the reconstruction. ``airspeed``: the V channel that wind was fitted with
    (calibrated by the pitot's scale factor), which the reconstruction takes in place of the
    logged one (with the logged one and the held wind, the airspeed error would be booked on
    the IMU); the data returned keep the logged V, which the air-data-angle stage calibrates
    again."""
    pr.stage("sensor compatibility (flight path reconstruction)")
    if not enabled:
        doc = {
            "status": "skipped",
            "reason": "switched off (--no-compat)",
            "applied": {},
            "data_for_estimation": "as logged",
        }
        pr.done("skipped (--no-compat)")
        return fd, doc
    imu, boom = positions or (
        (tuple(ac.imu), tuple(ac.airdata)) if ac is not None else ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    )
    try:
        seen = fd if airspeed is None else replace(fd, channels={**fd.channels, "V": airspeed})
        doc, out = correct_for_estimation(
            seen,
            imu_position=imu,
            boom_position=boom,
            truth=truth,
            estimate=IMU_PARAMS if imu_only else RUN_ESTIMATE,
            wind=wind,
            unsteady=unsteady,
        )
        if airspeed is not None:
            out = replace(out, channels={**out.channels, "V": fd["V"]})
            doc["airspeed"] = "calibrated by the air-data-angle stage's airspeed scale factor"
        if imu_only:
            doc["scope"] = "IMU errors only: no air-data vanes in the log"
    except Exception as exc:  # noqa: BLE001 - the compatibility check must not cost the run
        doc, out = (
            {
                "status": "failed",
                "reason": f"{type(exc).__name__}: {exc}",
                "applied": {},
                "data_for_estimation": "as logged",
            },
            fd,
        )
    doc["positions"] = {"imu_m": list(map(float, imu)), "boom_m": list(map(float, boom))}
    _report_compatibility(doc, pr)
    return out, doc


def _report_compatibility(doc: Mapping[str, Any], pr: Progress) -> None:
    """The end of the compatibility stage's progress line."""
    st = doc.get("status")
    if st in ("skipped", "failed"):
        pr.done(f"{st}: {doc.get('reason', '')}")
    elif doc["applied"]:
        pr.done(
            f"{len(doc['applied'])} of {len(doc.get('parameters', {}))} sensor errors significant, "
            "removed from the data for estimation"
        )
    else:
        pr.done(f"{st}: {doc.get('note', 'no correction applied')}")


def compatibility_after_flow_angles(
    logged: FlightData,
    rebuilt: FlightData,
    flow: Mapping[str, Any],
    ac: AircraftConstants | None,
    pr: Progress,
    **kw: Any,
) -> tuple[FlightData, dict]:
    """:func:`compatibility_stage` after the air-data-angle stage (:func:`flow_angle_stage`:
    ``logged`` its logged data without derived angles, ``rebuilt`` its data, ``flow`` its
    document): the IMU errors only when the log has no vane, with that stage's wind held,
    its verdict on the steadiness of the air, and the airspeed it calibrated. ``kw`` go to
    :func:`compatibility_stage`."""
    imu_only = not any(k in logged for k in ("alpha", "beta"))
    return compatibility_stage(
        logged,
        ac,
        pr,
        imu_only=imu_only,
        unsteady=unsteady(flow),
        wind=mean_wind(flow),
        airspeed=rebuilt["V"] if imu_only and calibrated(flow) else None,
        **kw,
    )


def input_dynamics_stage(
    fd: FlightData, pr: Progress, setting: str | tuple[float, float] = "auto"
) -> tuple[FlightData, dict]:
    """The control-input dynamics stage (:mod:`pipeline.conditioning.input_dynamics`):
    returns (flight data with the dynamics applied, JSON-ready document). ``setting``:
    "auto" estimates each surface's delay and lag and applies the significant ones; "off"
    skips the stage; (delay, lag) [s] applies those to every control input without
    estimating. Never ends the run: a failed estimate is reported and the inputs stay as
    logged."""
    pr.stage("control-input delay and lag (equation error)")
    if setting == "off":
        pr.done("skipped (--input-dynamics off)")
        return fd, {"status": "skipped", "reason": "switched off (--input-dynamics off)", "applied": {}}
    if setting != "auto":
        d, tau = (float(x) for x in setting)
        doc = {"status": "given", "applied": {s: {"delay_s": d, "lag_s": tau} for s in CONTROL_INPUTS if s in fd}}
        pr.done(dynamics_summary(doc))
        return with_input_dynamics(fd, doc["applied"]), doc
    try:
        doc = estimate_input_dynamics(fd)
    except Exception as exc:  # noqa: BLE001 - the estimate must not cost the run
        pr.done(f"failed: {type(exc).__name__}: {exc}; inputs as logged")
        return fd, {"status": "failed", "reason": f"{type(exc).__name__}: {exc}", "applied": {}}
    doc["status"] = "estimated"
    pr.done(dynamics_summary(doc))
    return with_input_dynamics(fd, doc["applied"]), doc


def refine_input_dynamics_stage(
    fd_before: FlightData,
    fd: FlightData,
    doc: dict[str, Any],
    methods: Sequence[str],
    pr: Progress,
    fit: Callable[[dict, Any], Mapping[str, Any]],
) -> tuple[FlightData, dict]:
    """The control-input dynamics stage's delays and lags refined by output error
    (:func:`pipeline.conditioning.input_dynamics.refine_by_output_error`; ``fit(dynamics,
    starts)`` its output-error fits) when that stage estimated and applied some and output
    error is among ``methods``. Returns (the data ``fd_before`` that stage had, with the
    refined dynamics applied - ``fd``, the stage's, when nothing was refined -, ``doc``).
    Never ends the run: a refinement that fails keeps the equation-error values, and says
    why - unless the output-error fits want the inputs as logged
    (:func:`pipeline.conditioning.input_dynamics.logged_inputs_fit_better`): then none is
    applied (each surface's ``withdrawn`` says why): a correction the fits do not want is
    not made."""
    if doc.get("status") != "estimated" or not doc.get("applied"):
        return fd, doc
    if "oem" not in methods:
        doc["refined"] = {"status": "not refined", "reason": "output error is not among the methods"}
        return fd, doc
    pr.substage(f"refined by output error ({', '.join(doc['applied'])})")
    ref = refine_by_output_error(doc, fit, pr)
    why = logged_inputs_fit_better(doc["applied"], fit) if ref["status"] != "refined" else None
    if why:
        for srf in doc["applied"]:
            doc["surfaces"][srf]["applied"] = False
            doc["surfaces"][srf]["withdrawn"] = f"not refined ({ref['reason']}); {why}"
        doc["applied"] = {}
        ref["reason"] += f"; {why}: none applied"
        pr.done(f"not refined: {ref['reason']}")
        return fd_before, doc
    if ref["status"] != "refined":
        pr.done(f"not refined: {ref['reason']}; equation error's values kept")
        return fd, doc
    pr.done(
        ", ".join(
            f"{s} delay {v['delay_s'] * 1e3:+.1f}, lag {v['lag_s'] * 1e3:.1f} ms" for s, v in doc["applied"].items()
        )
        + f" ({ref['iterations']} iterations, {ref['fits']} fits)"
    )
    return with_input_dynamics(fd_before, doc["applied"]), doc


def with_instrument_errors_removed(fd_val: FlightData, comp: Mapping[str, Any], meta: dict | None = None) -> FlightData:
    """The validation flight with the instrument errors the compatibility stage removed
    from the fitted flight (scale factors, air-data delay:
    :func:`pipeline.conditioning.compatibility.instrument_errors`) removed too, so that the
    model is proved on data in the same corrected space it was fitted on; the names go to
    ``meta["validation flight corrections"]``."""
    errs = instrument_errors(comp.get("applied") or {})
    if not errs:
        return fd_val
    if meta is not None:
        meta["validation flight corrections"] = {n: float(v) for n, v in errs.items()}
    return remove_sensor_errors(fd_val, errs, keep_times=True)
