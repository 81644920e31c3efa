"""From canonical flight data to estimation problems: models, segments, start values.

This is where the pipeline decides, for one axis of one flight, which built-in model to
fit, with which constants (from an aircraft description), on which time segments (the
maneuvers found in the log), from which start values (an equation-error regression on the
same data), and which maneuver is held out for proof of match.

Longitudinal: the nonlinear model of :mod:`estimators.models.longitudinal` observing
V, alpha, theta, q, ax, az (angular acceleration is not measured by loggers), with the
air-data and IMU positions as constants, per-segment initial states and per-segment
biases on q, ax, az. Thrust (N) comes from a ``thrust`` channel when the log has one,
else from ``throttle * max_thrust``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

from estimators import Segment
from estimators.models import lateral_directional, longitudinal
from estimators.models.lateral import lateral_measured_longitudinal
from estimators.models.longitudinal import longitudinal_measured_lateral
from estimators.simulation.integrators import DEFAULT_INPUTS
from pipeline.conditioning.checks import slow_airspeed
from pipeline.conditioning.flow_angles import rebuilt
from pipeline.conditioning.input_sampling import step_spans
from pipeline.conditioning.input_smoothing import smooth_columns, smoothed_control_inputs, zero_phase
from pipeline.errors import FsidError
from pipeline.ingest.flightdata import FlightData, SegmentSpec, fit_grid_rate, merge_overlapping

#: derivatives estimated by default for the longitudinal axis
LONG_FREE = ("CD0", "CDalpha", "CDalpha2", "CL0", "CLalpha", "CLq", "CLde", "Cm0", "Cmalpha", "Cmq", "Cmde")
LONG_OUTPUTS = ("V", "alpha", "theta", "q", "ax", "az")
LONG_CHANNELS = ("V", "alpha", "theta", "q", "ax", "az", "de")
#: measured lateral-directional variables that drive the longitudinal model of multi-axis
#: maneuvers (longitudinal_problem(measured_lateral=True))
LONG_PSEUDO_LATERAL = ("beta", "p", "r", "phi", "ay")
#: derivatives estimated by default for the lateral-directional axes
LAT_FREE = (
    "CYbeta",
    "CYp",
    "CYr",
    "CYda",
    "CYdr",
    "Clbeta",
    "Clp",
    "Clr",
    "Clda",
    "Cldr",
    "Cnbeta",
    "Cnp",
    "Cnr",
    "Cnda",
    "Cndr",
)
LAT_OUTPUTS = ("beta", "p", "r", "phi", "ay")
LAT_CHANNELS = ("V", "alpha", "theta", "beta", "p", "r", "phi", "ay", "da", "dr")
G0 = 9.80665


@dataclass
class AircraftConstants:
    """What the models need to know about the aircraft (SI units).

    mass (kg), Ixx Iyy Izz Ixz (kg m^2), S (m^2), b, cbar (m), max_thrust (N, thrust =
    throttle * max_thrust when the log has no thrust channel), sensor positions from the
    CG in body axes (m): ``airdata`` and ``imu`` as (x, y, z).
    """

    mass: float
    Ixx: float
    Iyy: float
    Izz: float
    Ixz: float
    S: float
    b: float
    cbar: float
    max_thrust: float | None = None
    airdata: tuple[float, float, float] = (0.0, 0.0, 0.0)
    imu: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_truth(cls, truth: Mapping[str, Any]) -> AircraftConstants:
        """From a run's truth.json dictionary (aircraft + sensor positions)."""
        ac = truth["aircraft"]
        sensors = truth.get("sensors", {})

        def pos(name):
            s = sensors.get(name, {}) or {}
            return tuple(float(v) for v in s.get("position_m", s.get("position", (0, 0, 0))))

        g = ac.get("geometry", ac)
        m = ac.get("mass", ac)
        prop = ac.get("propulsion", ac)
        return cls(
            mass=_num(m, "mass_kg", "mass"),
            Ixx=_num(m, "Ixx_kgm2", "Ixx"),
            Iyy=_num(m, "Iyy_kgm2", "Iyy"),
            Izz=_num(m, "Izz_kgm2", "Izz"),
            Ixz=_num(m, "Ixz_kgm2", "Ixz"),
            S=_num(g, "S_m2", "S"),
            b=_num(g, "b_m", "b"),
            cbar=_num(g, "cbar_m", "cbar"),
            max_thrust=_num(prop, "max_thrust_N", "max_thrust", default=None),
            airdata=pos("airdata"),
            imu=pos("imu"),
        )

    @classmethod
    def from_aircraft(cls, aircraft: Any, sensors: Mapping[str, Sequence[float]] | None = None) -> AircraftConstants:
        """From a :class:`sim.Aircraft` (an aircraft TOML) and optional sensor positions."""
        d = aircraft.to_dict()
        return cls.from_truth(
            {"aircraft": d, "sensors": {k: {"position_m": list(v)} for k, v in (sensors or {}).items()}}
        )


def _num(d: Mapping[str, Any], *keys: str, default: Any = ...) -> Any:
    for k in keys:
        if k in d and d[k] is not None:
            return float(d[k])
    if default is not ...:
        return default
    raise FsidError(f"aircraft description has no {keys[0]!r}: add it (SI units) to the aircraft TOML")


def isa_density(h: np.ndarray | float) -> np.ndarray:
    """ISA air density (kg/m^3) at geometric altitude h (m), troposphere."""
    T = 288.15 - 0.0065 * np.asarray(h, dtype=float)
    return 1.225 * (T / 288.15) ** 4.2559


def isa_altitude(rho: float) -> float:
    """The altitude (m) of the ISA troposphere where the air density is ``rho`` (kg/m^3):
    the inverse of :func:`isa_density`."""
    return float((1.0 - (max(rho, 1e-3) / 1.225) ** (1.0 / 4.2559)) * 288.15 / 0.0065)


