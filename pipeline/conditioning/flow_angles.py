"""Angle of attack and sideslip from the flight path, for logs without vanes.

Most small aircraft fly without an alpha/beta vane; their logs carry the navigation
filter's (or the GPS's) inertial velocity vn, ve, vd, the attitude and the true airspeed.
The air velocity is the inertial velocity minus the wind, turned into body axes by the
attitude:

    (u, v, w) = T_bn(phi, theta, psi) (vn - W_n, ve - W_e, vd)
    alpha = atan2(w, u),  beta = asin(v / |(u, v, w)|)

The wind is horizontal (no vertical wind) and slowly varying: linear between knots every
``window_s`` seconds (one constant wind for flights shorter than 1.5 windows). It is the
least-squares solution of two conditions on every airborne sample:

* the air velocity's magnitude is the measured true airspeed, |vg - W| = V (weight: the
  airspeed residual level): this fixes the wind along the track;
* the sideslip is zero on average, v = 0 (weight: ``beta_std`` x V): this fixes the wind
  across the track when the heading does not change. Turns make both components visible
  to the airspeed condition alone, and the sideslip condition then matters less.

The pitot's scale factor k (airspeed measured as (1 + k) |vg - W|; a pitot bias at the
flight's airspeed looks the same) is estimated with the wind when the headings tell it from
the wind along the track (:func:`fit_wind`, :func:`airspeed_calibration`): a turn of a few
tens of degrees does (std at k = 0 below :data:`SCALE_STD_MAX`; straight flight does not).
Applied when significant (3 std), the V channel becomes V / (1 + k), so the models'
airspeed and dynamic pressure are calibrated too; applied or not, its std is carried to
the estimates with the wind's. A steady sideslip (asymmetric thrust) moves it; with little
heading change its std is large and k is not estimated.

Assumptions, which the document names: no vertical wind (it would shift alpha by W_d / V;
its uncertainty is carried to the estimates,
:func:`pipeline.conditioning.wind_uncertainty.wind_uncertainty`), a mean sideslip of zero
over each window (a steady sideslip, e.g. from asymmetric thrust, is booked on the
cross-track wind), a correct airspeed where the pitot's scale factor cannot be estimated
(it is then booked on the along-track wind), and the inertial velocity at the body
origin, taken as the CG (the navigation filters, ArduPilot's EKF3 and PX4's EKF2, report
it there, having moved the IMU's by its configured offset; the simulator's GPS sits at the
CG): the rebuilt angles are the CG's, and the air-data position for them is (0, 0, 0).
The angles carry the velocity channel's noise and sample times (a 10 Hz GPS gives 10 Hz
angles; the estimators count only those samples, and the filters' common grid drops to
that rate). They hold no gusts: in turbulence they are the rigid body's angles, not the
ones the aerodynamics see, and the airspeed departs from the steady-wind fit
(:func:`unsteady`), which ``fsid estimate`` takes as the sign that the calm-air
sensor-compatibility model does not hold.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from pipeline.errors import FsidError
from pipeline.ingest.flightdata import Channel, FlightData

#: the channels the reconstruction reads
NEEDS = ("vn", "ve", "vd", "phi", "theta", "psi", "V")
#: sideslip spread allowed by the zero-mean-sideslip condition [rad]
BETA_STD = np.deg2rad(2.0)
#: knot spacing of the wind [s]
WINDOW_S = 120.0
#: std [-] of the prior (mean 0) on the pitot's scale factor in the wind fit: a plausible
#: range, weak beside what turning flight tells
SCALE_PRIOR = 0.3
#: the scale factor is estimated with the wind only when its std at 0 is at most this [-]
SCALE_STD_MAX = 0.02
#: ... applied when at least this many std from 0 (as a sensor error in
#: pipeline.conditioning.sensor_correction)
SCALE_SIGNIFICANCE = 3.0
#: ... and within +- this [-] (beyond: implausible for a pitot, something else is wrong)
SCALE_MAX = 0.25


@dataclass
class WindFit:
    """The wind of :func:`fit_wind`: knots (K,) [s], north/east (K,) [m/s] and their
    std (K,) [m/s], airspeed residual rms [m/s], rms sideslip [rad], samples used, the
    airspeed residual's correlation time [s]."""

    knots: np.ndarray
    north: np.ndarray
    east: np.ndarray
    std_north: np.ndarray
    std_east: np.ndarray
    airspeed_rms: float
    beta_rms: float
    n: int
    #: correlation time of the airspeed residual [s] (:func:`correlation_time`)
    airspeed_tau: float = 0.0
    #: the pitot's scale factor k [-] (airspeed measured as (1 + k) x true), estimated or held
    scale: float = 0.0
    #: its std [-], estimated or (held) what it would be if freed there
    std_scale: float = float("nan")
    #: whether ``scale`` was estimated (else held)
    scale_estimated: bool = False

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(north, east) wind [m/s] at times t [s] (linear between knots, constant beyond)."""
        return np.interp(t, self.knots, self.north), np.interp(t, self.knots, self.east)


def _hat_basis(t: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """(n, K) weights of the piecewise-linear interpolation between knots (rows sum to 1;
    one knot: all ones)."""
    eye = np.eye(knots.size)
    return np.stack([np.interp(t, knots, eye[k]) for k in range(knots.size)], axis=1)


def _body_axes(phi: np.ndarray, theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rows = body x, y, z axes in NED (T_bn per sample)."""
    cf, sf, ct, st, cp, sp = (np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi))
    return np.stack(
        [
            np.stack([ct * cp, ct * sp, -st], axis=-1),
            np.stack([sf * st * cp - cf * sp, sf * st * sp + cf * cp, sf * ct], axis=-1),
            np.stack([cf * st * cp + sf * sp, cf * st * sp - sf * cp, cf * ct], axis=-1),
        ],
        axis=1,
    )


