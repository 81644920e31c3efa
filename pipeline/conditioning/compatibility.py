"""Data compatibility: flight path reconstruction (DESIGN.md section 8).

The kinematic model (:mod:`pipeline.conditioning.flight_path_model`) integrates the
measured specific forces and body rates (corrected by biases and scale factors) into the
body velocity, attitude and altitude, and predicts what the air-data boom, attitude
reference, barometer and GPS should have measured. The output error method
(``estimators.OutputError``) then estimates the sensor errors with Cramér-Rao bounds, over
several segments sharing the sensor errors, with per-segment initial states. A steady wind
between the air-relative states and the logged inertial velocity can be estimated with
them: a calm-air model would book a wind on the sensors. Which estimates are applied to
the data is the run's compatibility stage (:mod:`pipeline.conditioning.sensor_correction`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from estimators import EKF, UKF, EstimationResult, OutputError, Segment
from estimators.defaults import GAP_FACTOR
from estimators.output_error.pseudo_input_noise import PropagationError, propagated_covariance
from estimators.statistics import difference_noise_std
from pipeline.conditioning.checks import no_forward_flight
from pipeline.conditioning.flight_path_model import (
    ALL_OUTPUTS,
    DEFAULT_ESTIMATE,
    INPUTS,
    MODEL_INPUTS,
    PARAM_STD,
    UNITS,
    WIND_PARAMS,
    kinematic_model,
)
from pipeline.conditioning.sensor_errors import remove_sensor_errors
from pipeline.errors import FsidError
from pipeline.ingest.flightdata import CANONICAL_UNITS, Channel, FlightData, SegmentSpec, merge_overlapping
from pipeline.ingest.sampling import contiguous


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


def _lever(t: np.ndarray, rates: np.ndarray, r: np.ndarray) -> np.ndarray:
    """omega_dot x r + omega x (omega x r) for rates (N, 3) [rad/s]; returns (N, 3) [m/s^2]."""
    wd = np.gradient(rates, t, axis=0)
    return np.cross(wd, r) + np.cross(rates, np.cross(rates, r))


def _shifted(fd: FlightData, channels: Sequence[str], tau: float) -> FlightData:
    """``fd`` with the times of ``channels`` moved earlier by ``tau`` [s] (undoing a delay)."""
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
        pieces = [p for p in _pieces(df[ok].reset_index(drop=True)) if len(p) >= 20]
        for j, df in enumerate(pieces):
            rates = df[["p", "q", "r"]].to_numpy()
            acc = np.gradient(rates, df["t"].to_numpy(), axis=0)
            df[["pdot", "qdot", "rdot"]] = acc
            if np.any(imu_position != 0):
                lev = _lever(df["t"].to_numpy(), rates, imu_position)
                df[["ax", "ay", "az"]] = df[["ax", "ay", "az"]].to_numpy() - lev
            t = df["t"].to_numpy()
            piece = s if len(pieces) == 1 else replace(s, name=f"{s.name}.{j}", t0=float(t[0]), t1=float(t[-1]))
            frames.append((piece, df))
    return frames


def _pieces(df: pd.DataFrame) -> list[pd.DataFrame]:
    """The stretches of a segment's frame between gaps in its time (a gap in the log, or
    samples dropped for a missing input): longer than GAP_FACTOR median intervals, the
    estimators' rule (a model is not integrated across one)."""
    t = df["t"].to_numpy()
    if t.size < 2:
        return [df]
    return [df.iloc[s].reset_index(drop=True) for s in contiguous(t, GAP_FACTOR * float(np.median(np.diff(t))))]


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


@dataclass(frozen=True)
class ReconstructionSettings:
    """How :func:`reconstruct` fits (each field is also a keyword of :func:`reconstruct`).

    segments : spans to use (default: :func:`default_segments`, the log's time ranges, else
        its maneuvers, else its modes, else 20 s pieces, in forward flight); at most
        ``max_segments`` of them
    rate_hz : common rate (default: the IMU rate, at most 100 Hz)
    estimate : names of the free sensor-error parameters
        (:mod:`pipeline.conditioning.flight_path_model`)
    imu_position, boom_position : sensor positions from the CG, body axes [m]
    wind : one steady wind between the air-relative states and vn, ve: True estimates it,
        (north, east) m/s holds it, False (default) is calm air
    method : "oem" (output error, per-segment initial states estimated), "ekf" or "ukf"
        (extended / unscented Kalman filter with the parameters in the state, run over the
        segments in order; initial states from the first samples); ``filter_options`` go to
        ``estimators.EKF`` / ``estimators.UKF``; ``integrator`` and ``max_iter`` to the
        estimator
    delay : how ``delay_air`` (when in ``estimate``) is estimated: "profile" (default) shifts
        the ``delay_channels`` by whole grid steps (exact, no interpolation) and leaves the
        fraction of a step to the model's first-order term y(t - tau) = y - tau dy/dt (its
        Cramér-Rao bound is the delay's); "taylor" uses the first-order term alone (one
        fit, biased for delays that are long against the input's time scale)
    delay_bounds : accepted for callers that pass it; the delay is bounded by the model
    """

    segments: Sequence[SegmentSpec] | None = None
    rate_hz: float | None = None
    estimate: Sequence[str] = DEFAULT_ESTIMATE
    imu_position: Sequence[float] = (0.0, 0.0, 0.0)
    boom_position: Sequence[float] = (0.0, 0.0, 0.0)
    max_segments: int = 8
    integrator: str = "rk4"
    max_iter: int = 50
    delay: str = "profile"
    delay_channels: Sequence[str] = ("V", "alpha", "beta")
    delay_bounds: tuple[float, float] = (-0.05, 0.25)
    method: str = "oem"
    filter_options: Mapping | None = None
    wind: bool | tuple[float, float] = False