@dataclass
class Problem:
    """One estimation problem: a model, the segments it is fitted to, held-out segments."""

    axis: str
    model: Any
    fit: list[Segment]
    held_out: list[Segment]
    specs: list[SegmentSpec]
    held_specs: list[SegmentSpec]
    estimate_x0: bool | Sequence[str] = True
    inputs: str = DEFAULT_INPUTS
    notes: list[str] = field(default_factory=list)
    #: equation-error regressions on the fitted windows (:class:`Regression`)
    regressions: list[Regression] = field(default_factory=list)
    #: grid rate of the segments (Hz)
    rate_hz: float = 0.0
    #: a-priori values {parameter: (value, std)} for output error (OutputError(priors=))
    priors: dict[str, tuple[float, float]] = field(default_factory=dict)
    #: measurement-noise std per output on this grid, from the log's native samples
    #: (pipeline.jobs.run.attach_logged_noise); outputs not in it use the grid's own estimate
    noise_std: dict[str, float] = field(default_factory=dict)
    #: the control-input steps between slow samples of the flight the segments come from,
    #: input -> [(start, end, std or None), ...] s (pipeline.conditioning.input_sampling.step_times)
    step_times: dict[str, list[tuple[float, float, float | None]]] = field(default_factory=dict)
    #: per held-out segment, those of its own flight when they come from other flights
    #: (pipeline.jobs.run.with_validation_flight); empty: ``step_times`` for each
    held_step_times: list[dict[str, list[tuple[float, float, float | None]]]] = field(default_factory=list)

    def held_out_step_times(self) -> list[dict[str, list[tuple[float, float, float | None]]]]:
        """The control-input steps between slow samples of each held-out segment's flight."""
        return list(self.held_step_times) or [self.step_times] * len(self.held_out)


def thrust_signal(df: pd.DataFrame, ac: AircraftConstants) -> np.ndarray:
    if "thrust" in df and df["thrust"].notna().all():
        return df["thrust"].to_numpy()
    if "throttle" in df and ac.max_thrust:
        return df["throttle"].to_numpy() * ac.max_thrust
    raise FsidError(
        "the log has neither a thrust channel nor throttle with a known max_thrust: "
        "add [propulsion] max_thrust_N to the aircraft description"
    )


#: highest grid rate for estimation; faster channels are low-pass filtered down to it
MAX_RATE_HZ = 200.0
#: outputs a control input reaches without dynamics (the control forces on the
#: accelerometers): left out where the fits' input is a ramp standing in for a step between
#: two slow samples (:func:`pipeline.conditioning.input_sampling.step_spans`)
FEEDTHROUGH_OUTPUTS = ("ax", "ay", "az")


def multirate_frame(
    fd: FlightData, outputs: Sequence[str], others: Sequence[str], rate_hz: float | None = None
) -> tuple[pd.DataFrame, float]:
    """Measurements on one uniform grid without inventing samples.

    The grid runs at the fastest output channel's rate, or a whole multiple of it that
    reaches MIN_GRID_HZ (:func:`pipeline.ingest.flightdata.fit_grid_rate`, at most MAX_RATE_HZ),
    or at ``rate_hz``. Output channels at that rate are resampled as usual; slower output
    channels keep only their native samples and are NaN in between, so the likelihood
    counts every real measurement once and no interpolated one (the estimators give NaN
    samples zero weight): each native sample goes to its nearest grid time, with the
    channel's value interpolated there (at most half a grid step from the sample; two
    samples on one grid time count once). Samples that do not fall on the grid - a GPS
    at 5 Hz on a 25 Hz attitude's grid with another phase, telemetry timestamps with
    jitter - are all kept: when only those within a quarter step were (before), a
    MAVLink telemetry log at 3.8-4.3 Hz kept 2-8 of its 26-41 pitch-rate samples per
    maneuver. ``others`` (inputs, air density, ...) are interpolated to every grid time.
    The accelerometers (FEEDTHROUGH_OUTPUTS) are NaN at grid times inside a control-input
    step's span (:func:`pipeline.conditioning.input_sampling.step_spans`). Returns (frame, rate).
    """
    rates = {c: fd[c].rate_hz for c in outputs}
    rate = float(rate_hz or fit_grid_rate(max(rates.values()), MAX_RATE_HZ))
    fast = [c for c in outputs if rates[c] >= 0.9 * rate]
    df = fd.resample(rate, list(fast) + [c for c in others if c in fd])
    t = df["t"].to_numpy()
    for c in outputs:
        if c in fast:
            continue
        ch = fd[c]
        idx = np.rint((ch.t - t[0]) * rate).astype(np.int64)
        idx = np.unique(idx[(idx >= 0) & (idx < t.size)])
        col = np.full(t.size, np.nan)
        col[idx] = np.interp(t[idx], ch.t, ch.values)
        df[c] = col
    spans = step_spans(fd.meta)
    blank = [c for c in outputs if c in FEEDTHROUGH_OUTPUTS]
    if spans and blank:
        a, b = np.array(spans).T
        marks = np.zeros(t.size + 1, dtype=np.int64)  # +1 where a span opens, -1 where it closes
        np.add.at(marks, np.searchsorted(t, a, side="right"), 1)
        np.add.at(marks, np.searchsorted(t, b, side="left"), -1)
        df.loc[np.cumsum(marks)[:-1] > 0, blank] = np.nan  # grid times strictly inside a span
    return df, rate


def _first_valid(w: pd.DataFrame, cols: Sequence[str]) -> np.ndarray:
    """First non-NaN value of each column (initial states from multi-rate data)."""
    return np.array([w[c].dropna().iloc[0] for c in cols])


def _window(df: pd.DataFrame, spec: SegmentSpec) -> pd.DataFrame:
    w = df[(df["t"] >= spec.t0) & (df["t"] <= spec.t1)]
    return w.reset_index(drop=True)


def _window_fault(
    w: pd.DataFrame, s: SegmentSpec, outputs: Sequence[str], others: Sequence[str], airborne: bool = True
) -> str | None:
    """What makes window ``w`` of segment ``s`` unusable - fewer than 10 rows, an output
    with fewer than 10 samples (outputs may be slower than the grid: NaN between their
    samples), another channel (an input) with any NaN, and with ``airborne`` an airspeed
    column below 5 m/s (:func:`pipeline.conditioning.checks.slow_airspeed`: a control check on the
    ground, a hover) - or None."""
    bad = [k for k in outputs if w[k].notna().sum() < 10] + [k for k in others if w[k].isna().any()]
    if len(w) < 10 or bad:
        return f"segment {s.name} ({s.t0:.2f}-{s.t1:.2f} s) has gaps or NaN in {bad}"
    if airborne and "V" in w:
        slow, why = slow_airspeed(w["V"].dropna().to_numpy())
        if slow:
            return f"segment {s.name} ({s.t0:.2f}-{s.t1:.2f} s) is on the ground or hovering ({why})"
    return None


