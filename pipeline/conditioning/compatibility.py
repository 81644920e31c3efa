"""Data compatibility: flight path reconstruction (DESIGN.md section 8).

The kinematic model integrates the measured specific forces and body rates (corrected by
biases and scale factors) into the body velocity, attitude and altitude, and predicts what
the air-data boom, attitude reference, barometer and GPS should have measured. The output
error method (``estimators.OutputError``) then estimates the sensor errors with
Cramér-Rao bounds, over several segments sharing the sensor errors, with per-segment
initial states.

States   x = u v w [m/s, body axes, air-relative = inertial in calm air], phi theta psi [rad], h [m]
Inputs   ax ay az [m/s^2] (IMU, moved to the CG with the known IMU position), p q r [rad/s]
Outputs  V alpha beta (at the boom position, delayed by ``delay_air``), phi theta psi, h, vn ve vd

The states are air-relative; the inertial velocity the GPS / navigation filter logs is
theirs plus a steady horizontal wind ``wind_n``, ``wind_e`` [m/s], one for the flight.
:func:`correct_for_estimation` estimates it with the sensor errors and keeps it when it is
significant (else calm air, as before): a calm-air model booked the 6.4 m/s wind of a
windy longitudinal_3211_calm on the sensors (bias_az, scale_az, bias_V, bias_beta,
scale_beta, delay_air "significant" and applied; Cmalpha then 44 std off;
tests/test_flow_angles.py).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from numba.extending import register_jitable

from estimators.statistics import difference_noise_std
from pipeline.errors import FsidError
from pipeline.ingest.flightdata import FlightData, SegmentSpec, merge_overlapping

G0 = 9.80665
STATES = ["u", "v", "w", "phi", "theta", "psi", "h"]
INPUTS = ["ax", "ay", "az", "p", "q", "r"]
#: model inputs: the IMU channels plus angular accelerations [rad/s^2] differentiated from the
#: gyros (used only for the boom velocity derivative in the delay term)
MODEL_INPUTS = INPUTS + ["pdot", "qdot", "rdot"]
ALL_OUTPUTS = ["V", "alpha", "beta", "phi", "theta", "psi", "h", "vn", "ve", "vd"]
IMU_PARAMS = [f"bias_{c}" for c in INPUTS] + [f"scale_{c}" for c in INPUTS]
AIR_PARAMS = ["bias_V", "scale_V", "bias_alpha", "scale_alpha", "bias_beta", "scale_beta", "delay_air"]
#: the steady wind (m/s, NED) between the air-relative states and vn, ve
WIND_PARAMS = ["wind_n", "wind_e"]
#: estimated by default: IMU biases, air-data biases and scale factors, air-data delay
DEFAULT_ESTIMATE = tuple([f"bias_{c}" for c in INPUTS] + AIR_PARAMS)
#: initial std of each parameter for the EKF (SI units)
PARAM_STD = {
    **{f"bias_{c}": 0.5 for c in ("ax", "ay", "az")},
    **{f"bias_{c}": 0.05 for c in ("p", "q", "r")},
    **{f"scale_{c}": 0.1 for c in INPUTS + ["V", "alpha", "beta"]},
    "bias_V": 2.0,
    "bias_alpha": 0.05,
    "bias_beta": 0.05,
    "delay_air": 0.02,
    "wind_n": 10.0,
    "wind_e": 10.0,
}
#: parameter -> its unit (for reports)
UNITS = {
    **{f"bias_{c}": "m/s^2" for c in ("ax", "ay", "az")},
    **{f"bias_{c}": "rad/s" for c in ("p", "q", "r")},
    **{f"scale_{c}": "-" for c in INPUTS + ["V", "alpha", "beta"]},
    "bias_V": "m/s",
    "bias_alpha": "rad",
    "bias_beta": "rad",
    "delay_air": "s",
}


@register_jitable
def _body_kinematics(x, u, p, c):
    """Corrected IMU rates and the body-axis velocity derivatives (m/s^2): the measured
    specific forces and rates with bias and scale factor removed drive u, v, w."""
    uu, vv, ww, phi, theta, psi, h = x
    axm, aym, azm, pm, qm, rm, pd, qd, rd = u
    ax = (axm - p.bias_ax) / (1.0 + p.scale_ax)
    ay = (aym - p.bias_ay) / (1.0 + p.scale_ay)
    az = (azm - p.bias_az) / (1.0 + p.scale_az)
    pr = (pm - p.bias_p) / (1.0 + p.scale_p)
    qr = (qm - p.bias_q) / (1.0 + p.scale_q)
    rr = (rm - p.bias_r) / (1.0 + p.scale_r)
    sph, cph = np.sin(phi), np.cos(phi)
    sth, cth = np.sin(theta), np.cos(theta)
    udot = rr * vv - qr * ww - c.g * sth + ax
    vdot = pr * ww - rr * uu + c.g * cth * sph + ay
    wdot = qr * uu - pr * vv + c.g * cth * cph + az
    return pr, qr, rr, udot, vdot, wdot


def _f(x, u, p, c):
    uu, vv, ww, phi, theta, psi, h = x
    pr, qr, rr, udot, vdot, wdot = _body_kinematics(x, u, p, c)
    sph, cph = np.sin(phi), np.cos(phi)
    sth, cth = np.sin(theta), np.cos(theta)
    phidot = pr + np.tan(theta) * (qr * sph + rr * cph)
    thetadot = qr * cph - rr * sph
    psidot = (qr * sph + rr * cph) / cth
    hdot = uu * sth - vv * sph * cth - ww * cph * cth
    return udot, vdot, wdot, phidot, thetadot, psidot, hdot


def _g(x, u, p, c):
    uu, vv, ww, phi, theta, psi, h = x
    axm, aym, azm, pm, qm, rm, pd, qd, rd = u
    pr, qr, rr, udot, vdot, wdot = _body_kinematics(x, u, p, c)
    sph, cph = np.sin(phi), np.cos(phi)
    sth, cth = np.sin(theta), np.cos(theta)
    sps, cps = np.sin(psi), np.cos(psi)
    # velocity at the boom: v + omega x r_boom
    ub = uu + qr * c.zb - rr * c.yb
    vb = vv + rr * c.xb - pr * c.zb
    wb = ww + pr * c.yb - qr * c.xb
    ubd = udot + qd * c.zb - rd * c.yb
    vbd = vdot + rd * c.xb - pd * c.zb
    wbd = wdot + pd * c.yb - qd * c.xb
    V = np.sqrt(ub * ub + vb * vb + wb * wb)
    alpha = np.arctan2(wb, ub)
    beta = np.arcsin(vb / V)
    Vdot = (ub * ubd + vb * vbd + wb * wbd) / V
    alphadot = (ub * wbd - wb * ubd) / (ub * ub + wb * wb)
    betadot = (vbd * V - vb * Vdot) / (V * np.sqrt(ub * ub + wb * wb))
    Vm = (1.0 + p.scale_V) * (V - p.delay_air * Vdot) + p.bias_V
    am = (1.0 + p.scale_alpha) * (alpha - p.delay_air * alphadot) + p.bias_alpha
    bm = (1.0 + p.scale_beta) * (beta - p.delay_air * betadot) + p.bias_beta
    # NED inertial velocity: air-relative plus the steady wind
    vn = cth * cps * uu + (sph * sth * cps - cph * sps) * vv + (cph * sth * cps + sph * sps) * ww + p.wind_n
    ve = cth * sps * uu + (sph * sth * sps + cph * cps) * vv + (cph * sth * sps - sph * cps) * ww + p.wind_e
    vd = -sth * uu + sph * cth * vv + cph * cth * ww
    return Vm, am, bm, phi, theta, psi, h, vn, ve, vd


def kinematic_model(
    outputs: Sequence[str] = ALL_OUTPUTS,
    estimate: Sequence[str] = DEFAULT_ESTIMATE,
    boom_position: Sequence[float] = (0.0, 0.0, 0.0),
    start: Mapping[str, float] | None = None,
    wind: bool | tuple[float, float] = False,
):
    """The flight-path-reconstruction model as an ``estimators.Model``.

    outputs : subset of ALL_OUTPUTS the data have; estimate : free parameter names;
    boom_position : air-data boom position from the CG, body axes [m]; wind : True: estimate
    the steady wind (wind_n, wind_e, one for the flight) when vn/ve are among the outputs;
    (north, east) m/s: hold it there; False: calm air.
    """
    from estimators import Model, Parameter

    names = IMU_PARAMS + AIR_PARAMS
    bad = [e for e in estimate if e not in names]
    if bad:
        raise FsidError(f"unknown compatibility parameter(s) {bad}; choose from {names}")
    start = dict(start or {})
    params = []
    for n in names:
        lo, hi = (-0.5, 0.5) if n.startswith("scale") else (-0.2, 0.5) if n == "delay_air" else (-np.inf, np.inf)
        params.append(
            Parameter(n, float(start.get(n, 0.0)), free=n in estimate, bounds=(lo, hi), unit=UNITS.get(n, ""))
        )
    held = tuple(wind) if isinstance(wind, (tuple, list)) else (0.0, 0.0)
    free = wind is True and any(c in outputs for c in ("vn", "ve"))
    params += [Parameter(n, float(start.get(n, w0)), free=free, unit="m/s") for n, w0 in zip(WIND_PARAMS, held)]
    xb, yb, zb = (float(v) for v in boom_position)
    model = Model(
        states=STATES,
        inputs=MODEL_INPUTS,
        outputs=list(ALL_OUTPUTS),
        parameters=params,
        constants={"g": G0, "xb": xb, "yb": yb, "zb": zb},
        f=_f,
        g=_g,
        name="flight_path_reconstruction",
    )
    if list(outputs) != list(ALL_OUTPUTS):
        model = model.select_outputs(list(outputs))
    return model


@dataclass
class CompatibilityResult:
    """Estimated sensor errors with Cramér-Rao bounds, and the fit behind them.

    result : the ``estimators.EstimationResult``; params/std : Series by parameter name
    (sensor-error parameters only, SI units, see ``UNITS``); segments : the segments used.
    """

    result: object
    params: pd.Series
    std: pd.Series
    segments: list[SegmentSpec] = field(default_factory=list)
    outputs: list[str] = field(default_factory=list)
    settings: dict = field(default_factory=dict)
    crb_std: pd.Series | None = None  #: conventional Cramér-Rao std (white-residual assumption)

    def table(self, truth: Mapping[str, float] | None = None) -> pd.DataFrame:
        """estimate, std, unit (and truth, error in std units when ``truth`` is given)."""
        df = pd.DataFrame(
            {
                "estimate": self.params,
                "std": self.std,
                "crb_std": self.crb_std if self.crb_std is not None else self.std,
                "unit": [UNITS.get(n, "") for n in self.params.index],
            }
        )
        if truth is not None:
            df["truth"] = [truth.get(n, np.nan) for n in df.index]
            df["error_std"] = (df["estimate"] - df["truth"]) / df["std"]
        return df

    def to_dict(self, truth: Mapping[str, float] | None = None) -> dict:
        tab = self.table(truth)
        res = self.result
        return {
            "status": "ok" if getattr(res, "converged", False) else "not converged",
            "method": self.settings.get("method", "oem"),
            "parameters": {
                n: {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in row.items()}
                for n, row in tab.to_dict("index").items()
            },
            "segments": [s.as_dict() for s in self.segments],
            "outputs": self.outputs,
            "iterations": int(getattr(res, "iterations", 0)),
            "cost": float(getattr(res, "cost", np.nan)),
            "settings": self.settings,
        }

    def corrected(self, fd: FlightData, keep_times: bool = False) -> FlightData:
        """A copy of ``fd`` with the estimated errors removed (:func:`remove_sensor_errors`)."""
        return remove_sensor_errors(fd, self.params, keep_times=keep_times)


def remove_sensor_errors(fd: FlightData, errors: Mapping[str, float], keep_times: bool = False) -> FlightData:
    """A copy of ``fd`` with sensor errors (this module's names: ``bias_<ch>``,
    ``scale_<ch>``, ``delay_air``; missing ones are 0) removed from the measured channels
    (IMU: (x - bias) / (1 + scale); air data also shifted earlier by the delay).

    keep_times : undo the delay by interpolating each air-data channel at t + delay on
        its own sample times (samples whose t + delay lies past the channel's end are
        dropped) instead of moving the time stamps: the channel keeps its sample grid,
        which the estimation's multi-rate frame places slow channels on."""
    from pipeline.ingest.flightdata import Channel

    v = errors
    out = FlightData(dict(fd.channels), dict(fd.meta), list(fd.segments))
    for ch in INPUTS:
        if ch in fd.channels:
            c = fd.channels[ch]
            vals = (c.values - v.get(f"bias_{ch}", 0.0)) / (1.0 + v.get(f"scale_{ch}", 0.0))
            out.channels[ch] = Channel(c.t, vals, c.unit, c.source + " (compatibility-corrected)")
    tau = float(v.get("delay_air", 0.0))
    for ch in ("V", "alpha", "beta"):
        if ch in fd.channels:
            c = fd.channels[ch]
            vals = (c.values - v.get(f"bias_{ch}", 0.0)) / (1.0 + v.get(f"scale_{ch}", 0.0))
            if keep_times and tau != 0.0 and len(c.t) > 1:
                keep = (c.t + tau >= c.t[0]) & (c.t + tau <= c.t[-1])
                out.channels[ch] = Channel(
                    c.t[keep], np.interp(c.t[keep] + tau, c.t, vals), c.unit, c.source + " (compatibility-corrected)"
                )
                continue
            out.channels[ch] = Channel(c.t - tau, vals, c.unit, c.source + " (compatibility-corrected)")
    out.meta["compatibility"] = {k: float(x) for k, x in v.items()}
    return out


