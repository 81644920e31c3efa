"""The proof of match: the identified model, every derivative held, predicts maneuvers not
used for fitting and is judged against tolerance bands.

What is held out is decided by the caller; here: the mode of the prediction (open-loop
simulation, or the model driven by its measured air data), the bands (widened by the
held-out data's measurement noise and by the timing uncertainty of control steps between
slow samples), and the prediction's own uncertainty from the estimates' covariance that a
miss is weighed against."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

import estimators
from estimators import EstimationResult, Segment, simulate_outputs
from estimators import statistics as st
from estimators import validation as V
from estimators.integrators import DEFAULT_INPUTS
from pipeline.conditioning.input_sampling import TIMED_RANGE_STD, TIMING_FRACTIONS, timing_variants
from pipeline.validation.json_values import num
from pipeline.validation.linear import Linearisation
from pipeline.validation.names import is_segment_parameter
from pipeline.validation.settings import ValidationSettings
from pipeline.validation.units import display_unit
from pipeline.validation.verdict import verdict

#: proof-of-match modes (:class:`pipeline.validation.settings.ValidationSettings`)
POM_MODES = ("auto", "simulation", "air-data")
#: largest real part (1/s) of an eigenvalue of a model still taken as stable
_UNSTABLE_REAL = 1e-3
#: share of a prediction's variance at its worst miss that names a derivative as its source
_SHARE_NAMED = 0.1
#: most derivatives named as the source of a prediction's variance
_SHARES_NAMED = 3


def _process_noise(result: EstimationResult) -> np.ndarray | None:
    """The process noise F (n, n) a result identified or used (FEM, EKF, UKF); None for
    methods without one (output error and its stabilised forms, equation error)."""
    F = result.extra.get("F", result.extra.get("process_noise"))
    return None if F is None else np.asarray(F, dtype=float)


def pom_mode(result: EstimationResult, lin: Linearisation | None = None, calm_air: bool = False) -> str:
    """The proof of match that suits a result: ``air-data`` (the model driven by its
    measured air data, :func:`estimators.validation.air_data_prediction`) when the method
    modelled process noise (it was chosen for turbulence: an open-loop simulation cannot
    follow the gusts) unless the held-out maneuvers are known to be flown in calm air
    (``calm_air``), or when the identified model is unstable (its open-loop simulation
    diverges from any error in the initial state), provided the model has an air-data
    state to drive; ``simulation`` (open loop, the classic proof of match) otherwise."""
    if not V.driving_states(result.model):
        return "simulation"
    F = _process_noise(result)
    if F is not None and np.any(F != 0) and not calm_air:
        return "air-data"
    if lin is not None and np.max(np.linalg.eigvals(lin[0]).real) > _UNSTABLE_REAL:
        return "air-data"
    return "simulation"


@dataclass
class _Run:
    """What every held-out segment's proof of match shares."""

    result: EstimationResult
    settings: ValidationSettings
    integrator: str
    mode: str
    outputs: list[str]
    notes: list[str]