def usable_segments(
    df: pd.DataFrame,
    specs: Sequence[SegmentSpec],
    outputs: Sequence[str],
    others: Sequence[str],
    hold_out: int,
    what: str,
    airborne: bool = True,
) -> tuple[list[SegmentSpec], list[str], dict[int, pd.DataFrame]]:
    """(the segments of ``specs`` whose windows are usable, a note for each one left out,
    their rows of ``df`` by ``id(spec)``): the one place that cuts segment windows out of the
    multi-rate frame.
    Found segments (automatic or by flight mode) that are not - a maneuver detected in a
    hover without forward flight for the rebuilt air-data angles, a telemetry dropout, and
    with ``airborne`` (the aircraft models) one on the ground or hovering - are left out and
    named, so that the others are still fitted; a segment given by time range (kind
    "time") ends with one clear error naming what is missing (the airspeed rule aside: a
    range the user chose is fitted as given). FsidError when fewer than 1 + ``hold_out``
    remain (``what``: the maneuvers, for the message)."""
    keep, faults, frames = [], [], {}
    for s in specs:
        w = _window(df, s)
        fault = _window_fault(w, s, outputs, others, airborne and s.kind != "time")
        if fault is None:
            keep.append(s)
            frames[id(s)] = w
        elif s.kind == "time":
            raise FsidError(f"{fault}: cut it or fix the log")
        else:
            faults.append(fault)
    if len(keep) < 1 + hold_out:
        more = f"; and {len(faults) - 2} more" if len(faults) > 2 else ""
        raise FsidError(
            f"found {len(specs)} {what} segment(s), {len(keep)} usable, but need at "
            f"least {1 + hold_out} (one to fit, {hold_out} to hold out)"
            + (f" - {'; '.join(faults[:2])}{more}" if faults else "")
            + ": fly more maneuvers or give segments by time range"
        )
    return keep, [f"{f}: left out" for f in faults], frames


def with_smoothed_inputs(
    frames: Mapping[int, pd.DataFrame],
    specs: Sequence[SegmentSpec],
    smoothed: pd.DataFrame | None,
    cols: Sequence[str],
    *,
    relative: bool = False,
) -> None:
    """Put the columns ``cols`` of ``smoothed`` (the flight's grid with its control inputs
    low-passed, :func:`pipeline.conditioning.input_smoothing.smoothed_control_inputs`) into each window
    of ``frames`` in place, relative to the window's first sample when ``relative``. The
    equation-error regressions and starts are built before, from the logged samples: they
    filter every signal of their linear relation alike. Nothing to do when ``smoothed``
    is None (no input had a noise floor to remove)."""
    if smoothed is None or not cols:
        return
    for s in specs:
        w, sm = frames[id(s)], _window(smoothed, s)[list(cols)]
        w[list(cols)] = (sm - sm.iloc[0] if relative else sm).to_numpy()


class Regression(NamedTuple):
    """One equation-error regression on the maneuver windows: the coefficient, the
    parameter names of X's columns (None: an intercept that is no model parameter), X
    (N, k), y (N,) and the window (N,) each row comes from (0, 1, ... in the order given:
    the maneuver clusters of estimators.validation.cluster)."""

    coef: str
    names: list
    X: np.ndarray
    y: np.ndarray
    window: np.ndarray


def _window_rows(parts: Sequence[np.ndarray]) -> np.ndarray:
    """The window index of each row of the stacked ``parts``."""
    return np.concatenate([np.full(len(a), k) for k, a in enumerate(parts)]) if parts else np.zeros(0, int)


def longitudinal_regressions(
    frames: Sequence[pd.DataFrame], c: Mapping[str, float], thrusts: Sequence[np.ndarray]
) -> list[Regression]:
    """Equation-error regressions of the longitudinal coefficients on the maneuver windows:
    CL, CD, Cm computed from the measured specific forces and the differentiated pitch rate,
    regressed on [1, alpha, q cbar/2V, de] (CL, Cm) and [1, alpha, alpha^2] (CD), NaN rows
    removed."""
    rows = {"L": [], "D": [], "M": []}
    yL, yD, yM = [], [], []
    xv, zv = c.get("x_vane", 0.0), c.get("z_vane", 0.0)
    yv = c.get("y_vane", 0.0)
    xi, zi = c.get("x_imu", 0.0), c.get("z_imu", 0.0)
    for df, T in zip(frames, thrusts):
        t = df["t"].to_numpy()
        Vv, av, q, de = (df[k].to_numpy() for k in ("V", "alpha", "q", "de"))
        qdot = np.gradient(q, t)
        # air data and accelerations moved from the sensors to the CG: the vane reads
        # alpha - q x_vane / V, which a regression would book on CLq/Cmq (CLalpha x_vane
        # 2/cbar: +29 on CLq of uav_small) - the inverse of the model's sensor terms
        u = Vv * np.cos(av) - q * zv
        w = Vv * np.sin(av) + q * xv
        if yv and "p" in df and "r" in df:  # wing-tip boom: + p y_vane in w, - r y_vane in u
            u = u + df["r"].to_numpy() * yv
            w = w - df["p"].to_numpy() * yv
        V, a = np.hypot(u, w), np.arctan2(w, u)
        ax = df["ax"].to_numpy() - qdot * zi + q * q * xi
        az = df["az"].to_numpy() + qdot * xi + q * q * zi
        qbar = 0.5 * c["rho"] * V**2
        CX = (c["m"] * ax - T) / (qbar * c["S"])
        CZ = c["m"] * az / (qbar * c["S"])
        CL = -CZ * np.cos(a) + CX * np.sin(a)
        CD = -CX * np.cos(a) - CZ * np.sin(a)
        Cm = c["Iyy"] * qdot / (qbar * c["S"] * c["cbar"])
        qh = q * c["cbar"] / (2 * V)
        one = np.ones_like(a)
        rows["L"].append(np.column_stack([one, a, qh, de]))
        yL.append(CL)
        rows["D"].append(np.column_stack([one, a, a * a]))
        yD.append(CD)
        rows["M"].append(np.column_stack([one, a, qh, de]))
        yM.append(Cm)
    out = []
    for key, coef, y, names in (
        ("L", "CL", yL, ["CL0", "CLalpha", "CLq", "CLde"]),
        ("D", "CD", yD, ["CD0", "CDalpha", "CDalpha2"]),
        ("M", "Cm", yM, ["Cm0", "Cmalpha", "Cmq", "Cmde"]),
    ):
        X = np.vstack(rows[key])
        Y = np.concatenate(y)
        ok = np.all(np.isfinite(X), axis=1) & np.isfinite(Y)
        out.append(Regression(coef, names, X[ok], Y[ok], _window_rows(rows[key])[ok]))
    return out