def instrument_errors(applied: Mapping[str, Mapping[str, float]]) -> dict[str, float]:
    """Of a compatibility document's ``applied`` errors, those of the instruments that a
    second flight with the same sensors shares: the scale factors and the air-data delay
    (name -> estimate). Biases are left out: they change with every power-up (the proof of
    match fits its own output biases)."""
    return {n: float(d["estimate"]) for n, d in applied.items() if n.startswith("scale_") or n == "delay_air"}


def _lever(t: np.ndarray, rates: np.ndarray, r: np.ndarray) -> np.ndarray:
    """omega_dot x r + omega x (omega x r) for rates (N, 3) [rad/s]; returns (N, 3) [m/s^2]."""
    wd = np.gradient(rates, t, axis=0)
    return np.cross(wd, r) + np.cross(rates, np.cross(rates, r))


def _shifted(fd: FlightData, channels: Sequence[str], tau: float) -> FlightData:
    """``fd`` with the times of ``channels`` moved earlier by ``tau`` [s] (undoing a delay)."""
    from pipeline.ingest.flightdata import Channel

    if tau == 0.0:
        return fd
    chans = dict(fd.channels)
    for c in channels:
        if c in chans:
            ch = chans[c]
            chans[c] = Channel(ch.t - tau, ch.values, ch.unit, ch.source)
    return FlightData(chans, fd.meta, fd.segments)