def reconstruct(
    data: FlightData | pd.DataFrame | Sequence[pd.DataFrame], settings: ReconstructionSettings | None = None, **options
) -> CompatibilityResult:
    """Flight path reconstruction on ``data`` with the estimators' output-error method (or
    a Kalman filter, ``method``).

    data : FlightData with at least ax ay az p q r and some of V alpha beta phi theta psi h
        vn ve vd, or DataFrame segments with those columns and ``t`` [s] (one segment per
        DataFrame)
    settings, options : :class:`ReconstructionSettings`, its fields given as keywords
        override it; :func:`pipeline.conditioning.sensor_correction.correct_for_estimation`
        keeps an estimated wind when it is significant

    Returns
    -------
    CompatibilityResult (estimates with Cramér-Rao std; ``.corrected(fd)`` applies them).
    """
    s = replace(settings or ReconstructionSettings(), **options)
    segments = s.segments
    if not isinstance(data, FlightData):
        data, df_segs = frames_to_flightdata(data)
        segments = df_segs if segments is None else segments
    outputs, est = _outputs_and_estimate(data, s)
    # windows over the same span (aileron and rudder moved together) once: fitted twice, the
    # data would count twice
    segs = merge_overlapping(default_segments(data) if segments is None else list(segments))[: s.max_segments]
    rate_hz = s.rate_hz
    if rate_hz is None:  # the IMU's sample interval (median: robust to gaps between segments)
        dt = np.diff(data.channels["p"].t)
        dt = dt[dt > 0]
        rate_hz = min(round(1.0 / float(np.median(dt)), 6), 100.0)
    fit = _Fit(
        data,
        segs,
        rate_hz,
        outputs,
        np.asarray(s.imu_position, float),
        kinematic_model(outputs, list(est), s.boom_position, wind=s.wind),
        list(est),
        [c for c in s.delay_channels if c in outputs],
        s,
    )
    if not (s.delay == "profile" and "delay_air" in est):
        res, frames, _ = fit(0.0)
        names = [n for n in est if n in res.params.index]
        params, std = res.params[names].astype(float), res.std[names].astype(float)
        tau_info: dict = {"method": s.delay if "delay_air" in est else "none"}
    else:
        res, frames, params, std, tau_info = _profile_delay(fit, est)
    crb_std = std.copy()
    if s.method not in ("ekf", "ukf"):
        res = _carry_imu_noise(res)
    carried = res.std_method == "propagated"
    if carried:
        std = res.std[std.index].astype(float)
    return CompatibilityResult(
        res,
        params,
        std,
        [sg for sg, _ in frames],
        outputs,
        {
            "rate_hz": rate_hz,
            "imu_position": list(map(float, s.imu_position)),
            "boom_position": list(map(float, s.boom_position)),
            "estimate": list(est),
            "integrator": s.integrator,
            "delay": tau_info,
            "method": s.method,
            "std": "Cramér-Rao with the IMU noise carried through the kinematics" if carried else "Cramér-Rao",
            "wind_mps": {
                n: [float(res.params[n]), float(res.std[n])] for n in res.params.index if n.startswith("wind_")
            },
        },
        crb_std=crb_std,
    )