def longitudinal_starts(
    frames: Sequence[pd.DataFrame], c: Mapping[str, float], thrusts: Sequence[np.ndarray]
) -> dict[str, float]:
    """Equation-error start values: least squares of CL, CD, Cm computed from the measured
    specific forces and the differentiated pitch rate on the maneuver windows."""
    sol = {}
    for _, names, X, Y, _ in longitudinal_regressions(frames, c, thrusts):
        beta = np.linalg.lstsq(X, Y, rcond=None)[0]
        sol.update(zip(names, beta))
    # keep the signs that make a flyable start (stable pitch damping, positive lift slope)
    sol["Cmq"] = min(sol["Cmq"], -1.0)
    sol["Cmalpha"] = min(sol["Cmalpha"], -0.05)
    sol["CLalpha"] = max(sol["CLalpha"], 1.0)
    return {k: float(v) for k, v in sol.items()}


#: problem note when a gust model measures a rebuilt angle as the rigid body's
KINEMATIC_NOTE = (
    "{angle} rebuilt from the flight path (no vane) is measured as {state}, the "
    "rigid body's angle against the mean wind: it carries no gust"
)


def longitudinal_problem(
    fd: FlightData,
    ac: AircraftConstants,
    *,
    rate_hz: float | None = None,
    segments: Sequence[SegmentSpec] | None = None,
    hold_out: int = 1,
    free: Sequence[str] = LONG_FREE,
    biases: Sequence[str] = ("q", "ax", "az"),
    measured_lateral: bool = False,
    rotary_gust: bool = False,
    values: Mapping[str, float] | None = None,
    smooth_inputs: bool = True,
) -> Problem:
    """Build the longitudinal problem from flight data.

    segments : windows to use (default: the log's segments whose axis is 'de' or
        'throttle'); the last ``hold_out`` elevator windows are kept for proof of match.
    measured_lateral : fit :func:`longitudinal_measured_lateral` instead, with the
        measured beta, p, r, phi, ay as inputs (low-pass filtered like the lateral
        model's pseudo-inputs) and the air data at the boom's full (x, y, z) position:
        for maneuvers that move all three axes at once.
    rotary_gust : with ``measured_lateral``: the model's gust states (the rotary gust
        q_g from the vertical gust and its own Markov part in the pitch damping; for the
        filters, whose process noise drives them).
    values : derivative values that override the equation-error starts (held ones stay
        at them: e.g. a-priori CLalphadot, Cmalphadot).
    smooth_inputs : the segments' elevator low-passed where its noise floor begins
        (:mod:`pipeline.conditioning.input_smoothing`); False: as logged.
    """
    channels = LONG_CHANNELS + (LONG_PSEUDO_LATERAL if measured_lateral else ())
    missing = fd.missing(channels)
    if missing:
        raise FsidError(
            f"longitudinal identification needs channels {missing} that the log "
            f"does not provide ({fd.meta.get('source', 'log')}); add them to the "
            "channel map (--map) or choose another model"
        )
    specs = list(
        segments
        if segments is not None
        else merge_overlapping([s for s in fd.segments if s.axis in ("de", "throttle")])
    )
    if len(specs) < 1 + hold_out:
        raise FsidError(
            f"found {len(specs)} longitudinal maneuver segment(s) but need at least "
            f"{1 + hold_out} (one to fit, {hold_out} to hold out): fly more elevator "
            "maneuvers or give segments by time range"
        )
    df, rate_hz = multirate_frame(
        fd,
        LONG_OUTPUTS,
        ["de", "throttle", "thrust", "rho", "h"] + (list(LONG_PSEUDO_LATERAL) if measured_lateral else []),
        rate_hz,
    )
    smoothed, input_note = smoothed_control_inputs(fd, df, rate_hz, ("de",) if smooth_inputs else ())
    rho = mean_density(df)
    c = {
        "m": ac.mass,
        "Iyy": ac.Iyy,
        "S": ac.S,
        "cbar": ac.cbar,
        "rho": rho,
        "x_vane": ac.airdata[0],
        "z_vane": ac.airdata[2],
        "x_imu": ac.imu[0],
        "z_imu": ac.imu[2],
    }
    if measured_lateral:
        c.update({"Ixx": ac.Ixx, "Izz": ac.Izz, "Ixz": ac.Ixz, "y_vane": ac.airdata[1], "b": ac.b})
    rotary_gust = rotary_gust and measured_lateral
    if rotary_gust:
        c["kin_angles"] = float(rebuilt(fd, "alpha"))
    outs = [k for k in channels if k in LONG_OUTPUTS]
    others = [k for k in channels if k not in LONG_OUTPUTS]
    specs, left_out, frames = usable_segments(df, specs, outs, others, hold_out, "longitudinal maneuver")
    elev = [s for s in specs if s.axis == "de"]
    held = elev[-hold_out:] if hold_out else []
    fit_specs = [s for s in specs if s not in held]
    thrust = {id(s): thrust_signal(frames[id(s)], ac) for s in specs}
    regs = longitudinal_regressions([frames[id(s)] for s in fit_specs], c, [thrust[id(s)] for s in fit_specs])
    start = longitudinal_starts([frames[id(s)] for s in fit_specs], c, [thrust[id(s)] for s in fit_specs])
    start.update(values or {})
    with_smoothed_inputs(frames, specs, smoothed, ["de"])
    if measured_lateral:
        model = longitudinal_measured_lateral(
            c, values=start, free=free, output_biases=biases, name="longitudinal-measured", rotary_gust=rotary_gust
        ).select_outputs(LONG_OUTPUTS)
        for s in specs:
            frames[id(s)] = smooth_pseudo_inputs(frames[id(s)], rate_hz, LONG_PSEUDO_CORNER_HZ)
    else:
        model = longitudinal(c, values=start, free=free, output_biases=biases, name="longitudinal").select_outputs(
            LONG_OUTPUTS
        )
    ucols = ["de"] + (list(LONG_PSEUDO_LATERAL) if measured_lateral else [])

    def density(w):
        """Air density along the window (the measured-lateral model's input rho): the
        log's rho channel, else ISA at the measured altitude, else the flight mean."""
        for col, fn in (("rho", lambda x: x), ("h", isa_density)):
            if col in w and w[col].notna().all():
                return fn(w[col].to_numpy(dtype=float))
        return np.full(len(w), rho)

    def seg(s):
        w = frames[id(s)]
        x0 = list(_first_valid(w, ["V", "alpha", "theta", "q"]))
        if rotary_gust:  # alpha_k = alpha (no gust at the start), lags 0
            x0 += [x0[1], 0.0, 0.0]
        u = np.column_stack(
            [w["de"], thrust[id(s)]] + [w[k] for k in ucols[1:]] + ([density(w)] if measured_lateral else [])
        )
        return Segment(t=w["t"].to_numpy(), u=u, z=w[list(LONG_OUTPUTS)].to_numpy(), x0=x0, name=s.name)

    notes = (
        (
            [
                f"measured beta, p, r, phi, ay as inputs (the lateral motion as flown); air data at "
                f"({ac.airdata[0]:g}, {ac.airdata[1]:g}, {ac.airdata[2]:g}) m"
            ]
            if measured_lateral
            else []
        )
        + [
            f"grid {rate_hz:g} Hz; slower channels at their own samples only",
            f"density {rho:.4f} kg/m^3 (mean over the flight)",
            f"thrust from {'thrust channel' if 'thrust' in df else 'throttle x max_thrust'}",
            "start values from equation error: " + ", ".join(f"{k}={v:.3g}" for k, v in start.items()),
        ]
        + ([input_note] if input_note else [])
        + left_out
    )
    if not {"CLalphadot", "Cmalphadot"} & set(free):
        notes.append(
            "CLalphadot, Cmalphadot held at 0: without gusts to separate them, the "
            "angle-of-attack rate moves with q, so CLq and Cmq carry their effect "
            "(Cmq estimates about Cmq + Cmalphadot)"
        )
    return Problem(
        "longitudinal",
        model,
        [seg(s) for s in fit_specs],
        [seg(s) for s in held],
        fit_specs,
        held,
        estimate_x0=["V", "alpha", "theta", "q"] if rotary_gust else True,
        notes=notes
        + (
            [
                "vertical gust in the states (Dryden shaping filters): "
                "rotary gust q_g = -s/(1 + tau s) alpha_g + q_gi in the pitch "
                "damping"
            ]
            if rotary_gust
            else []
        )
        + ([KINEMATIC_NOTE.format(angle="alpha", state="alpha_k")] if rotary_gust and c["kin_angles"] else []),
        regressions=regs,
        rate_hz=rate_hz,
    )