def _segment_frames(
    fd: FlightData,
    segs: Sequence[SegmentSpec],
    rate_hz: float,
    outputs: list[str],
    imu_position: np.ndarray,
    mask_from: FlightData | None = None,
) -> list[tuple[SegmentSpec, pd.DataFrame]]:
    """Resampled segments; slow outputs are thinned to one grid point per native sample of
    ``mask_from`` (default ``fd``), so a time shift of ``fd`` changes values smoothly."""
    mask_from = mask_from or fd
    frames = []
    tp = fd.channels["p"].t
    for s in segs:
        k = int(np.searchsorted(tp, s.t0))
        if k >= tp.size:
            continue
        df = fd.resample(rate_hz, INPUTS + outputs, t0=float(tp[k]), t1=s.t1, unwrap=True)
        if len(df) < 20:
            continue
        # slower channels: keep only the grid points nearest their own samples (NaN elsewhere),
        # so interpolated values do not pose as independent measurements
        for ch in outputs:
            c = mask_from.channels[ch]
            if c.rate_hz < 0.75 * rate_hz:
                tc = c.t[(c.t >= df["t"].iloc[0]) & (c.t <= df["t"].iloc[-1])]
                # one grid point per native sample; its value is interpolated at the grid time
                keep = np.zeros(len(df), bool)
                idx = np.clip(np.round((tc - df["t"].iloc[0]) * rate_hz).astype(int), 0, len(df) - 1)
                keep[idx] = True
                df.loc[~keep, ch] = np.nan
        inp = df[INPUTS].to_numpy()
        ok = np.all(np.isfinite(inp), axis=1)
        df = df[ok].reset_index(drop=True)
        if len(df) < 20:
            continue
        rates = df[["p", "q", "r"]].to_numpy()
        acc = np.gradient(rates, df["t"].to_numpy(), axis=0)
        df[["pdot", "qdot", "rdot"]] = acc
        if np.any(imu_position != 0):
            lev = _lever(df["t"].to_numpy(), rates, imu_position)
            df[["ax", "ay", "az"]] = df[["ax", "ay", "az"]].to_numpy() - lev
        frames.append((s, df))
    return frames


