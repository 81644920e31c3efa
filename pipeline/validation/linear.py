"""Checks of the identified model linearised at a fitted segment's first sample: its modes,
its frequency response against the data's, and the inverse simulation."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimators import EstimationResult, Segment, frequency_response, simulate_outputs
from estimators import validation as V
from estimators.integrators import DEFAULT_INPUTS
from estimators.model import Namespace
from pipeline.validation.json_values import frame_dict, num
from pipeline.validation.settings import ValidationSettings
from pipeline.validation.units import display_unit

#: speed states whose trim value scales the mode names' velocity components
_SPEEDS = ("V", "u", "vn", "vd")
#: halvings of the inverse simulation's loop bandwidth tried while its sampled loop is unstable
_BANDWIDTH_HALVINGS = 3

#: (A, B, C, D, x0, u0) of :func:`linear_model`
#: the frequency check's grid: log-spaced from about two periods of the longest segment to
#: this (or a fifth of the sample rate)
F_CHECK_MAX_HZ = 10.0
F_CHECK_POINTS = 60
#: a frequency-response mismatch within this many of the data's random errors is no failure
RANDOM_ERROR_K = 3.0
#: frequencies whose estimate rests on fewer averages are not judged (from one average the
#: coherence is 1 whatever the data)
MIN_AVERAGES = 1.5

Linearisation = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def linear_model(result: EstimationResult, segment: Segment | None = None) -> Linearisation:
    """(A, B, C, D, x0, u0): the identified model linearised at the first sample of
    ``segment`` (default: the first fitted segment): x0 its initial state, u0 its first input.
    A (n_x, n_x), B (n_x, n_u), C (n_y, n_x), D (n_y, n_u) in SI per SI."""
    model = result.model_with_estimates()
    seg = segment if segment is not None else result.segments[0]
    x0 = np.asarray(seg.initial_state(model), dtype=float)
    u0 = np.asarray(seg.u[0], dtype=float)
    p = Namespace({pp.name: float(pp.value) for pp in model.parameters})
    c = Namespace(model.constants_for(seg))
    A, B = V.linearize(model.f, x0, u0, p, c)
    C, D = V.linearize(model.g, x0, u0, p, c)
    return A, B, C, D, x0, u0


def mode_table(result: EstimationResult, lin: Linearisation) -> dict[str, Any]:
    """The ``modes`` section: ``trim`` (x0 per state, u0 per input), ``table`` per mode
    (``real imag wn zeta period t_half t_double stable axis``), ``eigenvalues`` ([real, imag])."""
    A, B, C, D, x0, u0 = lin
    model = result.model
    speed = next((abs(x0[model.states.index(s)]) for s in _SPEEDS if s in model.states), None)
    scales = {s: speed for s in _SPEEDS if speed} if speed else None
    ma = V.modes(A, model.states, scales=scales)
    tab = ma.table.drop(columns=["eigenvalue"])
    return {
        "trim": {"x0": num(dict(zip(model.states, x0))), "u0": num(dict(zip(model.inputs, u0)))},
        "table": frame_dict(tab),
        "eigenvalues": [[float(v.real), float(v.imag)] for v in ma.eigenvalues],
    }


def _between_samples(t: np.ndarray, y: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """Columns of ``y`` (N, n) kept where ``measured`` (N, n) and linear in ``t`` between
    those samples (held before the first and after the last)."""
    out = y.astype(float).copy()
    for j in range(y.shape[1]):
        if not measured[:, j].all():
            out[:, j] = np.interp(t, t[measured[:, j]], y[measured[:, j], j])
    return out


def _data_and_model_responses(
    result: EstimationResult,
    segs: list[Segment],
    measured: list[np.ndarray],
    excited: list[int],
    keep: np.ndarray,
    f: np.ndarray,
    integrator: str,
) -> tuple[Any, Any]:
    """The frequency responses (:func:`estimators.frequency_response`) of the measured
    outputs ``keep`` (``measured``: per segment where each output has samples) to the
    inputs ``excited`` over ``segs``, and of the identified model's simulated outputs read
    at the same samples."""
    model = result.model_with_estimates()
    how = result.settings.get("inputs", DEFAULT_INPUTS)
    data, sim = [], []
    for s, m in zip(segs, measured):
        data.append(_between_samples(s.t, s.z[:, keep], m[:, keep]))
        y_sim = simulate_outputs(model, s, integrator=integrator, inputs=how).to_numpy()
        sim.append(_between_samples(s.t, y_sim[:, keep], m[:, keep]))
    ts, us = [s.t for s in segs], [s.u[:, excited] for s in segs]
    return frequency_response(ts, us, data, f=f), frequency_response(ts, us, sim, f=f)


def frequency_check(
    result: EstimationResult, lin: Linearisation, settings: ValidationSettings, integrator: str
) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """Model vs data in the frequency domain over the fitted segments (those uniformly
    sampled at one rate; their averages add up): (section, arrays), (None, None) without
    uniform sampling or an excited input.

    The data's responses are :func:`estimators.frequency_response`'s: with several inputs
    each one's response conditioned on the others (aileron and rudder that move together
    give each its own) and judged where its partial coherence is high. The model is put
    through the SAME estimator (its simulated outputs with the same inputs), so window
    leakage, the short record and the maneuver's transient affect both alike and the
    mismatch shows the model alone. The model's outputs are a fresh simulation of the
    identified model held fixed (not a filter's one-step predictions, which lean on the
    data). The analytic G(jw) = C (jwI - A)^-1 B + D of the model linearised at the first
    sample is kept alongside for the plots. Bounds from ``settings``."""
    A, B, C, D, _, _ = lin
    segs = [s for s in result.segments if s.t.size >= 64 and np.ptp(np.diff(s.t)) <= 1e-6 * np.median(np.diff(s.t))]
    if not segs:
        return None, None  # needs uniform sampling
    dts = [float(np.median(np.diff(s.t))) for s in segs]
    segs = [s for s, d in zip(segs, dts) if abs(d - dts[0]) <= 1e-6 * dts[0]]  # one rate
    excited = [i for i in range(segs[0].u.shape[1]) if max(np.std(s.u[:, i]) for s in segs) > 1e-12]
    if not excited:
        return None, None
    # an output slower than the grid (NaN between its samples) is read linearly between its
    # samples, and the model's simulated output is read at the same samples the same way
    measured = [np.isfinite(s.z) for s in segs]
    keep = np.sum([m.sum(axis=0) for m in measured], axis=0) >= 64
    keep &= np.all([m.any(axis=0) for m in measured], axis=0)
    outs = [o for o, kk in zip(result.outputs, keep) if kk]
    fs = 1.0 / dts[0]
    span = max(float(s.t[-1] - s.t[0]) for s in segs)
    # from a little above the lowest frequency the longest window (half the longest
    # segment, rounded to samples) resolves
    f = np.geomspace(2.2 / span, min(F_CHECK_MAX_HZ, fs / 5), F_CHECK_POINTS)
    ins = [result.model.inputs[i] for i in excited]
    se, sm = _data_and_model_responses(result, segs, measured, excited, keep, f, integrator)
    w = se.w
    Hd, coh, Hm = se.H, se.coherence, sm.H
    G = V.freq_response(A, B[:, excited], C[keep], D[keep][:, excited], w)
    # judge only where the input carries power (its own spectrum a share of its peak) and
    # the estimate rests on enough averages (the coherence of a few is biased towards 1,
    # and the random error with it towards 0)
    suu = se.input_spectra
    weak = suu < settings.input_power_fraction * suu.max(axis=0, keepdims=True)
    weak |= (se.n_averages < MIN_AVERAGES)[:, None]
    coh_used = np.where(weak[:, None, :], 0.0, coh)
    # a point is judged against the bounds or, where the data's estimate is less certain,
    # against 3 of its random errors (of |H| in dB, of the phase in deg): a model that
    # agrees with the data within their spread does not fail on it
    eps = np.nan_to_num(se.random_error, nan=0.0, posinf=0.0)
    mag_bound = np.maximum(settings.mag_bound_db, 20 * np.log10(1 + RANDOM_ERROR_K * eps))
    phase_bound = np.maximum(settings.phase_bound_deg, np.degrees(RANDOM_ERROR_K * eps))
    mm = V.mismatch(
        Hm,
        Hd,
        w,
        coh_used,
        mag_bound_db=mag_bound,
        phase_bound_deg=phase_bound,
        min_coherence=settings.min_coherence,
        outputs=outs,
        inputs=ins,
    )
    tab = {f"{o}/{i}": num(row.to_dict()) for (o, i), row in mm.table.iterrows()}
    judged = mm.table[mm.table["n_used"] > 0]
    out = {
        "inputs": ins,
        "outputs": outs,
        "segments": [s.name or f"segment {k}" for k, s in enumerate(segs)],
        "table": tab,
        "bounds": {
            "mag_db": settings.mag_bound_db,
            "phase_deg": settings.phase_bound_deg,
            "random_errors": RANDOM_ERROR_K,
            "min_averages": MIN_AVERAGES,
            "min_coherence": settings.min_coherence,
            "input_power_fraction": settings.input_power_fraction,
        },
        "n_judged": int(len(judged)),
        "all_pass": bool(len(judged) and judged["pass"].all()),
    }
    arrays = {
        "f": w / (2 * np.pi),
        "H_model": Hm,
        "H_analytic": G,
        "H_data": Hd,
        "coherence": coh,
        "used": mm.used,
        "inputs": ins,
        "outputs": outs,
    }
    return out, arrays


def inverse_check(
    result: EstimationResult, lin: Linearisation, bandwidth: float
) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """Inverse simulation on the first fitted segment: (section, arrays), (None, None)
    without an excited input or a tracked output. The inputs the linearised model needs
    to follow the measured outputs, and the residual inputs (needed minus flown) per excited
    input, in perturbations about the first sample (trim). The loop tracks the outputs that
    are also states (falling back to all outputs) at ``bandwidth`` rad/s, halved up to
    _BANDWIDTH_HALVINGS times while the sampled loop is unstable. A higher bandwidth feeds
    more measurement noise into the residual inputs; compare methods at the same bandwidth."""
    A, B, C, D, x0, u0 = lin
    seg = result.segments[0]
    excited = [i for i in range(seg.u.shape[1]) if np.std(seg.u[:, i]) > 1e-12]
    finite = np.all(np.isfinite(seg.z), axis=0)
    keep = finite & np.array([o in result.model.states for o in result.outputs])
    if not keep.any():
        keep = finite
    if not excited or not keep.any():
        return None, None
    model = result.model_with_estimates()
    p = Namespace({pp.name: float(pp.value) for pp in model.parameters})
    rows = model.g(x0[:, None], u0[:, None], p, Namespace(model.constants_for(seg)))
    y0 = np.array([float(np.asarray(r, dtype=float).ravel()[0]) for r in rows])
    du = seg.u[:, excited] - u0[excited]
    # scipy.signal.dlsim (inside inverse_simulation) takes floor(t[-1] / dt) + 1 samples, one
    # short when rounding leaves t[-1] a hair below (N-1) dt: march on an exact grid kept
    # just above (N-1) dt
    dt = float(np.median(np.diff(seg.t)))
    t_loop = np.arange(seg.t.size) * dt
    t_loop[-1] += 1e-9 * dt
    bw = bandwidth
    for attempt in range(_BANDWIDTH_HALVINGS + 1):
        try:
            inv = V.inverse_simulation(
                A,
                B[:, excited],
                C[keep],
                D[keep][:, excited],
                t_loop,
                seg.z[:, keep] - y0[keep],
                u_ref=du,
                bandwidth=bw,
            )
            break
        except ValueError as exc:
            if "unstable" not in str(exc) or attempt == _BANDWIDTH_HALVINGS:
                raise
            bw /= 2.0
    ins = [result.model.inputs[i] for i in excited]
    tracked = [o for o, k in zip(result.outputs, keep) if k]
    return (
        {
            "segment": seg.name or "segment 0",
            "tracked": tracked,
            "bandwidth": bw,
            "per_input": _residual_inputs(ins, inv.residual_inputs, du),
        },
        {"t": seg.t, "name": seg.name or "#0", "inputs": ins, "residual_inputs": inv.residual_inputs},
    )


def _residual_inputs(inputs: list[str], residual: np.ndarray, flown: np.ndarray) -> dict[str, Any]:
    """Per input: rms and largest residual input (needed minus flown, (N, n_in) SI) against
    the rms of the flown perturbation ``flown`` (N, n_in), and the rms in display units."""
    per = {}
    for j, name in enumerate(inputs):
        fac, unit = display_unit(name)
        r = residual[:, j]
        rms_r, rms_u = float(np.sqrt(np.mean(r**2))), float(np.sqrt(np.mean(flown[:, j] ** 2)))
        per[name] = num(
            {
                "rms_residual": rms_r,
                "max_abs_residual": float(np.max(np.abs(r))),
                "rms_input": rms_u,
                "ratio": rms_r / rms_u if rms_u > 0 else math.nan,
                "unit": unit,
                "rms_residual_display": rms_r * fac,
            }
        )
    return per