#: zero-phase low-pass corner (Hz) of the lateral equation-error regressions
LATERAL_LS_CORNER_HZ = 3.0


def _filled(df: pd.DataFrame, k: str) -> np.ndarray:
    """Column k with NaN gaps (a slow channel between its samples) linearly interpolated."""
    x = df[k].to_numpy(dtype=float)
    ok = np.isfinite(x)
    if ok.all() or ok.sum() < 2:
        return x
    t = df["t"].to_numpy()
    return np.interp(t, t[ok], x[ok])


def lateral_regressions(frames: Sequence[pd.DataFrame], c: Mapping[str, float]) -> list[Regression]:
    """Equation-error regressions: CY (from ay), Cl and Cn (from the differentiated roll and
    yaw rates with the inertia coupling) on [1, beta, p b/2V, r b/2V, da, dr]; the intercept
    column is named None (no model parameter). The dynamic pressure and b/2V follow the
    measured airspeed sample by sample (column ``V`` when the frames have it, else the
    constant ``c["V"]``), as the airspeed wanders during cross-controlled sideslips.
    Columns ``V_kin``, ``beta_kin`` (:mod:`pipeline.conditioning.airdata_kinematics`), when present,
    replace the measured airspeed and sideslip: vane noise on the beta regressor (errors
    in variables, nearly collinear with dr and r in cross-controlled maneuvers) put CYbeta
    10 %, CYdr 15 %, Cndr 20 % off. Slow outputs (NaN between their samples) are
    interpolated, then every signal is low-passed at LATERAL_LS_CORNER_HZ."""
    X, Y = [], {"CY": [], "Cl": [], "Cn": []}
    for df in frames:
        t = df["t"].to_numpy()
        kin = "beta_kin" in df and "V_kin" in df
        beta, p, r, da, dr, ay = (_filled(df, k) for k in ("beta_kin" if kin else "beta", "p", "r", "da", "dr", "ay"))
        rate = (t.size - 1) / (t[-1] - t[0])
        V = _filled(df, "V_kin" if kin else "V") if "V" in df else np.full(t.size, c["V"])
        if not np.all(np.isfinite(V)):
            V = np.full(t.size, c["V"])
        elif not kin:
            V = zero_phase(V, rate, PSEUDO_INPUT_CORNER_HZ["V"])
        # one zero-phase low-pass on every signal of the linear relation (the response
        # differentiated after it): np.gradient of the raw rates averages the fast roll
        # response at each surface step over two samples while the steps in da, dr stay
        # sharp (Cl, Cn 5-7 % low, Cnp 16 %, on the noise-free truth of
        # lateral_doublets_calm; 0.2-0.4 % with the common filter)
        beta, p, r, da, dr, ay = (zero_phase(x, rate, LATERAL_LS_CORNER_HZ) for x in (beta, p, r, da, dr, ay))
        qbar = 0.5 * c["rho"] * V**2
        pdot, rdot = np.gradient(p, t), np.gradient(r, t)
        # vane and IMU readings moved to the CG (inverse of the model's sensor terms; the
        # kinematic sideslip is at the CG already)
        if not kin:
            beta = beta - (r * c.get("x_vane", 0.0) - p * c.get("z_vane", 0.0)) / V
        ay = ay - rdot * c.get("x_imu", 0.0) + pdot * c.get("z_imu", 0.0)
        L = c["Ixx"] * pdot - c["Ixz"] * rdot
        N = c["Izz"] * rdot - c["Ixz"] * pdot
        k = c["b"] / (2 * V)
        # rows about 4 per corner period apart: the filtered residuals are nearly white
        # there, so the OLS covariance s^2 (X^T X)^-1 is not 4x too optimistic
        rate = (t.size - 1) / (t[-1] - t[0]) if t.size > 1 else 1.0
        keep = slice(None, None, max(1, int(rate / (4.0 * LATERAL_LS_CORNER_HZ))))
        X.append(np.column_stack([np.ones_like(p), beta, p * k, r * k, da, dr])[keep])
        Y["CY"].append((c["m"] * ay / (qbar * c["S"]))[keep])
        Y["Cl"].append((L / (qbar * c["S"] * c["b"]))[keep])
        Y["Cn"].append((N / (qbar * c["S"] * c["b"]))[keep])
    A = np.vstack(X)
    window = _window_rows(X)
    out = []
    for coef, ys in Y.items():
        y = np.concatenate(ys)
        ok = np.all(np.isfinite(A), axis=1) & np.isfinite(y)
        names = [None] + [f"{coef}{n}" for n in ("beta", "p", "r", "da", "dr")]
        out.append(Regression(coef, names, A[ok], y[ok], window[ok]))
    return out