def _effective_n(r: np.ndarray) -> float:
    """Sample count of a residual series shrunk for its lag-1 autocorrelation (AR(1))."""
    if r.size < 3:
        return float(r.size)
    r = r - r.mean()
    rho = float(np.dot(r[1:], r[:-1]) / max(np.dot(r, r), 1e-300))
    rho = min(max(rho, 0.0), 0.999)
    return float(r.size * (1.0 - rho) / (1.0 + rho))


def correlation_time(r: np.ndarray, dt: float) -> float:
    """Correlation time [s] of a residual series r (n,) sampled every dt [s]: the lag at
    which its autocorrelation falls to 1/e of the lag-1 value (so that white noise on top,
    which only lowers lag 0, does not shorten it), linear between lags; 0 for a series
    without lag-1 correlation, at most a quarter of its span."""
    r = np.asarray(r, dtype=float) - np.mean(r)
    n = r.size
    if n < 8:
        return 0.0
    m = 1 << int(np.ceil(np.log2(2 * n)))
    f = np.fft.rfft(r, m)
    acf = np.fft.irfft(f * np.conj(f), m)[: n // 4 + 1]
    if acf[1] <= 0.0:
        return 0.0
    below = np.flatnonzero(acf[1:] < acf[1] / np.e)
    if below.size == 0:
        return float((acf.size - 1) * dt)
    k = int(below[0]) + 1  # first lag under acf[1] / e (k >= 2)
    frac = (acf[k - 1] - acf[1] / np.e) / (acf[k - 1] - acf[k])
    return float((k - 2 + frac) * dt)


def fit_wind(
    t: np.ndarray,
    vg: np.ndarray,
    V: np.ndarray,
    axes: np.ndarray,
    *,
    window_s: float = WINDOW_S,
    beta_std: float = BETA_STD,
    iterations: int = 12,
    scale: float | None = 0.0,
) -> WindFit:
    """Horizontal wind from inertial velocity and airspeed (module doc), with the pitot's
    scale factor k (the airspeed measured as (1 + k) |vg - W|) held at ``scale``, or
    estimated with the wind when ``scale`` is None and the flight's headings tell it from
    the wind: its std at k = 0 at most :data:`SCALE_STD_MAX` (else k is held at 0).

    t (n,) [s]; vg (n, 3) inertial NED velocity [m/s]; V (n,) true airspeed [m/s];
    axes (n, 3, 3) body axes in NED (:func:`_body_axes`). Gauss-Newton on the stacked
    airspeed and zero-sideslip residuals, reweighted by each group's rms; the std come
    from the normal matrix with each group's sample count shrunk for its autocorrelation.
    ``WindFit.std_scale`` is k's std, estimated, or (held) what it would be if freed there
    with white residuals (the headings' geometry; at most :data:`SCALE_PRIOR`, a prior that
    keeps it finite without turns).
    """
    if scale is None:
        held = fit_wind(t, vg, V, axes, window_s=window_s, beta_std=beta_std, iterations=iterations)
        if not held.std_scale <= SCALE_STD_MAX:
            return held
        x = np.concatenate([held.north, held.east, [0.0]])  # (north knots, east knots, k)
        knots, B = held.knots, _hat_basis(t, held.knots)
    else:
        knots, B, x = _wind_start(t, vg, V, axes, window_s, scale)
    nk = knots.size
    free = np.arange(2 * nk + (scale is None))  # the columns estimated
    ey = axes[:, 1, :2]  # body y axis, horizontal part
    s_v, s_b = 1.0, beta_std * float(np.median(V))
    for it in range(iterations):
        k = float(x[-1])
        Wn, We = B @ x[:nk], B @ x[nk : 2 * nk]
        va = vg - np.column_stack([Wn, We, np.zeros_like(Wn)])
        mag = np.linalg.norm(va, axis=1)
        r1 = (1.0 + k) * mag - V
        r2 = np.einsum("ij,ij->i", ey, va[:, :2]) + axes[:, 1, 2] * va[:, 2]
        if it >= 2:  # reweight once the fit settled
            s_v = max(float(np.sqrt(np.mean(r1**2))), 1e-3)
        # columns: north knots, east knots, k
        J1 = np.hstack(
            [-(1.0 + k) * (va[:, :1] / mag[:, None]) * B, -(1.0 + k) * (va[:, 1:2] / mag[:, None]) * B, mag[:, None]]
        )
        J2 = np.hstack([-ey[:, :1] * B, -ey[:, 1:2] * B, np.zeros((t.size, 1))])
        J = np.vstack([J1[:, free] / s_v, J2[:, free] / s_b])
        r = np.concatenate([r1 / s_v, r2 / s_b])
        dx = -np.linalg.solve(J.T @ J + 1e-9 * np.eye(free.size), J.T @ r)
        x[free] += dx
        if np.max(np.abs(dx)) < 1e-6:
            break
    # the std: each group's information scaled by its effective/actual sample count; k's
    # prior information keeps its std finite when the headings cannot tell it from the wind
    f1, f2 = _effective_n(r1) / r1.size, _effective_n(r2) / r2.size
    M1, M2 = (J1.T @ J1) / s_v**2, (J2.T @ J2) / s_b**2
    M = f1 * M1 + f2 * M2
    sd = np.sqrt(np.clip(np.diag(np.linalg.pinv(M[np.ix_(free, free)])), 0.0, None))
    if scale is None:
        std_k = float(sd[-1])
    else:  # k freed here, the residuals taken as white: the headings' geometry, not a
        # residual the held k makes coloured
        P = np.linalg.pinv(M1 + M2 + np.diag(np.r_[np.zeros(2 * nk), SCALE_PRIOR**-2]))
        std_k = float(np.sqrt(P[-1, -1]))
    mag = np.maximum(mag, 1e-6)
    return WindFit(
        knots=knots,
        north=x[:nk].copy(),
        east=x[nk : 2 * nk].copy(),
        std_north=sd[:nk],
        std_east=sd[nk : 2 * nk],
        airspeed_rms=float(np.sqrt(np.mean(r1**2))),
        beta_rms=float(np.sqrt(np.mean((r2 / mag) ** 2))),
        n=int(t.size),
        airspeed_tau=correlation_time(r1, float(np.median(np.diff(t)))),
        scale=float(x[-1]),
        std_scale=std_k,
        scale_estimated=scale is None,
    )


def _wind_start(
    t: np.ndarray, vg: np.ndarray, V: np.ndarray, axes: np.ndarray, window_s: float, scale: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The wind's knots (K,) [s] every ``window_s`` over the data (none in a gap), their
    interpolation weights (n, K) and the start of :func:`fit_wind` (north knots, east
    knots, k): zero sideslip and the airspeed, less the scale factor ``scale``, along the
    body x axis's horizontal direction."""
    span = float(t[-1] - t[0])
    nk = 1 if span < 1.5 * window_s else int(np.ceil(span / window_s)) + 1
    knots = np.array([0.5 * (t[0] + t[-1])]) if nk == 1 else np.linspace(t[0], t[-1], nk)
    B = _hat_basis(t, knots)  # (n, K)
    used = B.sum(axis=0) > 0
    if not used.all():  # knots in a gap of the data
        knots = knots[used]
        B = _hat_basis(t, knots)
    ex = axes[:, 0, :2] / np.linalg.norm(axes[:, 0, :2], axis=1, keepdims=True)
    Vh = np.sqrt(np.maximum((V / (1.0 + scale)) ** 2 - vg[:, 2] ** 2, 0.0))
    w0 = np.linalg.lstsq(B, vg[:, :2] - Vh[:, None] * ex, rcond=None)[0]  # (K, 2)
    return knots, B, np.append(w0.T.reshape(-1), float(scale))


#: ``Channel.derived`` of an angle this module rebuilt
REBUILT = "rebuilt from the inertial velocity, attitude and airspeed"


def rebuilt(fd: FlightData, name: str) -> bool:
    """Whether channel ``name`` (alpha, beta) of ``fd`` is an angle rebuilt from the flight
    path: the rigid body's angle against the mean wind, which carries no gust."""
    return name in fd and fd[name].derived == REBUILT


def _at(fd: FlightData, name: str, t: np.ndarray, wrapped: bool = False) -> np.ndarray:
    ch = fd[name]
    v = np.unwrap(ch.values) if wrapped else ch.values
    return np.interp(t, ch.t, v, left=np.nan, right=np.nan)


def reconstruct_flow_angles(
    fd: FlightData,
    *,
    window_s: float = WINDOW_S,
    beta_std: float = BETA_STD,
    wind_offset: Sequence[float] = (0.0, 0.0, 0.0),
    airspeed_scale: float | None = None,
) -> tuple[FlightData, dict[str, Any]]:
    """The flight with the missing ones of alpha, beta reconstructed from the flight path
    (module doc), and a JSON-ready document of what was done. The input is not modified.
    ``wind_offset`` (north, east, down [m/s], airspeed scale [-], the last optional, in
    the order of :data:`pipeline.conditioning.wind_uncertainty.WIND_PARTS`) moves the
    fitted wind before the angles are rebuilt and the pitot's scale factor from where
    :func:`airspeed_calibration` put it (the refits of
    :func:`pipeline.conditioning.wind_uncertainty.wind_uncertainty`; down: a vertical
    wind). ``airspeed_scale`` holds the pitot's scale factor there (another flight's, the
    same pitot) instead of estimating it. Where a scale factor k is used, the V channel
    becomes the calibrated V / (1 + k).

    Nothing to do (both angles logged): the same object and ``{"status": "not needed"}``.
    Raises FsidError naming the missing channels when an angle is missing and the flight
    has no inertial velocity, attitude or airspeed to rebuild it from, or no forward flight.
    """
    todo = fd.missing(("alpha", "beta"))
    if not todo:
        return fd, {"status": "not needed"}
    t, vg, V, heading, axes, vmin = _flight_path(fd, todo)
    dn, de, dd, dk = (list(map(float, wind_offset)) + [0.0])[:4]
    fit = {"window_s": window_s, "beta_std": beta_std}
    tried = None  # the fit that tried to estimate k
    if airspeed_scale is None:
        try:
            tried = fit_wind(t, vg, V, axes, scale=None, **fit)
            cal = airspeed_calibration(tried)
        except np.linalg.LinAlgError as exc:  # the joint fit: k taken as 0, as untold
            cal = {
                "status": "not identifiable",
                "estimate": 0.0,
                "std": float("nan"),
                "applied": False,
                "carried": False,
                "note": f"the airspeed scale factor's fit with the wind failed ({exc}): taken as 0",
            }
    else:
        cal = {"status": "held", "estimate": float(airspeed_scale), "applied": bool(airspeed_scale)}
    k = (cal["estimate"] if cal["applied"] else 0.0) + dk
    # given k: the wind's conditional std (a k the headings could not tell is already that
    # fit, held at 0)
    wind = (
        tried
        if tried is not None and not tried.scale_estimated and k == 0.0
        else fit_wind(t, vg, V, axes, scale=k, **fit)
    )
    Wn, We = wind.at(t)
    va = np.einsum("nij,nj->ni", axes, vg - np.column_stack([Wn + dn, We + de, np.full_like(Wn, dd)]))
    out = _with_angles(fd, todo, t, va, k, cal)
    doc = _document(fd, todo, t, V, heading, vmin, wind, cal)
    if any((dn, de, dd, dk)):
        doc["wind_offset_mps"] = [dn, de, dd]
        doc["airspeed_scale_offset"] = dk
    return out, doc


def _flight_path(
    fd: FlightData, todo: list[str]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """The flight path the angles ``todo`` are rebuilt from, on the velocity's samples in
    forward flight: times t (n,) [s], inertial velocity vg (n, 3) [m/s], airspeed V (n,)
    [m/s], unwrapped heading (n,) [rad], body axes (n, 3, 3) and the airspeed [m/s] that
    counts as forward flight. Raises FsidError without the channels or forward flight."""
    lacking = fd.missing(NEEDS)
    if lacking:
        raise FsidError(
            f"the log has no {'/'.join(todo)} vane and lacks {lacking} to rebuild "
            f"{'them' if len(todo) > 1 else 'it'} from the flight path "
            f"({fd.meta.get('source', 'log')}): add the channels to the map (--map) "
            "or use a model without air-data angles (--model path.py:name)"
        )
    t = np.asarray(fd["vn"].t, dtype=float)
    vg = np.column_stack([_at(fd, c, t) for c in ("vn", "ve", "vd")])
    V = _at(fd, "V", t)
    phi, theta, psi = _at(fd, "phi", t, True), _at(fd, "theta", t), _at(fd, "psi", t, True)
    ok = np.all(np.isfinite(vg), axis=1) & np.isfinite(V + phi + theta + psi)
    vmin = max(3.0, 0.5 * float(np.percentile(V[ok], 95))) if ok.any() else np.inf
    ok &= V >= vmin
    if ok.sum() < 20:
        where = (
            f"in forward flight (airspeed >= {vmin:.1f} m/s)"
            if np.isfinite(vmin)
            else "where airspeed, attitude and the velocity are all logged"
        )
        raise FsidError(
            f"cannot rebuild {'/'.join(todo)} from the flight path: fewer than 20 velocity samples "
            f"{where} in {fd.meta.get('source', 'log')}"
        )
    axes = _body_axes(phi[ok], theta[ok], psi[ok])
    return t[ok], vg[ok], V[ok], np.unwrap(psi[ok]), axes, vmin


def _with_angles(
    fd: FlightData, todo: list[str], t: np.ndarray, va: np.ndarray, k: float, cal: dict[str, Any]
) -> FlightData:
    """A copy of ``fd`` with the angles ``todo`` from the body-axis air velocity ``va``
    (n, 3) [m/s] at times t [s], and V calibrated by the pitot's scale factor k [-]."""
    speed = np.linalg.norm(va, axis=1)
    angles = {"alpha": np.arctan2(va[:, 2], va[:, 0]), "beta": np.arcsin(np.clip(va[:, 1] / speed, -1.0, 1.0))}
    src = f"flight path ({fd['vn'].source or 'vn'}, attitude, V) minus the fitted wind"
    channels = dict(fd.channels)
    for a in todo:
        channels[a] = Channel(
            t=t.copy(),
            values=angles[a],
            unit="rad",
            source=src,
            notes="reconstructed: no vane in the log (pipeline.conditioning.flow_angles)",
            derived=REBUILT,
        )
    if k:
        v = fd["V"]
        channels["V"] = replace(
            v,
            values=v.values / (1.0 + k),
            source=f"{v.source or 'V'} / (1 + {k:.5f})",
            notes=f"calibrated: the pitot's scale factor {100 * k:+.2f} % ({cal['status']}, pipeline.conditioning.flow_angles)",
        )
    return FlightData(channels=channels, meta=dict(fd.meta), segments=list(fd.segments))


def _document(
    fd: FlightData,
    todo: list[str],
    t: np.ndarray,
    V: np.ndarray,
    heading: np.ndarray,
    vmin: float,
    wind: WindFit,
    cal: dict[str, Any],
) -> dict[str, Any]:
    """The JSON-ready document of :func:`reconstruct_flow_angles`."""
    return {
        "status": "reconstructed",
        "channels": todo,
        "rate_hz": float(fd["vn"].rate_hz),
        "samples": int(t.size),
        "airspeed_min_mps": vmin,
        "wind": {
            "t_s": wind.knots.tolist(),
            "north_mps": wind.north.tolist(),
            "east_mps": wind.east.tolist(),
            "std_north_mps": wind.std_north.tolist(),
            "std_east_mps": wind.std_east.tolist(),
        },
        "airspeed_residual_rms_mps": wind.airspeed_rms,
        "airspeed_residual_tau_s": wind.airspeed_tau,
        "airspeed_mean_mps": float(np.mean(V)),
        "airspeed_noise_mps": float(fd.noise_std("V")),
        "sideslip_rms_deg": float(np.rad2deg(wind.beta_rms)),
        "heading_span_deg": float(np.rad2deg(np.ptp(heading))),
        "airspeed_scale": cal,
        "assumptions": "no vertical wind; mean sideslip zero over each wind window; "
        f"{_SCALE_ASSUMED[cal['status']]}; angles at the CG (the navigation "
        "filter's velocity)",
    }


def airspeed_calibration(wind: WindFit) -> dict[str, Any]:
    """What the rebuilt angles take as the pitot's scale factor, from a wind fit that tried
    to estimate it (``fit_wind(scale=None)``), as a JSON-ready document: ``status``
    "estimated" (the headings tell it from the wind: its std, at k = 0 with white
    residuals and as estimated, at most :data:`SCALE_STD_MAX`) or "not identifiable" (k
    held at 0, the caveat stands) or "implausible" (beyond +-:data:`SCALE_MAX`: held at 0,
    the caveat stands), ``estimate``, ``std``, ``applied`` (estimated and at least
    :data:`SCALE_SIGNIFICANCE` std from 0; else 0 is used) and ``carried`` (its std goes to
    the estimates as a consider part: whenever it was estimated, applied or not)."""
    est, sd = float(wind.scale), float(wind.std_scale)
    if not wind.scale_estimated or not sd <= SCALE_STD_MAX:
        return {
            "status": "not identifiable",
            "estimate": 0.0,
            "std": sd,
            "applied": False,
            "carried": False,
            "note": f"the headings do not separate an airspeed scale factor from the wind "
            f"(its std {100 * sd:.1f} %, > {100 * SCALE_STD_MAX:g} %): taken as 0",
        }
    sig = abs(est) / sd if sd > 0 else float("inf")
    if abs(est) > SCALE_MAX:
        return {
            "status": "implausible",
            "estimate": est,
            "std": sd,
            "significance_std": sig,
            "applied": False,
            "carried": False,
            "note": f"airspeed scale factor {100 * est:+.1f} +- {100 * sd:.1f} % with the wind, "
            f"beyond +-{100 * SCALE_MAX:g} %: something else is wrong (airspeed "
            "units, EAS for TAS, a blocked pitot?); taken as 0",
        }
    applied = sig >= SCALE_SIGNIFICANCE
    why = "applied" if applied else f"within {SCALE_SIGNIFICANCE:g} std of 0: not applied"
    return {
        "status": "estimated",
        "estimate": est,
        "std": sd,
        "significance_std": sig,
        "applied": applied,
        "carried": True,
        "note": f"airspeed scale factor {100 * est:+.2f} +- {100 * sd:.2f} % with the wind ({why}; "
        "its std carried to the estimates)",
    }


#: what the rebuilt angles assume of the airspeed, by :func:`airspeed_calibration` status
_SCALE_ASSUMED = {
    "estimated": "the pitot's scale factor estimated with the wind (a pitot bias "
    "taken as a scale factor at the flight's airspeed)",
    "not identifiable": "airspeed without scale error",
    "implausible": "airspeed without scale error",
    "held": "the pitot's scale factor of the fitted flight",
}


def unsteady(doc: dict[str, Any], limit: float = 1.5) -> str | None:
    """Why the steady wind does not explain the airspeed - its residual above ``limit`` x
    the pitot's noise (about 1 in calm air, a steady wind included) - or None when it does
    or nothing was rebuilt."""
    if doc.get("status") != "reconstructed":
        return None
    res, noise = doc["airspeed_residual_rms_mps"], doc.get("airspeed_noise_mps") or float("nan")
    if res <= limit * noise:
        return None
    return (
        f"the airspeed departs from the steady-wind fit by {res:.2f} m/s rms, "
        f"{res / noise:.1f} x the pitot noise (turbulence or a changing wind)"
    )


def calibrated(doc: dict[str, Any]) -> bool:
    """Whether the rebuilt flight's V channel is the calibrated V / (1 + k)."""
    return doc.get("status") == "reconstructed" and bool((doc.get("airspeed_scale") or {}).get("applied"))


def mean_wind(doc: dict[str, Any]) -> tuple[float, float] | None:
    """The rebuilt flight's mean wind (north, east) [m/s] over its knots, or None when
    nothing was rebuilt."""
    if doc.get("status") != "reconstructed":
        return None
    return float(np.mean(doc["wind"]["north_mps"])), float(np.mean(doc["wind"]["east_mps"]))


#: what report.md says of the airspeed the rebuilt angles take as calibrated, when the
#: pitot's scale factor could not be estimated
AIRSPEED_CAVEAT = (
    "an airspeed scale factor or bias goes into the along-track wind, and the models' "
    "airspeed and dynamic pressure keep it, outside the std (pitot_wind_turn's "
    ".bin, a 3 % scale factor and 0.4 m/s, with the scale factor not estimated: "
    "46 std off; estimated: within 2.8): calibrate the airspeed before "
    "estimation, or fly a turn of some tens of degrees so that the wind fit "
    "estimates it"
)


def assumptions(doc: dict[str, Any]) -> str:
    """One line for report.md: what the rebuilt angles assume; the airspeed's caveat where
    the pitot's scale factor was not estimated."""
    cal = doc.get("airspeed_scale") or {}
    if cal.get("status") == "estimated":
        return f"{doc.get('assumptions', '')}; {cal['note']}"
    if cal.get("status") == "held":
        return str(doc.get("assumptions", ""))
    return f"{doc.get('assumptions', '')}; {cal.get('note', '')}{'; ' if cal.get('note') else ''}{AIRSPEED_CAVEAT}"


def summary(doc: dict[str, Any]) -> str:
    """One line for progress and report.md."""
    if doc.get("status") != "reconstructed":
        return str(doc.get("status"))
    w = doc["wind"]
    wn, we = mean_wind(doc)
    return (
        f"{'/'.join(doc['channels'])} from the flight path at {doc['rate_hz']:.3g} Hz: wind "
        f"{np.hypot(wn, we):.1f} m/s towards {np.rad2deg(np.arctan2(we, wn)) % 360:.0f} deg "
        f"(+-{max(max(w['std_north_mps']), max(w['std_east_mps'])):.2f}, {len(w['t_s'])} knot(s)), "
        f"airspeed residual {doc['airspeed_residual_rms_mps']:.2f} m/s rms, heading span "
        f"{doc['heading_span_deg']:.0f} deg" + _scale_summary(doc.get("airspeed_scale") or {})
    )


def _scale_summary(cal: dict[str, Any]) -> str:
    """The airspeed scale factor's part of :func:`summary`."""
    if cal.get("status") == "estimated":
        return (
            f", airspeed scale factor {100 * cal['estimate']:+.2f} +- {100 * cal['std']:.2f} % "
            f"({'applied' if cal['applied'] else 'not applied'})"
        )
    if cal.get("status") == "held":
        return f", airspeed scale factor {100 * cal['estimate']:+.2f} % (the fitted flight's)"
    return ""