def _x0(df: pd.DataFrame) -> np.ndarray:
    def first(c, default=0.0):
        if c not in df:
            return default
        v = df[c].to_numpy()
        v = v[np.isfinite(v)]
        return float(v[0]) if v.size else default

    V, a, b = first("V", 20.0), first("alpha"), first("beta")
    return np.array(
        [
            V * np.cos(a) * np.cos(b),
            V * np.sin(b),
            V * np.sin(a) * np.cos(b),
            first("phi"),
            first("theta"),
            first("psi"),
            first("h"),
        ]
    )


def frames_to_flightdata(frames: pd.DataFrame | Sequence[pd.DataFrame]) -> tuple[FlightData, list[SegmentSpec]]:
    """Segments given as DataFrames (column ``t`` [s] and canonical SI columns) -> one
    FlightData with one segment each (later segments moved in time so none overlap)."""
    from pipeline.ingest.flightdata import CANONICAL_UNITS, Channel

    frames = [frames] if isinstance(frames, pd.DataFrame) else list(frames)
    chans: dict[str, list] = {}
    segs: list[SegmentSpec] = []
    end = -np.inf
    for k, df in enumerate(frames):
        if "t" not in df:
            raise FsidError(f"segment DataFrame {k} has no 't' column (time in s)")
        t = df["t"].to_numpy(dtype=float)
        shift = 0.0 if t[0] > end else end - t[0] + 1.0
        t = t + shift
        segs.append(SegmentSpec(f"segment_{k}", float(t[0]), float(t[-1]), "time"))
        end = t[-1]
        for c in df.columns:
            if c != "t":
                v = df[c].to_numpy(dtype=float)
                ok = np.isfinite(v)
                chans.setdefault(c, []).append((t[ok], v[ok]))
    ch = {
        c: Channel(
            np.concatenate([a for a, _ in parts]), np.concatenate([b for _, b in parts]), CANONICAL_UNITS.get(c, "")
        )
        for c, parts in chans.items()
    }
    return FlightData(ch, {"source": "DataFrame segments"}, segs), segs


