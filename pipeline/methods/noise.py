"""Noise levels the methods start from: measurement noise per output, process noise per
state (from a Dryden turbulence level, an assumed light turbulence, or the data), the
Kalman filters' process noise from a filter-error fit and their initial parameter std."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from estimators.filters.noise import default_process_noise
from estimators.statistics import difference_noise_std
from pipeline.ingest.constants import isa_altitude
from pipeline.ingest.flightdata import FlightData
from pipeline.problems import Problem
from sim.turbulence import dryden_parameters

#: states of the gust models that are coloured already (first-order Markov): the filters
#: take filter error's F for them as it is, not doubled (see process_noise_std)
COLOURED_STATES = ("p_g", "q_gi")
#: parameters of the gust models' noise, not of the aerodynamics: the Kalman filters hold
#: them at filter error's estimates when they take its process noise (no turbulence level
#: known: a real log); free, the filters' own estimate of the roll gust's time constant
#: trades off against the roll damping
GUST_NOISE_PARAMETERS = ("tau_pg",)


def measurement_noise_std(problem: Problem, logged: bool = True) -> np.ndarray:
    """Measurement-noise std per output (the filters' R), shape (n_outputs,): with
    ``logged``, ``problem.noise_std`` where it has the output (from the log's native
    samples, :func:`attach_logged_noise`); else from the fitted segments: sqrt(var(second
    differences) / 6), exact for white noise on a signal that is locally linear over two
    samples."""
    sd = difference_noise_std([s.z for s in problem.fit])
    logged = (problem.noise_std or {}) if logged else {}
    sd = np.array([logged.get(o, v) for o, v in zip(problem.model.outputs, sd)], dtype=float)
    return np.where(np.isfinite(sd) & (sd > 0), sd, 1e-6)


def attach_logged_noise(fd: FlightData, problem: Problem) -> Problem:
    """Set ``problem.noise_std`` for each output that is a logged channel: its white-noise
    std from the native samples in the fitted windows, as it appears on the problem's grid
    (FlightData.noise_std with the grid rate: the anti-alias filter of the resampling
    lowers it). On the grid itself the second differences of a fast signal mistake its
    curvature for noise, and the filtered noise is no longer white. Returns the problem."""
    rate = problem.rate_hz or None
    wins = [(s.t0, s.t1) for s in problem.specs]
    problem.noise_std = {
        o: sd
        for o in problem.model.outputs
        if o in fd
        for sd in [fd.noise_std(o, wins, rate)]
        if np.isfinite(sd) and sd > 0
    }
    return problem


def dryden_known(turbulence: Mapping[str, Any] | None) -> bool:
    """Whether a Dryden turbulence level is given (``model`` not off and ``sigma_w``)."""
    turb = turbulence or {}
    return turb.get("model", "off") not in ("off", None, "") and bool(turb.get("sigma_w"))


def assumed_turbulence(problem: Problem) -> dict[str, float]:
    """The Dryden level of light turbulence (MIL-F-8785C: 15 kt at 20 ft, probability of
    exceedance 1e-2, as sim.turbulence tabulates it) at the flight's altitude, taken from
    the model's air density (ISA): the start of filter error's process noise for the gust
    states when no turbulence level is known (a real log); FEM then estimates it."""
    rho = float(problem.model.constants.get("rho", 1.225))
    return {"model": "assumed light", **dryden_parameters(isa_altitude(rho), 15 * 0.514444, 3)}


def process_noise_std(
    problem: Problem, turbulence: Mapping[str, Any] | None = None, scale: float = 1.0
) -> dict[str, float]:
    """Process-noise std F (state unit per sqrt(s)) for the filters, by state.

    From a Dryden turbulence level (``sigma_u``, ``sigma_w`` m/s, scale lengths ``L_u``,
    ``L_w`` m) when known: a first-order gust of std sigma and time constant L/V has the
    white-noise intensity sigma sqrt(2 V / L), so F_V = sigma_u sqrt(2V/L_u),
    F_alpha = sigma_w/V sqrt(2V/L_w), and F_q = 0.3 F_alpha for what the alpha noise does
    not carry into the pitch rate. Lateral: beta, p, r likewise from sigma_v
    (F_p = F_r = 0.3 F_beta). A gust model (rotary-gust states) without a known level starts
    from light turbulence at the flight's altitude (:func:`assumed_turbulence`): the data
    default leaves its unmeasured gust states at 0, where their time constant has no effect
    on the likelihood. Otherwise the FilterError default: 0.05 sqrt(var(diff z)/h) per
    measured state. Everything times ``scale``."""
    m = problem.model
    turb = turbulence or {}
    if not dryden_known(turb) and any(st in m.states for st in COLOURED_STATES):
        turb = assumed_turbulence(problem)
    if dryden_known(turb):
        V = _mean_airspeed(problem)
        su, sv, sw = (float(turb.get(k, turb["sigma_w"])) for k in ("sigma_u", "sigma_v", "sigma_w"))
        Lu, Lv, Lw = (float(turb.get(k, 300.0)) for k in ("L_u", "L_v", "L_w"))
        rot = _rotary_gust_std(m, V, sw, Lw)
        if problem.axis == "longitudinal":
            fa = sw / V * np.sqrt(2 * V / Lw)
            return {"V": scale * su * np.sqrt(2 * V / Lu), "alpha": scale * fa, "q": scale * 0.3 * fa, **rot}
        fb = sv / V * np.sqrt(2 * V / Lv)
        return {"beta": scale * fb, "p": scale * 0.3 * fb, "r": scale * 0.3 * fb, **rot}
    f = default_process_noise(m, problem.fit)
    return {st: float(scale * v) for st, v in zip(m.states, f) if st in m.outputs}


def _mean_airspeed(problem: Problem) -> float:
    """Mean measured airspeed over the fitted segments (m/s), else the model's constant V."""
    m = problem.model
    if "V" in m.outputs:
        return float(np.nanmean(np.concatenate([s.z[:, m.outputs.index("V")] for s in problem.fit])))
    return float(m.constants.get("V", 30.0))


def _rotary_gust_std(m: Any, V: float, sigma_w: float, L_w: float) -> dict[str, float]:
    """F of the rotary gust states of a gust model (first-order Markov, time constant
    4b/(pi V)): the MIL-F-8785C roll-gust level sigma_w sqrt(0.8 / (L_w b)) (pi L_w / 4b)^(1/6);
    q_gi, the part of the pitch gust not coherent with w_g, at half of it. Not times a
    scale: these states are coloured already (the filters' 2x is for white noise standing in
    for Dryden gusts)."""
    rot = {}
    for st, k in (("p_g", 1.0), ("q_gi", 0.5)):
        if st in m.states:
            b = float(m.constants["b"])
            sg = sigma_w * np.sqrt(0.8 / (L_w * b)) * (np.pi * L_w / (4 * b)) ** (1 / 6)
            rot[st] = k * sg * np.sqrt(2 * np.pi * V / (4 * b))
    return rot


def filter_process_noise(fem: Any, scale: float = 2.0) -> dict[str, float]:
    """EKF/UKF process noise (state -> F, state unit per sqrt(s)) from a filter-error fit of
    the same model: FEM's maximum-likelihood F times ``scale`` (the filters' 2x for white
    noise standing in for coloured gusts, as with the Dryden level), gust states x1. Used
    when no turbulence level is known (a real log), where the data default is far below the
    gusts' level."""
    out = {}
    for name, v in fem.params.items():
        if name.startswith("F_"):
            st = name[2:]
            out[st] = float(v) * (1.0 if st in COLOURED_STATES else scale)
    return out


def filter_param_std(model: Any) -> dict[str, float]:
    """Initial parameter std of the Kalman filters, by free parameter: loose for
    derivatives, twice the start value and at least 0.3 (the initial covariance acts as a
    prior centred on the equation-error start, which a tight one would hold), and a
    sensor-bias scale for the per-segment output biases (0.02 rad/s, 0.3 m/s^2, 0.01 rad,
    1 m/s)."""
    out = {}
    for p in model.parameters:
        if not p.free:
            continue
        if p.name.startswith("bias_"):
            o = p.name[5:]
            out[p.name] = (
                0.02 if o in ("p", "q", "r") else 0.3 if o in ("ax", "ay", "az") else 1.0 if o == "V" else 0.01
            )
        elif p.name.endswith("alphadot"):
            out[p.name] = 10.0  # CLalphadot, Cmalphadot start at 0: no prior pull
        elif p.name == "tau_pg":
            out[p.name] = 0.1 * p.value  # a time constant: UKF sigma points must stay > 0
        else:
            out[p.name] = max(2.0 * abs(p.value), 0.3)
    return out