def lateral_starts(
    frames: Sequence[pd.DataFrame], c: Mapping[str, float], regressions: Sequence | None = None
) -> dict[str, float]:
    """Equation-error start values: least squares of CY (from ay), Cl and Cn (from the
    differentiated roll and yaw rates with the inertia coupling) on the maneuver windows
    (``regressions``: those of :func:`lateral_regressions` when already formed)."""
    out: dict[str, float] = {}
    for _, names, A, y, _ in regressions if regressions is not None else lateral_regressions(frames, c):
        sol = np.linalg.lstsq(A, y, rcond=None)[0]
        for name, v in zip(names[1:], sol[1:]):
            out[name] = float(v)
    # flyable start: directional stability, roll and yaw damping of the usual sign
    out["Cnbeta"] = max(out["Cnbeta"], 0.01)
    out["Clp"] = min(out["Clp"], -0.05)
    out["Cnr"] = min(out["Cnr"], -0.01)
    return out


def lateral_specs(
    fd: FlightData, channels: Sequence[str], segments: Sequence[SegmentSpec] | None, hold_out: int
) -> list[SegmentSpec]:
    """The aileron/rudder windows of a lateral problem (default: the log's 'da' and 'dr'
    segments), after checking the log has ``channels`` and enough maneuvers to fit and
    hold out ``hold_out``."""
    missing = fd.missing(channels)
    if missing:
        raise FsidError(
            f"lateral identification needs channels {missing} that the log does not "
            f"provide ({fd.meta.get('source', 'log')}); add them to the channel map"
        )
    specs = list(
        segments if segments is not None else merge_overlapping([s for s in fd.segments if s.axis in ("da", "dr")])
    )
    if len(specs) < 1 + hold_out:
        raise FsidError(
            f"found {len(specs)} aileron/rudder maneuver segment(s) but need at least "
            f"{1 + hold_out}: fly more doublets or give segments by time range"
        )
    return specs


def multi_axis(fd: FlightData) -> bool:
    """Whether the log's elevator windows overlap aileron or rudder windows in time
    (maneuvers on all axes at once, e.g. 3-axis multisines)."""
    lon = [s for s in fd.segments if s.axis == "de"]
    lat = [s for s in fd.segments if s.axis in ("da", "dr")]
    return any(a.t0 < b.t1 and b.t0 < a.t1 for a in lon for b in lat)


#: derivatives freed in addition on multi-axis flights for the filters (gust-state models)
MULTIAXIS_FILTER_FREE = {"longitudinal": ("CLalphadot", "Cmalphadot"), "lateral": ("tau_pg",)}


def multiaxis_problem(
    fd: FlightData,
    ac: AircraftConstants,
    axis: str,
    *,
    gust_states: bool,
    rate_hz: float | None = None,
    smooth_inputs: bool = True,
    hold_out: int = 1,
) -> Problem:
    """The axis problem for maneuvers that move all axes at once, and for the filters in
    turbulence whatever the maneuvers (pipeline.jobs.run's _method_problem): the model of that axis
    driven by the other axis' measured variables (longitudinal_measured_lateral /
    lateral_measured_longitudinal), air data at the boom's full position. ``gust_states``
    (the filters, in turbulence): the Dryden gust states of the models (rotary gusts q_g,
    p_g in the damping terms), with CLalphadot, Cmalphadot (longitudinal; identifiable once
    the gust angle of attack separates alphadot from q: |corr(Cmq, Cmalphadot)| 0.33 on
    multiaxis_multisine_turbulence) and the roll-gust time constant tau_pg (lateral) free."""
    extra = MULTIAXIS_FILTER_FREE[axis] if gust_states else ()
    if axis == "longitudinal":
        return longitudinal_problem(
            fd,
            ac,
            rate_hz=rate_hz,
            measured_lateral=True,
            rotary_gust=gust_states,
            free=LONG_FREE + extra,
            smooth_inputs=smooth_inputs,
            hold_out=hold_out,
        )
    return lateral_problem(
        fd,
        ac,
        rate_hz=rate_hz,
        measured_longitudinal=True,
        rotary_gust=gust_states,
        free=LAT_FREE + extra,
        smooth_inputs=smooth_inputs,
        hold_out=hold_out,
    )


def mean_density(df: pd.DataFrame) -> float:
    """Mean air density (kg/m^3) of the flight: the rho channel, else ISA at the measured
    altitude, else sea level."""
    if "rho" in df:
        return float(np.nanmean(df["rho"]))
    return float(np.nanmean(isa_density(df["h"]))) if "h" in df else 1.225


#: zero-phase low-pass corner (Hz) of the measured longitudinal variables that drive the
#: lateral model as inputs: noise on an input is not in the output-error likelihood
PSEUDO_INPUT_CORNER_HZ = {"V": 1.0, "alpha": 5.0, "theta": 5.0, "q": 5.0}
#: likewise for the measured lateral variables that drive the longitudinal model
LONG_PSEUDO_CORNER_HZ = {"beta": 5.0, "p": 5.0, "r": 5.0, "phi": 5.0, "ay": 2.0}