def default_segments(data: FlightData, span_s: float = 20.0) -> list[SegmentSpec]:
    """The spans a reconstruction uses when none are given: the log's own time ranges
    (kind "time", e.g. ``--segments t0:t1``) as they are; else its maneuvers (kind "auto"),
    else its flight modes of at least 5 s, else the whole log in ``span_s`` pieces - of
    these, the ones in forward flight (:func:`pipeline.conditioning.checks.no_forward_flight`; a span
    whose state is unknown is kept), from the first choice that has any.

    A log that starts with minutes on the ground or mixes hover and wing-borne flight
    (a VTOL) is reconstructed from its flight; raises FsidError when no span is in
    forward flight."""
    from pipeline.conditioning.checks import no_forward_flight

    given = [s for s in data.segments if s.kind == "time"]
    if given:
        return given
    lo, hi = data.span
    edges = np.arange(lo, hi, span_s)
    pieces = [
        SegmentSpec(f"span_{k}", a, min(a + span_s, hi)) for k, a in enumerate(edges) if min(a + span_s, hi) - a >= 5.0
    ]
    why = ""
    for cands in (
        [s for s in data.segments if s.kind == "auto"],
        [s for s in data.segments if s.kind == "mode" and s.duration >= 5],
        pieces,
    ):
        ground = [no_forward_flight(data, s) for s in cands]
        keep = [s for s, (g, _) in zip(cands, ground) if not g]
        if keep:
            return keep
        why = why or next((f"{s.name} {s.t0:.1f}-{s.t1:.1f} s: {w}" for s, (g, w) in zip(cands, ground) if g), "")
    if not why:
        raise FsidError(
            f"compatibility: the log spans {hi - lo:.1f} s, no span of >= 5 s to reconstruct; use a longer log"
        )
    raise FsidError(
        f"compatibility: no span of the log is in forward flight (on the ground or "
        f"hovering; {why}), nothing to reconstruct; give spans in flight with "
        "--segments t0:t1"
    )