def match_held_out(
    result: EstimationResult,
    held_out: Sequence[Segment],
    settings: ValidationSettings,
    integrator: str,
    mode: str,
    step_times: Sequence[Mapping[str, Any]] | None = None,
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """(section, arrays): the ``proof_of_match`` section of the validation (``mode``,
    ``driven``, ``segments``, ``notes``, ``all_pass``) and per held-out segment its
    ``arrays["match"]`` entry. ``mode`` is ``simulation`` or ``air-data`` (a segment whose
    air-data prediction fails is simulated instead); ``step_times`` per segment: its
    control-input steps between slow samples (:func:`_timing_envelope`)."""
    run = _Run(result, settings, integrator, mode, list(result.model_with_estimates().outputs), [])
    segs, arrays = [], []
    driven: list[str] = []
    for k, seg in enumerate(held_out):
        steps = (step_times or [{}] * len(held_out))[k] or {}
        sg, arr, driven = _match_segment(run, seg, k, steps)
        segs.append(sg)
        arrays.append(arr)
    if segs and all(sg["mode"] == "simulation" for sg in segs):
        mode = "simulation"
    return {
        "mode": mode,
        "driven": driven,
        "segments": segs,
        "notes": run.notes,
        "all_pass": bool(segs) and all(s["all_pass"] for s in segs),
    }, arrays


def _predict(
    run: _Run, seg: Segment, k: int
) -> tuple[pd.DataFrame, tuple[list[str], np.ndarray] | None, list[str], str]:
    """(y, sensitivity, driven, mode) of one held-out segment: its prediction in the run's
    mode, falling back to the open-loop simulation (with a note) when the air-data
    prediction fails, the prediction's sensitivity to the estimates (or None), and the
    air-data channels that drive the filter."""
    result, integrator = run.result, run.integrator
    y, sens, driven = None, None, []
    if run.mode == "air-data":
        try:
            dp = _air_data_prediction(result, seg, integrator)
            y, driven = dp.predicted, dp.driven
            sens = _air_data_sensitivity(result, seg, integrator, y)
        except (estimators.EstimationError, np.linalg.LinAlgError) as exc:
            # reported, and the classic proof of match run instead of none
            run.notes.append(f"air-data prediction of {seg.name or k} failed ({exc}); open-loop simulation instead")
            driven = []
    seg_mode = "air-data" if y is not None else "simulation"
    if y is None:
        y, fit = _held_out_fit(result, seg, integrator)
        sens = _prediction_sensitivity(result, seg, fit, integrator)
    return y, sens, driven, seg_mode


def _match_segment(
    run: _Run, seg: Segment, k: int, steps: Mapping[str, Any]
) -> tuple[dict[str, Any], dict[str, Any], list[str]]:
    """(section entry, arrays entry, driven channels) of one held-out segment."""
    y, sens, driven, seg_mode = _predict(run, seg, k)
    name = seg.name or f"held-out {k}"
    envelope, timing = _timing_envelope(run, seg, steps, seg_mode, y, name)
    z = pd.DataFrame(seg.z, index=y.index, columns=run.outputs)
    # the channels that drive the filter are its one-step predictions: not judged
    tol = {**(run.settings.tolerances or {}), **{c: math.nan for c in driven}}
    # the measurement noise of the held-out data, so that it alone does not fail a channel
    # somewhere in a long segment: the white level of the second differences of its error
    # against the prediction (robust: the kinks at control steps aside), not of the data,
    # whose second differences carry the signal's curvature on a slow channel
    noise = {
        c: float(v)
        for c, v in zip(run.outputs, st.difference_noise_std([seg.z - y.to_numpy(float)], robust=True))
        if np.isfinite(v) and v > 0
    }
    pm = V.proof_of_match(
        z, y, tolerances=tol, allowed_bias=run.settings.allowed_bias, envelope=envelope, noise_std=noise
    )
    chans = _channel_entries(pm, V.theil(z.to_numpy(), y.to_numpy()).U, driven, envelope is not None)
    arr = {
        "name": name,
        "t": seg.t,
        "measured": z,
        "predicted": y,
        "excess": pm.attrs["excess"],
        "sensitivity": sens,
        "tolerance": pm["tolerance"].to_numpy(float),
        "envelope": None
        if envelope is None
        else tuple(pd.DataFrame(a, index=y.index, columns=y.columns) for a in envelope),
    }
    _prediction_entries(chans, arr, None if sens is None else _band_covariance(run.result, sens[0]))
    entry = {
        "name": name,
        "mode": seg_mode,
        "channels": chans,
        "input_timing": timing,
        "all_pass": bool(pm.attrs["all_pass"]),
        "prediction_uncertainty": None if sens is None else {"parameters": len(sens[0]), "k": V.PREDICTION_K},
    }
    return entry, arr, driven


def _channel_entries(
    pm: pd.DataFrame, tic: np.ndarray, driven: Sequence[str], enveloped: bool
) -> dict[str, dict[str, Any]]:
    """Per channel: the columns of :func:`estimators.validation.proof_of_match` (SI), the
    same in display units (``*_display``, ``unit``), its ``TIC`` and ``role``; with a
    timing envelope also the nominal error and the envelope's width."""
    chans = {}
    for (ch, row), u in zip(pm.iterrows(), tic):
        fac, unit = display_unit(ch)
        d = num(row.to_dict())
        d.update(
            unit=unit,
            tolerance_display=num(row["tolerance"] * fac),
            max_abs_error_display=num(row["max_abs_error"] * fac),
            rms_error_display=num(row["rms_error"] * fac),
            TIC=num(u),
            noise_allowance_display=num(row["noise_allowance"] * fac),
            role="drives the filter" if ch in driven else "predicted",
        )
        if enveloped:
            d.update(
                nominal_max_abs_error_display=num(row["nominal_max_abs_error"] * fac),
                envelope_max_width_display=num(row["envelope_max_width"] * fac),
            )
        chans[ch] = d
    return chans


def _band_covariance(result: EstimationResult, names: Sequence[str]) -> np.ndarray:
    """The covariance of ``names`` among the result's free shared parameters (total:
    with its consider part), for the held-out prediction's std."""
    have, cov = _shared_covariance(result)
    idx = [have.index(n) for n in names]
    return cov[np.ix_(idx, idx)]


def _prediction_entries(chans: dict[str, dict[str, Any]], arr: dict[str, Any], cov: np.ndarray | None) -> None:
    """Set each proof-of-match channel's entries of the prediction's own uncertainty
    (display units, in place): ``prediction_std_max_display`` (its largest std),
    ``beyond_prediction_display`` (how far the misses reach beyond PREDICTION_K of it) and,
    on a failed channel, ``prediction_std_from`` (the derivatives carrying at least
    _SHARE_NAMED of the variance at its worst miss, :func:`estimators.validation.variance_shares`,
    at most _SHARES_NAMED: the ones better maneuvers should pin down); and the segment's
    ``arrays`` entry ``arr``'s ``prediction_std`` (N, n_out) DataFrame. From ``arr``:
    ``excess`` (N, n_out) each sample's error beyond its band, ``predicted`` (its columns
    and index) and ``sensitivity`` (names, S (N, n_out, n_p)) with ``cov`` their
    covariance, or None (no band: the entries None)."""
    sens, excess, columns = arr["sensitivity"], arr["excess"], arr["predicted"].columns
    ps = None if sens is None else V.prediction_std(sens[1], cov)
    arr["prediction_std"] = None if ps is None else pd.DataFrame(ps, index=arr["predicted"].index, columns=columns)
    top, beyond = V.prediction_uncertainty(excess, ps) if ps is not None else (np.full(len(columns), np.nan),) * 2
    for j, ch in enumerate(columns):
        d = chans.get(ch)
        if d is None:
            continue
        fac = display_unit(ch)[0]
        d.update(prediction_std_max_display=num(top[j] * fac), beyond_prediction_display=num(beyond[j] * fac))
        if ps is not None and d.get("pass") is False and np.isfinite(excess[:, j]).any():
            n = int(np.nanargmax(excess[:, j]))
            share = V.variance_shares(sens[1][n, j], cov)
            d["prediction_std_from"] = {
                sens[0][i]: num(round(float(share[i]), 3))
                for i in np.argsort(-share)[:_SHARES_NAMED]
                if share[i] >= _SHARE_NAMED
            }


def refresh_prediction_uncertainty(validation: dict[str, Any], result: EstimationResult) -> None:
    """Redo the proof of match's prediction-uncertainty entries of ``validation`` (in
    place) with the result's current covariance (a ``consider_cov`` set after validation),
    from the sensitivities and per-sample misses kept in its ``arrays``."""
    pm = validation.get("proof_of_match")
    arrays = (validation.get("arrays") or {}).get("match") or []
    if not pm:
        return
    for sg, a in zip(pm["segments"], arrays):
        if a.get("sensitivity") is None:
            continue
        _prediction_entries(sg["channels"], a, _band_covariance(result, a["sensitivity"][0]))
    validation["verdict"] = verdict(validation)


def _timing_envelope(
    run: _Run, seg: Segment, steps: Mapping[str, Any], mode: str, y: pd.DataFrame, name: str
) -> tuple[tuple[np.ndarray, np.ndarray] | None, dict[str, Any] | None]:
    """The range of the held-out prediction ``y`` over the unknown times of the segment's
    control-input steps between slow samples (``steps``: input -> [(start, end, std), ...]
    s, :func:`pipeline.conditioning.input_sampling.step_times`): the model, as held, predicts
    the segment again with every such step moved through the range of its time - an untimed
    one anywhere in its interval, a timed one within TIMED_RANGE_STD of its std
    (:func:`pipeline.conditioning.input_sampling.timing_variants`) - in ``mode`` as ``y``
    was; (lower, upper) over those and ``y``, and what was done. (None, None) when no step
    moves a grid sample of the segment; (None, doc) with a note when a prediction fails.
    Why: an untimed step is a ramp over a slow sample interval in the fitted input, and
    the prediction of a fast channel (a rate after a surface step) misses the band there
    by far more than the model's error."""
    result = run.result
    variants = timing_variants(seg, result.model.inputs, steps) if steps else []
    if not variants:
        return None, None
    inside = [sd for c in result.model.inputs for a, b, sd in steps.get(c, ()) if seg.t[0] < a and b < seg.t[-1]]
    doc: dict[str, Any] = {
        "steps": len(inside),
        "untimed": sum(sd is None for sd in inside),
        "timed_range_std": TIMED_RANGE_STD,
        "fractions": list(TIMING_FRACTIONS),
        "envelope": False,
    }
    ys = []
    for v in variants:
        try:
            ys.append(
                _air_data_prediction(result, v, run.integrator).predicted
                if mode == "air-data"
                else _held_out_fit(result, v, run.integrator)[0]
            )
        except (estimators.EstimationError, np.linalg.LinAlgError) as exc:
            run.notes.append(
                f"{name}: the prediction with its control-input steps moved within "
                f"their timing uncertainty failed ({exc}); judged on the steps as fitted"
            )
            return None, doc
    stack = np.stack([y.to_numpy(float)] + [a.to_numpy(float) for a in ys])
    doc["envelope"] = True
    return (np.min(stack, axis=0), np.max(stack, axis=0)), doc


def _air_data_prediction(
    result: EstimationResult, seg: Segment, integrator: str, shift: Mapping[str, float] | None = None
):
    """The identified model driven by the held-out segment's air data: every derivative
    held; per-segment parameters (output biases) at their mean over the fitted segments
    (sensor biases persist through a flight); the filter's process noise on the air-data
    states is the one the method identified or used (FEM, EKF, UKF), else the data
    default; the measurement noise is the method's (its R). ``shift``: amounts added to
    shared parameters (the sensitivities of :func:`_air_data_sensitivity`)."""
    vals = {n: v + (shift or {}).get(n, 0.0) for n, v in zip(result.names, result.values) if "[" not in n}
    per_seg: dict[str, list[float]] = {}
    for n, v in zip(result.names, result.values):
        if "[" in n and not n.startswith("x0_"):
            per_seg.setdefault(n.split("[")[0], []).append(float(v))
    vals.update({n: float(np.mean(v)) for n, v in per_seg.items()})
    R = result.extra.get("measurement_noise", result.R)
    return V.air_data_prediction(
        result.model.with_values(vals),
        seg,
        process_noise=_process_noise(result),
        measurement_noise=R,
        integrator=integrator,
        inputs=result.settings.get("inputs", DEFAULT_INPUTS),
    )


def _air_data_sensitivity(
    result: EstimationResult, seg: Segment, integrator: str, y: pd.DataFrame, rel_step: float = 1e-5
) -> tuple[list[str], np.ndarray] | None:
    """(names, S) as :func:`_prediction_sensitivity`, for the air-data-driven prediction
    ``y``: forward differences, one filter pass per free shared model parameter (the
    filter's gain moves with them too; nothing is refitted to the segment). None when a
    pass fails."""
    names = _band_parameters(result)
    if not names:
        return None
    vals = result.params
    cols = []
    for n in names:
        h = rel_step * max(abs(float(vals[n])), 1.0)
        try:
            yp = _air_data_prediction(result, seg, integrator, {n: h}).predicted
        except (estimators.EstimationError, np.linalg.LinAlgError):
            return None
        cols.append((yp.to_numpy(float) - y.to_numpy(float)) / h)
    S = np.stack(cols, axis=2)
    return (names, S) if np.all(np.isfinite(S)) else None


def _held_out_fit(
    result: EstimationResult, seg: Segment, integrator: str
) -> tuple[pd.DataFrame, EstimationResult | None]:
    """The identified model's prediction of a held-out segment: every derivative held at
    its estimate; only the segment's initial state and the model's per-segment biases are
    adjusted to the data (the usual proof of match - a noisy first sample as initial
    condition would excite the phugoid and fail the angles for no fault of the model).
    Falls back to a plain simulation from the segment's x0 when that fit fails (None for
    the fit)."""
    shared = {n: v for n, v in zip(result.names, result.values) if "[" not in n}
    model = result.model.with_values(shared).fixed([n for n in result.free_names if "[" not in n])
    inputs = result.settings.get("inputs", DEFAULT_INPUTS)
    try:
        fit = estimators.OutputError(model, integrator=integrator, inputs=inputs, fallback="never").fit(
            seg, estimate_x0=True
        )
        return fit.predicted[0], fit
    except estimators.EstimationError:
        return simulate_outputs(result.model_with_estimates(), seg, integrator=integrator, inputs=inputs), None


def _shared_covariance(result: EstimationResult) -> tuple[list[str], np.ndarray]:
    """(names, covariance) of the result's free shared parameters (no per-segment ones):
    its covariance plus its ``consider_cov`` when it has one (the total uncertainty)."""
    free = result.free_names
    keep = [i for i, n in enumerate(free) if not is_segment_parameter(n)]
    cov = np.asarray(result.cov, dtype=float)
    if result.consider_cov is not None:
        cov = cov + np.asarray(result.consider_cov, dtype=float)
    return [free[i] for i in keep], cov[np.ix_(keep, keep)]


def _band_parameters(result: EstimationResult) -> list[str]:
    """The free shared parameters of the result's model that its predictions depend on
    (filter error's process-noise F_<state>, G_<output> are not the model's)."""
    return [n for n in _shared_covariance(result)[0] if n in result.model.parameter_names]


def _prediction_sensitivity(
    result: EstimationResult, seg: Segment, fit: EstimationResult | None, integrator: str
) -> tuple[list[str], np.ndarray] | None:
    """(names, S) with S (N, n_out, n_names) the held-out prediction's sensitivity to the
    result's free shared parameters, the segment's initial state and output biases refitted
    as the proof of match fits them (:func:`estimators.validation.parameter_sensitivity`,
    weighted by that fit's residual variance); None without that fit or when the
    simulation fails. Parameters the result held (another axis' estimates a 6-DoF model
    holds) add nothing here: their uncertainty is not in its covariance."""
    if fit is None:
        return None
    names = _band_parameters(result)
    if not names:
        return None
    values = {n: float(v) for n, v in zip(fit.names, fit.values)}
    w = 1.0 / np.diag(np.atleast_2d(fit.R))
    w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
    try:
        S = V.parameter_sensitivity(
            fit.model,
            seg,
            values,
            names,
            fit.free_names,
            weights=w,
            integrator=integrator,
            inputs=result.settings.get("inputs", DEFAULT_INPUTS),
        )
    except (estimators.EstimationError, np.linalg.LinAlgError, ValueError):
        return None
    return (names, S) if np.all(np.isfinite(S)) else None