def smooth_pseudo_inputs(w: pd.DataFrame, rate_hz: float, corners: Mapping[str, float] | None = None) -> pd.DataFrame:
    """V, alpha, theta, q of a window (or the channels of ``corners``) low-pass filtered
    forwards and backwards (second-order Butterworth at PSEUDO_INPUT_CORNER_HZ) before
    they drive the lateral model."""
    return smooth_columns(w, rate_hz, corners or PSEUDO_INPUT_CORNER_HZ)


def airspeed_window_std(fd: FlightData, segments: Sequence[Segment]) -> tuple[float, list[float]]:
    """(sigma_V, [std of the mean pitot-noise error over each segment]) in m/s.

    sigma_V, the pitot's white-noise level, from its own samples: the second difference
    V[j+1] - 2 V[j] + V[j-1] of white noise has variance 6 sigma^2, and the airspeed's own
    curvature over two pitot samples is negligible. The pseudo-input V is that noise
    interpolated to the grid and low-passed (PSEUDO_INPUT_CORNER_HZ, zero phase); both have
    unit gain at zero frequency, so they leave the window MEAN of the noise as it was: the
    mean of n independent samples, std sigma_V / sqrt(n), n = f_s T the pitot samples in
    the window (the noise in the band 0..f_s/2 has 2 B T = f_s T degrees of freedom over
    T; the low-pass only removes the fluctuation about the mean). Exact operator on
    lateral_doublets_calm (interpolation + filtfilt with its even padding, 5 s at 50 Hz):
    0.0196 m/s against 0.0195 from sigma / sqrt(n). Pitot noise coloured below the
    window's bandwidth (drift, pressure-sensor 1/f) is not in this figure."""
    ch = fd["V"]
    t, v = np.asarray(ch.t, dtype=float), np.asarray(ch.values, dtype=float)
    ok = np.isfinite(t) & np.isfinite(v)
    t, v = t[ok], v[ok]
    sigma = float(np.sqrt(np.var(np.diff(v, 2)) / 6.0)) if v.size > 3 else 0.0
    sds = []
    for s in segments:
        n = int(np.count_nonzero((t >= s.t[0]) & (t <= s.t[-1])))
        sds.append(sigma / np.sqrt(max(n, 1)))
    return sigma, sds


def with_airspeed_offsets(problem: Problem, fd: FlightData) -> Problem:
    """The lateral-measured problem with a per-segment airspeed correction dV[k] on the
    pseudo-input V (:func:`estimators.models.lateral.with_airspeed_offset`) and the
    a-priori penalty dV[k] ~ N(0, sigma_V / sqrt(n_k)) (:func:`airspeed_window_std`) for
    output error, so that its Cramer-Rao bounds include the pitot noise of the input.

    Why: output error takes inputs as exact; each fitted window's mean airspeed is off by
    sigma_V / sqrt(n) (0.02 m/s, 0.1-0.2 % in dynamic pressure on lateral_doublets_calm,
    while the bounds of the stiff derivatives are 0.03-0.1 %): Cnp, Cnda, Cndr, Clda, Cldr
    3-4 std off on seed 21, Cnbeta 7.8 std on seed 11, against 2.1 with the noise-free V.
    Worst |error|/std on seeds 21, 5, 7, 11, 3, 13, 17: 4.3, 3.0, 1.5, 7.8, 3.7, 7.0, 2.4
    without dV, 2.6, 1.9, 1.9, 2.8, 3.2, 3.5, 2.3 with it; the bounds of Clp, Cnbeta, Cldr
    1.15x, 2.6x, 1.6x wider (0.074, 0.089, 0.076 %). Not covered: the pitot noise's
    fluctuation inside a window (below the 1 Hz corner), which a constant dV[k] leaves
    (seed 13: Clbeta, Clr, Cnbeta, Cnr 3.0-3.5 std)."""
    from dataclasses import replace

    from estimators.models.lateral import with_airspeed_offset

    sigma, sds = airspeed_window_std(fd, problem.fit)
    priors = {f"dV[{k}]": (0.0, float(max(sd, 1e-6))) for k, sd in enumerate(sds)}
    note = (
        f"per-maneuver airspeed correction dV on the pseudo-input V, a priori 0 +- "
        f"sigma_V/sqrt(n) = {min(sds):.3f}-{max(sds):.3f} m/s (pitot noise {sigma:.2f} m/s)"
    )
    return replace(
        problem,
        model=with_airspeed_offset(problem.model),
        priors={**problem.priors, **priors},
        notes=list(problem.notes) + [note],
    )