def reconstruct(
    data: FlightData | pd.DataFrame | Sequence[pd.DataFrame],
    *,
    segments: Sequence[SegmentSpec] | None = None,
    rate_hz: float | None = None,
    estimate: Sequence[str] = DEFAULT_ESTIMATE,
    imu_position: Sequence[float] = (0.0, 0.0, 0.0),
    boom_position: Sequence[float] = (0.0, 0.0, 0.0),
    max_segments: int = 8,
    integrator: str = "rk4",
    max_iter: int = 50,
    delay: str = "profile",
    delay_channels: Sequence[str] = ("V", "alpha", "beta"),
    delay_bounds: tuple[float, float] = (-0.05, 0.25),
    method: str = "oem",
    filter_options: Mapping | None = None,
    wind: bool | tuple[float, float] = False,
) -> CompatibilityResult:
    """Flight path reconstruction on ``data`` with the estimators' output-error method.

    Parameters
    ----------
    data : FlightData with at least ax ay az p q r and some of V alpha beta phi theta psi h vn ve vd,
        or DataFrame segments with those columns and ``t`` [s] (one segment per DataFrame)
    segments : spans to use (default: :func:`default_segments`, the log's time ranges, else
        its maneuvers, else its modes, else 20 s pieces, in forward flight); at most
        ``max_segments`` of them
    rate_hz : common rate (default: the IMU rate, at most 100 Hz)
    estimate : names of the free sensor-error parameters (module docstring)
    imu_position, boom_position : sensor positions from the CG, body axes [m]
    wind : one steady wind between the air-relative states and vn, ve: True estimates it,
        (north, east) m/s holds it, False (default) is calm air;
        :func:`correct_for_estimation` keeps an estimated one when it is significant
    method : "oem" (output error, per-segment initial states estimated), "ekf" or "ukf"
        (extended / unscented Kalman filter with the parameters in the state, run over the
        segments in order; initial states from the first samples); ``filter_options`` go to
        ``estimators.EKF`` / ``estimators.UKF``
    delay : how ``delay_air`` (when in ``estimate``) is estimated: "profile" (default) shifts
        the ``delay_channels`` by whole grid steps (exact, no interpolation) and leaves the
        fraction of a step to the model's first-order term y(t - tau) = y - tau dy/dt (its
        Cramér-Rao bound is the delay's); "taylor" uses the first-order term alone (one
        fit, biased for delays that are long against the input's time scale)

    Returns
    -------
    CompatibilityResult (estimates with Cramér-Rao std; ``.corrected(fd)`` applies them).
    """
    from estimators import OutputError, Segment

    if not isinstance(data, FlightData):
        data, df_segs = frames_to_flightdata(data)
        segments = df_segs if segments is None else segments
    miss = data.missing(INPUTS)
    if miss:
        raise FsidError(f"compatibility needs the IMU channels; missing {miss} ({data.explain_missing(miss)})")
    imu_rate = min(data.channels[c].rate_hz for c in INPUTS)
    if imu_rate < 20.0:
        raise FsidError(
            f"compatibility needs the IMU at >= 20 Hz; this log has it at {imu_rate:.1f} Hz (telemetry?) — use the onboard log"
        )
    # outputs with too few samples to say anything (< 20, or < 1 Hz) are left out
    outputs = [
        c for c in ALL_OUTPUTS if c in data.channels and len(data.channels[c]) >= 20 and data.channels[c].rate_hz >= 1.0
    ]
    if not {"phi", "theta"} <= set(outputs):
        raise FsidError("compatibility needs phi and theta to reconstruct the flight path")
    air = {"V": ["bias_V", "scale_V"], "alpha": ["bias_alpha", "scale_alpha"], "beta": ["bias_beta", "scale_beta"]}
    est = [e for e in estimate if not any(e in ps and ch not in outputs for ch, ps in air.items())]
    if not any(c in outputs for c in ("V", "alpha", "beta")):
        est = [e for e in est if e != "delay_air"]
    if method not in ("oem", "ekf", "ukf"):
        raise FsidError(f"compatibility method '{method}' unknown; use oem, ekf or ukf")
    # windows over the same span (aileron and rudder moved together) once: fitted twice, the
    # data would count twice
    segs = merge_overlapping(default_segments(data) if segments is None else list(segments))[:max_segments]
    if rate_hz is None:  # the IMU's sample interval (median: robust to gaps between segments)
        dt = np.diff(data.channels["p"].t)
        dt = dt[dt > 0]
        rate_hz = min(round(1.0 / float(np.median(dt)), 6), 100.0)
    imu_pos = np.asarray(imu_position, float)
    profile = delay == "profile" and "delay_air" in est
    model_est = list(est)
    model = kinematic_model(outputs, model_est, boom_position, wind=wind)
    dch = [c for c in delay_channels if c in outputs]

    def fit(tau: float, start: Mapping[str, float] | None = None):
        shifted = _shifted(data, dch, tau)
        frames = _segment_frames(shifted, segs, rate_hz, outputs, imu_pos, mask_from=shifted)
        if not frames:
            raise FsidError("compatibility: no segment with enough IMU data (>= 20 samples)")
        eseg = [
            Segment(
                t=df["t"].to_numpy(), u=df[MODEL_INPUTS].to_numpy(), z=df[outputs].to_numpy(), x0=_x0(df), name=s.name
            )
            for s, df in frames
        ]
        if method in ("ekf", "ukf"):
            from estimators import EKF, UKF

            opts = {
                "param_std": {n: PARAM_STD[n] for n in model_est + WIND_PARAMS},
                "measurement_noise": _noise_levels(frames, outputs),
                # initial states come from biased air data: do not trust them too much
                "state_std": {"u": 2.0, "v": 2.0, "w": 2.0, "phi": 0.02, "theta": 0.02, "psi": 0.02, "h": 3.0},
                **dict(filter_options or {}),
            }
            st = {n: v for n, v in (start or {}).items() if not n.startswith("x0_")}
            cls = EKF if method == "ekf" else UKF
            res = cls(model, integrator=integrator, **opts).fit(eseg, start=st or None)
        else:
            res = OutputError(model, integrator=integrator, max_iter=max_iter).fit(eseg, estimate_x0=True, start=start)
        return res, frames, _nll(res)

    if not profile:
        res, frames, _ = fit(0.0)
        names = [n for n in est if n in res.params.index]
        params, std = res.params[names].astype(float), res.std[names].astype(float)
        tau_info: dict = {"method": delay if "delay_air" in est else "none"}
    else:
        # whole grid steps by shifting the data (exact: samples stay on the grid), the
        # remaining fraction of a step by the first-order term of the model
        shift = 0
        res, frames, _ = fit(0.0)
        for _ in range(4):
            frac = float(res.params["delay_air"])
            step = int(round(frac * rate_hz))
            if step == 0:
                break
            shift += step
            res, frames, _ = fit(
                shift / rate_hz, {n: float(v) for n, v in zip(res.names, res.values) if n != "delay_air"}
            )
        names = [n for n in est if n in res.params.index]
        params = res.params[names].astype(float)
        std = res.std[names].astype(float)
        params["delay_air"] = shift / rate_hz + float(res.params["delay_air"])
        tau_info = {
            "method": "grid shift + first-order fraction",
            "shift_s": shift / rate_hz,
            "fraction_s": float(res.params["delay_air"]),
            "channels": dch,
        }
    crb_std = std.copy()
    carried = method not in ("ekf", "ukf") and _carry_imu_noise(res)
    if carried:
        std = res.std[std.index].astype(float)
    return CompatibilityResult(
        res,
        params,
        std,
        [s for s, _ in frames],
        outputs,
        {
            "rate_hz": rate_hz,
            "imu_position": list(map(float, imu_position)),
            "boom_position": list(map(float, boom_position)),
            "estimate": list(est),
            "integrator": integrator,
            "delay": tau_info,
            "method": method,
            "std": "Cramér-Rao with the IMU noise carried through the kinematics" if carried else "Cramér-Rao",
            "wind_mps": {
                n: [float(res.params[n]), float(res.std[n])] for n in res.params.index if n.startswith("wind_")
            },
        },
        crb_std=crb_std,
    )