def _outputs_and_estimate(data: FlightData, s: ReconstructionSettings) -> tuple[list[str], list[str]]:
    """The outputs the log supports (those with too few samples to say anything, < 20 or
    < 1 Hz, left out) and the estimated parameters they can tell; FsidError when the log
    cannot be reconstructed (no fast IMU, no attitude, an unknown method)."""
    miss = data.missing(INPUTS)
    if miss:
        raise FsidError(f"compatibility needs the IMU channels; missing {miss} ({data.explain_missing(miss)})")
    imu_rate = min(data.channels[c].rate_hz for c in INPUTS)
    if imu_rate < 20.0:
        raise FsidError(
            f"compatibility needs the IMU at >= 20 Hz; this log has it at {imu_rate:.1f} Hz (telemetry?) — use the onboard log"
        )
    outputs = [
        c for c in ALL_OUTPUTS if c in data.channels and len(data.channels[c]) >= 20 and data.channels[c].rate_hz >= 1.0
    ]
    if not {"phi", "theta"} <= set(outputs):
        raise FsidError("compatibility needs phi and theta to reconstruct the flight path")
    air = {"V": ["bias_V", "scale_V"], "alpha": ["bias_alpha", "scale_alpha"], "beta": ["bias_beta", "scale_beta"]}
    est = [e for e in s.estimate if not any(e in ps and ch not in outputs for ch, ps in air.items())]
    if not any(c in outputs for c in ("V", "alpha", "beta")):
        est = [e for e in est if e != "delay_air"]
    if s.method not in ("oem", "ekf", "ukf"):
        raise FsidError(f"compatibility method '{s.method}' unknown; use oem, ekf or ukf")
    return outputs, est


@dataclass
class _Fit:
    """One fit of the kinematic ``model`` to ``data`` over ``segs`` on a ``rate_hz`` grid,
    with the delay channels ``dch`` moved earlier by a delay (calling it:
    (estimation result, the segments' frames, negative log-likelihood))."""

    data: FlightData
    segs: list[SegmentSpec]
    rate_hz: float
    outputs: list[str]
    imu_pos: np.ndarray
    model: object
    model_est: list[str]
    dch: list[str]
    s: ReconstructionSettings

    def __call__(self, tau: float, start: Mapping[str, float] | None = None):
        shifted = _shifted(self.data, self.dch, tau)
        frames = _segment_frames(shifted, self.segs, self.rate_hz, self.outputs, self.imu_pos, mask_from=shifted)
        if not frames:
            raise FsidError("compatibility: no segment with enough IMU data (>= 20 samples)")
        eseg = [
            Segment(
                t=df["t"].to_numpy(),
                u=df[MODEL_INPUTS].to_numpy(),
                z=df[self.outputs].to_numpy(),
                x0=_x0(df),
                name=sg.name,
            )
            for sg, df in frames
        ]
        s = self.s
        if s.method in ("ekf", "ukf"):
            opts = {
                "param_std": {n: PARAM_STD[n] for n in self.model_est + WIND_PARAMS},
                "measurement_noise": _noise_levels(frames, self.outputs),
                # initial states come from biased air data: do not trust them too much
                "state_std": {"u": 2.0, "v": 2.0, "w": 2.0, "phi": 0.02, "theta": 0.02, "psi": 0.02, "h": 3.0},
                **dict(s.filter_options or {}),
            }
            st = {n: v for n, v in (start or {}).items() if not n.startswith("x0_")}
            cls = EKF if s.method == "ekf" else UKF
            res = cls(self.model, integrator=s.integrator, **opts).fit(eseg, start=st or None)
        else:
            res = OutputError(self.model, integrator=s.integrator, max_iter=s.max_iter).fit(
                eseg, estimate_x0=True, start=start
            )
        return res, frames, _nll(res)


def _profile_delay(fit: _Fit, est: Sequence[str]):
    """The air-data delay in whole grid steps by shifting the data (exact: samples stay on
    the grid), the remaining fraction of a step by the model's first-order term: (result,
    frames, estimates, std, the delay's document)."""
    rate_hz = fit.rate_hz
    shift = 0
    res, frames, _ = fit(0.0)
    for _ in range(4):
        frac = float(res.params["delay_air"])
        step = int(round(frac * rate_hz))
        if step == 0:
            break
        shift += step
        res, frames, _ = fit(shift / rate_hz, {n: float(v) for n, v in zip(res.names, res.values) if n != "delay_air"})
    names = [n for n in est if n in res.params.index]
    params = res.params[names].astype(float)
    std = res.std[names].astype(float)
    params["delay_air"] = shift / rate_hz + float(res.params["delay_air"])
    tau_info = {
        "method": "grid shift + first-order fraction",
        "shift_s": shift / rate_hz,
        "fraction_s": float(res.params["delay_air"]),
        "channels": fit.dch,
    }
    return res, frames, params, std, tau_info


def _carry_imu_noise(res: EstimationResult) -> EstimationResult:
    """The output-error fit reporting, instead of its Cramér-Rao covariance (kept as a view),
    one that carries the noise of the IMU signals driving the kinematic model
    (:func:`estimators.output_error.pseudo_input_noise.propagated_covariance`): gyro noise
    integrates into the attitude and accelerometer noise into the velocities, which the
    white-residual bound ignores (the gyro biases' bound is then several times too small).
    ``res`` itself (the bound kept) when it cannot be computed."""
    if not getattr(res, "sensitivities", None) or res.information is None:
        return res
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
        return res
    if not np.all(np.isfinite(np.diag(cov))):
        return res
    return res.with_cov(cov, "propagated")


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