def lateral_problem(
    fd: FlightData,
    ac: AircraftConstants,
    *,
    rate_hz: float | None = None,
    segments: Sequence[SegmentSpec] | None = None,
    hold_out: int = 1,
    free: Sequence[str] = LAT_FREE,
    biases: Sequence[str] = ("beta", "p", "r", "ay"),
    measured_longitudinal: bool = False,
    rotary_gust: bool = False,
    kinematic: bool = False,
    smooth_inputs: bool = True,
) -> Problem:
    """Build the lateral-directional problem (linear model about the flight's mean
    airspeed, angle of attack and pitch attitude) from the aileron and rudder maneuvers;
    control inputs are taken relative to their value at the start of each window.

    measured_longitudinal : fit :func:`lateral_measured_longitudinal` instead, with the
        measured V, alpha, theta, q as inputs (the linear model's frozen airspeed and
        small bank angles put Clda, Cnda, Cnp, Cnbeta 5-18 std off on
        lateral_doublets_calm, where the doublets bank the UAV by up to 30 deg).
    rotary_gust : with ``measured_longitudinal``: the model's roll-gust state p_g (the
        aerodynamics see p - p_g; for the filters, whose process noise drives it).
    kinematic : with ``measured_longitudinal``: the pseudo-inputs V and alpha are the air
        data blended with the integrated IMU (:mod:`pipeline.conditioning.airdata_kinematics`: pitot
        and vane below 0.1 Hz, the kinematic rates above), not the air data low-passed at
        1 and 5 Hz. For calm-air output error, which takes its inputs as exact: the pitot
        noise between 0.1 and 1 Hz scales every moment of the window (lateral_doublets_calm,
        16 + 16 seeds, benchmarks/lateral_airspeed_mc.py: empirical / Cramer-Rao std of
        the derivatives up to 2.1 and 1.9 with the air data, 1.4 and 1.4 blended; without
        any pitot noise 1.4 and 1.9), and an angle of attack rebuilt from the 10 Hz GPS
        velocity (no vane) puts its noise into the kinematic coupling (8 seeds,
        benchmarks/flow_angles_mc.py: up to 2.7, blended 1.7). In turbulence the blend
        misses the gusts above 0.1 Hz.
    smooth_inputs : the segments' aileron and rudder low-passed where their noise floor
        begins (:mod:`pipeline.conditioning.input_smoothing`); False: as logged."""
    rotary_gust = rotary_gust and measured_longitudinal
    channels = LAT_CHANNELS + (("q",) if measured_longitudinal else ())
    specs = lateral_specs(fd, channels, segments, hold_out)
    df, rate_hz = multirate_frame(
        fd,
        LAT_OUTPUTS,
        ["V", "alpha", "theta", "q", "da", "dr", "rho", "h"]
        if measured_longitudinal
        else ["V", "alpha", "theta", "da", "dr", "rho", "h"],
        rate_hz,
    )
    smoothed, input_note = smoothed_control_inputs(fd, df, rate_hz, ("da", "dr") if smooth_inputs else ())
    rho = mean_density(df)
    outs = [k for k in channels if k in LAT_OUTPUTS]
    others = [k for k in channels if k not in LAT_OUTPUTS]
    specs, left_out, frames = usable_segments(df, specs, outs, others, hold_out, "aileron/rudder maneuver")
    allw = pd.concat(frames.values())
    c = {
        "m": ac.mass,
        "Ixx": ac.Ixx,
        "Izz": ac.Izz,
        "Ixz": ac.Ixz,
        "S": ac.S,
        "b": ac.b,
        "rho": rho,
        "V": float(allw["V"].mean()),
        "alpha0": float(allw["alpha"].mean()),
        "theta0": float(allw["theta"].mean()),
        "x_vane": ac.airdata[0],
        "z_vane": ac.airdata[2],
        "x_imu": ac.imu[0],
        "z_imu": ac.imu[2],
    }
    for s in specs:
        w = frames[id(s)]
        w[["da", "dr"]] = w[["da", "dr"]] - w[["da", "dr"]].iloc[0]
    # airspeed and sideslip at the CG blended with the integrated IMU (V_kin, beta_kin) for
    # the equation-error regressors and, with kinematic, the pseudo-inputs V and alpha
    from pipeline.conditioning.airdata_kinematics import V_CORNER_HZ, kinematic_air_data

    kin = kinematic_air_data(fd, rate_hz, ac.imu, ac.airdata)
    kinematic = kinematic and measured_longitudinal and kin is not None
    if kin is not None:
        for s in specs:
            w = frames[id(s)]
            tw = w["t"].to_numpy()
            w["V_kin"] = np.interp(tw, kin["t"], kin["V"])
            w["beta_kin"] = np.interp(tw, kin["t"], kin["beta"])
            w["alpha_kin"] = np.interp(tw, kin["t"], kin["alpha"])
    both = [s for s in specs]
    held = both[-hold_out:] if hold_out else []
    fit_specs = [s for s in specs if s not in held]
    regs = lateral_regressions([frames[id(s)] for s in fit_specs], c)
    start = lateral_starts([frames[id(s)] for s in fit_specs], c, regs)
    if rotary_gust:  # Dryden roll-gust time constant 4 b / (pi V)
        start["tau_pg"] = 4.0 * ac.b / (np.pi * c["V"])
        c["kin_angles"] = float(rebuilt(fd, "beta"))
    if measured_longitudinal:
        model = lateral_measured_longitudinal(
            {**c, "Iyy": ac.Iyy},
            values=start,
            free=free,
            output_biases=biases,
            name="lateral-measured",
            rotary_gust=rotary_gust,
        )
    else:
        model = lateral_directional(c, values=start, free=free, output_biases=biases, name="lateral").select_outputs(
            LAT_OUTPUTS
        )
    ucols = ["da", "dr", "V", "alpha", "theta", "q"] if measured_longitudinal else ["da", "dr"]
    with_smoothed_inputs(frames, specs, smoothed, ["da", "dr"], relative=True)
    if measured_longitudinal:
        for s in specs:
            if kinematic:
                frames[id(s)]["V"] = frames[id(s)]["V_kin"]
                frames[id(s)]["alpha"] = frames[id(s)]["alpha_kin"]
            frames[id(s)] = smooth_pseudo_inputs(frames[id(s)], rate_hz)

    def seg(s):
        w = frames[id(s)]
        return Segment(
            t=w["t"].to_numpy(),
            u=w[ucols].to_numpy(),
            z=w[list(LAT_OUTPUTS)].to_numpy(),
            x0=list(_first_valid(w, ["beta", "p", "r", "phi"]))
            + ([0.0, float(_first_valid(w, ["beta"])[0]), 0.0] if rotary_gust else []),
            name=s.name,
        )

    notes = [
        (
            f"measured V, alpha, theta, q as inputs, density {rho:.4f} kg/m^3"
            + (
                f" (V, alpha: the air data blended with the integrated IMU, the air data below {V_CORNER_HZ:g} Hz)"
                if kinematic
                else ""
            )
            if measured_longitudinal
            else f"linear model about V={c['V']:.2f} m/s, alpha0={np.degrees(c['alpha0']):.2f} deg, "
            f"theta0={np.degrees(c['theta0']):.2f} deg, density {rho:.4f} kg/m^3"
        ),
        "start values from equation error: " + ", ".join(f"{k}={v:.3g}" for k, v in start.items()),
    ]
    if rotary_gust:
        notes.append("roll-gust state p_g (Dryden, time constant 4b/(pi V)) in the roll damping")
        if c["kin_angles"]:
            notes.append(KINEMATIC_NOTE.format(angle="beta", state="beta_k"))
    if input_note:
        notes.append(input_note)
    notes += left_out
    return Problem(
        "lateral",
        model,
        [seg(s) for s in fit_specs],
        [seg(s) for s in held],
        fit_specs,
        held,
        estimate_x0=["beta", "p", "r", "phi"] if rotary_gust else True,
        notes=notes,
        regressions=regs,
        rate_hz=rate_hz,
    )