def _carry_imu_noise(res) -> bool:
    """Replace the output-error fit's Cramér-Rao covariance (kept in extra["crb_cov"]) by one
    that carries the noise of the IMU signals driving the kinematic model
    (:func:`estimators.output_error.pseudo_input_noise.propagated_covariance`): gyro noise integrates
    into the attitude and accelerometer noise into the velocities, which the white-residual
    bound ignores (scenarios/default.toml: gyro-bias std 2.3-2.7x the bound; bias_p had been
    applied at 3.3 of those on an error-free flight, 1.8 std with the IMU noise carried, fsid demo).
    False (the bound kept) when it cannot be computed."""
    from estimators.output_error.pseudo_input_noise import PropagationError, propagated_covariance

    if not getattr(res, "sensitivities", None) or res.information is None:
        return False
    try:
        cov, _ = propagated_covariance(
            res.model,
            res.segments,
            res.params.to_dict(),
            res.sensitivities,
            [r.to_numpy(dtype=float) for r in res.residuals],
            res.R,
            res.information,
            [],
            noisy_inputs=INPUTS,
            prior_info=(res.extra or {}).get("prior_information"),
        )
    except (PropagationError, ValueError, np.linalg.LinAlgError):
        return False
    if not np.all(np.isfinite(np.diag(cov))):
        return False
    res.replace_cov(cov, "propagated")
    return True


def _noise_levels(frames, outputs: Sequence[str]) -> dict[str, float]:
    """Measurement-noise std of each output from its own samples: std of second differences
    / sqrt(6) (white noise on a smooth signal), pooled over segments."""
    sd = difference_noise_std([np.column_stack([df[c].to_numpy(dtype=float) for c in outputs]) for _, df in frames])
    return {c: max(float(v), 1e-6) if np.isfinite(v) else 1.0 for c, v in zip(outputs, sd)}


def _nll(res) -> float:
    """Negative log-likelihood (up to a constant) of an OEM fit with diagonal R:
    sum over outputs of N_j/2 ln(mean squared residual_j), NaN samples excluded."""
    e = pd.concat(res.residuals, ignore_index=True)
    total = 0.0
    for c in e.columns:
        v = e[c].to_numpy()
        v = v[np.isfinite(v)]
        if v.size:
            total += 0.5 * v.size * np.log(np.mean(v * v))
    return float(total)


def applied_correlation(res: CompatibilityResult) -> dict:
    """Correlation matrix of a reconstruction's sensor-error estimates (JSON-ready:
    ``names``, ``matrix``), from its fit's covariance (with the IMU noise carried,
    :func:`_carry_imu_noise`, when it could be); the identity for names the fit does not
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


def truth_errors(truth: Mapping) -> dict[str, float]:
    """Injected sensor errors of a ``truth.json`` document in this module's parameter names."""
    s = truth.get("sensors", {})
    out: dict[str, float] = {}
    imu, air = s.get("imu", {}), s.get("airdata", {})
    for ch in INPUTS:
        out[f"bias_{ch}"] = float(imu.get("bias", {}).get(ch, 0.0))
        out[f"scale_{ch}"] = float(imu.get("scale_factor", {}).get(ch, 0.0))
    for ch in ("V", "alpha", "beta"):
        out[f"bias_{ch}"] = float(air.get("bias", {}).get(ch, 0.0))
        out[f"scale_{ch}"] = float(air.get("scale_factor", {}).get(ch, 0.0))
    out["delay_air"] = float(air.get("delay_s", 0.0))
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
        from estimators.errors import EstimationError

        if isinstance(exc, EstimationError):
            return {"status": "failed", "reason": f"{type(exc).__name__}: {exc}"}, None
        raise
    return res.to_dict(), res


def residual_to_noise(res: CompatibilityResult) -> dict[str, float]:
    """Per output: std of the reconstruction's residuals / the output's measurement-noise
    std (std of second differences / sqrt(6) over the fitted samples). About 1 when the
    kinematic model explains the data down to the noise (measured 0.93-1.00 on every output
    of sensor_errors_calm); well above 1 on air data in turbulence or wind, which the
    calm-air model does not have (alpha 3.6, beta 2.2 on longitudinal_3211_turbulence)."""
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


#: what the main run estimates: every IMU bias and scale factor and every air-data error
#: (the default set without the IMU scale factors booked sensor_errors_calm's 1 % az
#: scale factor on bias_az, 82 std off)
RUN_ESTIMATE = tuple(IMU_PARAMS + AIR_PARAMS)
#: a sensor error is applied to the data only when |estimate| >= SIGNIFICANCE * std
SIGNIFICANCE = 3.0
#: ... and only when no air-data output's residual std exceeds ADEQUACY x its noise std
#: (:func:`residual_to_noise`): otherwise the calm-air kinematic model does not explain the
#: air data (turbulence, wind) and books the gusts on the sensor errors (on
#: longitudinal_3211_turbulence, without this gate: scale_alpha -25 %, bias_V -3.3 m/s
#: "significant" and applied, truth 0)
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
       :func:`_carry_imu_noise`): an estimate indistinguishable from zero is not applied, since applying
       it would only add its estimation noise to the data. None is applied when the fit
       does not explain the air data: an air-data output (V, alpha, beta) with residuals
       above ``ADEQUACY`` (1.5) times its noise level (turbulence or wind, which the
       calm-air kinematic model lacks, would otherwise be booked as sensor errors).
    3. When some are present, reconstruct again with only those free and the others held
       at zero, so that correlated errors take up what the held ones carried (over the
       narrow airspeed range of a flight, bias_V and scale_V are nearly one parameter: with
       bias_V held, scale_V carries the whole airspeed error), and apply that refit's
       estimates: IMU (x - bias) / (1 + scale), air data likewise and read ``delay_air``
       earlier on their own sample times (``CompatibilityResult.corrected(keep_times=True)``).
    4. Nothing present, the fit not converged, or the stage impossible (no forward flight,
       missing channels): the data go to estimation as logged, and the document says why.

    Measured on the built-in scenarios: sensor_errors_calm - the 13 injected errors the
    flight can show applied (bias_V is carried by scale_V), nothing else; default and
    unstable_short_period - nothing applied; the two turbulence scenarios - nothing applied
    (air-data residuals 2.2-6.2 x noise); false positives on error-free calm flights:
    lateral_doublets_calm bias_az/scale_az (nearly collinear at 1 g, cancelling to < 0.01
    m/s^2). With the plain Cramér-Rao std longitudinal_3211_calm and default had bias_p
    applied too (3.3-3.4 std, 0.008 deg/s); with the IMU noise carried it is 1.8 std (fsid demo).
    On default's error-free flight.mcap (benchmarks/correction_uncertainty_mc.py
    --scenario scenarios/default.toml, seeds 1-12; ad hoc over seeds 1-48) every sensor
    error's estimate / std has rms 0.83-1.17 but bias_ay's: mean -1.9, applied on 3 of 12
    flights (3.5-3.8 std). That is the Coriolis force of JSBSim's rotating Earth, which this
    flat-Earth model lacks: JSBSim's own truth leaves dv/dt - (p w - r u + g cos(theta)
    sin(phi) + ay) at a mean 0.0032 m/s^2 = 2 Omega V sin(47 deg) (the horizontal part is
    always across the track; at latitude 0 bias_ay's mean is -0.25 and bias_az's +1.2).
    Applied, it stands in for that force (a real IMU feels it too). scale_ay and
    delay_air had been over-dispersed too (rms 1.9 and 1.7) until the reconstruction
    stopped fitting the cross-controlled rudder doublets twice (one window per surface over
    the same span: :func:`pipeline.ingest.flightdata.merge_overlapping`); with them, scale_ay was
    applied at 4.7 "std" on one flight and the lateral output error put CYbeta 3.8 std off.

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
    import time

    t0 = time.perf_counter()
    rule = (
        f"a sensor error is applied when |estimate| >= {threshold:g} std in the fit with all "
        f"errors free and that fit leaves the air-data residuals within {ADEQUACY:g} x their "
        "noise level; the applied values come from a refit with only those free"
    )
    kw = {"imu_position": imu_position, "boom_position": boom_position, **kw}
    # a steady wind is estimated first; indistinguishable from calm (every component within
    # ``threshold`` std of zero), the calm-air fit is used: the same rule as the sensor errors.
    # A wind given (the air-data-angle stage's, for a log without vanes, where the cross wind
    # of a straight flight is unobservable here: 5.7 +- 18 m/s, not converged) is held
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
    sig = {
        n: abs(row["estimate"]) / row["std"]
        for n, row in doc["parameters"].items()
        if row.get("std")
        and np.isfinite(row["std"])
        and row["std"] > 0
        and abs(row["estimate"]) >= threshold * row["std"]
    }
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
        # the kinematic model has no gusts, and without vanes no air-data residual shows
        # them: on a windy longitudinal_3211_turbulence it found bias_ax and scale_ax
        # significant (truth 0) and put the cross wind 3 m/s off with a 0.2 m/s std
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
        sig = {}
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
    for n, row in doc["parameters"].items():
        row["applied"] = n in sig
    if untrusted:
        doc["seconds"] = time.perf_counter() - t0
        return doc, fd
    if not sig:
        doc["note"] = f"no sensor error distinguishable from zero (all |estimate| < {threshold:g} std)"
        doc["seconds"] = time.perf_counter() - t0
        return doc, fd
    try:
        refit = reconstruct(fd, estimate=list(sig), **kw)
    except Exception as exc:  # noqa: BLE001 - a failed refit must not cost the run
        doc["note"] = f"refit with the significant errors failed ({type(exc).__name__}: {exc}): no correction applied"
        doc["seconds"] = time.perf_counter() - t0
        return doc, fd
    if not getattr(refit.result, "converged", False):
        doc["note"] = "refit with the significant errors did not converge: no correction applied"
        doc["seconds"] = time.perf_counter() - t0
        return doc, fd
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
    doc["seconds"] = time.perf_counter() - t0
    return doc, refit.corrected(fd, keep_times=True)
