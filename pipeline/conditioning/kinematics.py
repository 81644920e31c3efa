"""Kinematic consistency: do the attitude, the track and the inertial sensors tell one story?

A frame, handedness or sign defect in logged or derived data (a mirrored axis in a
motion-capture export, a gyro mounted the other way round, ENU read as NED) leaves every
channel plausible on its own; only relations between channels reveal it. Each check
compares two things the physics ties together, from different sources, and fails when
they agree better with one of them mirrored than as logged:

``coordinated_turn``
    A banked wing turns the track: the course rate dchi/dt from vn, ve against
    g tan(phi) / V_h (the turn rate of a coordinated turn). Bank right while turning left
    means phi (or the track's east axis) is mirrored.
``lift_bank``
    Flight path reconstruction of the bank: the specific force the track needs
    (dv/dt - g, its part across the velocity) is the lift, perpendicular to the wings;
    its bank about the velocity against the attitude's bank about it.
``heading_course``
    The heading psi follows the course chi = atan2(ve, vn) within the crab angle (a warning
    only: a multicopter may fly sideways); it tells a mirrored roll from a mirrored track.
``pitch_path``
    The pitch theta and the flight-path angle gamma = atan2(-vd, V_h) rise and fall
    together in pitching manoeuvres.
``rates_attitude``
    Logged body rates p q r against the attitude's derivative (Euler kinematics), per axis.
``accel_track``
    Logged specific force ax ay az against R^T (dv/dt - g) from the track and the attitude.
``vertical_speed``
    The altitude rate dh/dt against -vd.

A pair whose members come from the same source (both derived from one pose) is not
compared: it agrees by construction. A check needs its relation to be excited (a spread
of the expected signal above ``min_spread``) over at least ``MIN_SAMPLES`` samples in
flight; otherwise it says nothing. Findings name the channel concerned and the change in
the channel map that would mend it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.signal import savgol_filter

from pipeline.conditioning.findings import FAIL, PASS, WARN, Finding
from pipeline.ingest.flightdata import FlightData
from pipeline.ingest.pose import G0, euler_to_quat, pose_part, quat_to_dcm

#: the comparison grid runs at the fastest channel's rate, at most this fast [Hz]
MAX_RATE_HZ = 100.0
#: derivatives on the grid: a local quadratic over this window [s]
SMOOTH_S = 0.3
#: horizontal speed [m/s] below which the track has no course (hover, ground)
MIN_SPEED = 1.0
#: samples (in flight, finite) a relation needs
MIN_SAMPLES = 50
#: correlation at or below which a relation is reversed (fail), at or above which it holds
FAIL_R, PASS_R = -0.5, 0.3


@dataclass
class Relation:
    """Two signals the physics ties together: ``expected`` (from one source) against
    ``observed`` (from another), pooled over the log's gap-free stretches.

    r : Pearson correlation; slope : least-squares slope of observed on expected;
    spread : std of expected; n : samples; stretches : (t0, t1) of each stretch [s] with its
    own r (NaN where that stretch's expected does not move)."""

    r: float
    slope: float
    spread: float
    n: int
    stretches: list[tuple[float, float, float]]

    @property
    def reversed_in(self) -> str:
        """'k of m stretches' that are reversed (r <= FAIL_R) among those with a finite r."""
        rs = [r for _, _, r in self.stretches if np.isfinite(r)]
        return f"{sum(r <= FAIL_R for r in rs)} of {len(rs)} stretch(es)"


def check_kinematics(fd: FlightData) -> list[Finding]:
    """Every kinematic-consistency finding for ``fd`` (module docstring)."""
    out: list[Finding] = []
    heading = _heading_course(fd)
    roll = [f for f in (_coordinated_turn(fd, heading), _lift_bank(fd, heading)) if f is not None]
    out += roll + ([heading[0]] if heading else [])
    roll_bad = any(f.status == FAIL for f in roll)
    for f in (_pitch_path(fd), _vertical_speed(fd)):
        if f is not None:
            out.append(f)
    out += _rates_attitude(fd, roll_bad)
    out += _accel_track(fd, roll_bad)
    return out


# ----------------------------------------------------------------- grid and relations
def _stretches(fd: FlightData, names: tuple[str, ...]) -> list[pd.DataFrame]:
    """``names`` on one uniform grid (the fastest one's rate, at most MAX_RATE_HZ), cut into
    its finite gap-free stretches of at least the smoothing window; [] when one is missing."""
    if fd.missing(names):
        return []
    rate = min(MAX_RATE_HZ, max(fd[c].rate_hz for c in names))
    if not rate > 0:
        return []
    df = fd.resample(rate, list(names), unwrap=True)
    ok = np.isfinite(df[list(names)].to_numpy()).all(axis=1)
    e = np.flatnonzero(np.diff(np.r_[0, ok.astype(np.int8), 0]))
    n_min = max(int(SMOOTH_S * rate) + 1, 5)
    return [df.iloc[a:b].reset_index(drop=True) for a, b in zip(e[::2], e[1::2]) if b - a >= n_min]


def _smooth(x: np.ndarray, dt: float, deriv: int = 0) -> np.ndarray:
    """Local quadratic over SMOOTH_S (or the whole stretch when shorter): value or derivative."""
    wl = max(int(round(SMOOTH_S / dt)) | 1, 5)
    wl = min(wl, x.size if x.size % 2 else x.size - 1)
    if wl < 3:
        return np.gradient(x, dt) if deriv else x
    return savgol_filter(x, wl, min(2, wl - 1), deriv=deriv, delta=dt, mode="interp")


def _relation(pairs: list[tuple[pd.DataFrame, np.ndarray, np.ndarray]]) -> Relation | None:
    """The pooled relation of (stretch, expected, observed) triples (NaN samples dropped)."""
    xs, ys, parts = [], [], []
    for df, x, y in pairs:
        m = np.isfinite(x) & np.isfinite(y)
        if m.sum() < 5:
            continue
        xs.append(x[m])
        ys.append(y[m])
        r = float(np.corrcoef(x[m], y[m])[0, 1]) if np.std(x[m]) > 0 and np.std(y[m]) > 0 else float("nan")
        parts.append((float(df["t"].iloc[0]), float(df["t"].iloc[-1]), r))
    if not xs:
        return None
    x, y = np.concatenate(xs), np.concatenate(ys)
    sx, sy = float(np.std(x)), float(np.std(y))
    if x.size < MIN_SAMPLES or sx == 0 or sy == 0:
        return Relation(float("nan"), float("nan"), sx, int(x.size), parts)
    r = float(np.corrcoef(x, y)[0, 1])
    slope = float(np.cov(x, y)[0, 1] / sx**2)
    return Relation(r, slope, sx, int(x.size), parts)


def _origin(fd: FlightData, name: str) -> str:
    """How a message names a channel: ``phi`` or ``phi (from the pose attitude (q_w ...))``."""
    return f"{name} (from the {fd[name].source})" if _pose_derived(fd, name) else name


def _span(rel: Relation) -> tuple[float | None, float | None]:
    return (rel.stretches[0][0], rel.stretches[-1][1]) if rel.stretches else (None, None)


def _course(df: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Course chi (unwrapped) [rad], its rate [rad/s] and horizontal speed [m/s] of a stretch;
    NaN where the horizontal speed is below MIN_SPEED."""
    dt = float(df["t"].iloc[1] - df["t"].iloc[0])
    vn, ve = df["vn"].to_numpy(), df["ve"].to_numpy()
    vh = np.hypot(vn, ve)
    chi = np.unwrap(np.arctan2(ve, vn))
    chid = _smooth(chi, dt, 1)
    slow = vh < MIN_SPEED
    return np.where(slow, np.nan, chi), np.where(slow, np.nan, chid), np.where(slow, np.nan, vh)


def _pose_derived(fd: FlightData, name: str) -> bool:
    return name in fd and pose_part(fd[name]) is not None


def _one_source(fd: FlightData, names: tuple[str, ...]) -> bool:
    """Whether all ``names`` were derived by the ingest from the same part of one pose
    (they agree by construction)."""
    parts = {pose_part(fd[n]) if n in fd else None for n in names}
    return None not in parts and (len(parts) == 1 or "both" in parts)


# ----------------------------------------------------------------- the checks
def _heading_course(fd: FlightData) -> tuple[Finding, bool] | None:
    """psi against the course of the track: the circular mean of psi - chi (the crab angle)
    is within 30 deg (pass), 30-60 deg (warn: strong wind or an offset), beyond (warn: a
    mirrored or offset heading or track, unless a multicopter flies sideways).
    Returns the finding and whether the heading follows the track."""
    diffs = []
    for df in _stretches(fd, ("psi", "vn", "ve")):
        chi, _, _ = _course(df)
        d = np.angle(np.exp(1j * (df["psi"].to_numpy() - chi)))
        diffs.append(d[np.isfinite(d)])
    d = np.concatenate(diffs) if diffs else np.zeros(0)
    if d.size < MIN_SAMPLES:
        return None
    mean = float(np.degrees(np.angle(np.mean(np.exp(1j * d)))))
    what = f"{_origin(fd, 'psi')} against the course atan2(ve, vn) of the track ({_origin(fd, 've')})"
    if abs(mean) <= 30:
        return Finding(
            PASS, "heading_course", "psi", f"{what}: {mean:+.1f} deg apart on average (crab)", value=mean
        ), True
    if abs(mean) <= 60:
        msg = (
            f"{what}: {mean:+.1f} deg apart on average: a strong crosswind, or a heading offset "
            "(magnetometer, a yaw frame offset in the channel map)"
        )
        return Finding(WARN, "heading_course", "psi", msg, value=mean), False
    msg = (
        f"{what}: {mean:+.1f} deg apart on average; the aircraft flies sideways to its heading: for a "
        "fixed wing the heading or the track's axes are mirrored or offset (check the sign of psi, or y_e / ve, "
        "in the channel map); a multicopter may fly so"
    )
    return Finding(WARN, "heading_course", "psi,y_e", msg, value=mean), False


def _roll_advice(fd: FlightData, heading: tuple[Finding, bool] | None) -> tuple[str, str]:
    """The channel(s) a reversed bank-vs-track relation concerns and what to change."""
    if heading is not None and heading[1]:
        mend = (
            "negate the pose's roll before its states are derived: pose = { roll_sign = -1 } under [map] in a "
            "channel map extending this log's (--map), or read_log(..., pose={'roll_sign': -1})"
            if _pose_derived(fd, "phi")
            else "sign = -1 on phi in the channel map"
        )
        return "phi", f"The heading psi follows the track, so the roll angle alone is mirrored: {mend}."
    return "phi,y_e", (
        "Negate phi in the channel map, or, when the heading psi does not follow the track either, "
        "flip the track's east axis (y_e / ve) or the attitude's handedness (q_x and q_z negated)."
    )


def _finding(check: str, rel: Relation, channel: str, what: str, advice: str) -> Finding:
    t0, t1 = _span(rel)
    if rel.r <= FAIL_R:
        msg = f"{what} are reversed: r = {rel.r:.2f} (slope {rel.slope:.2f}) in {rel.reversed_in}. {advice}"
        return Finding(FAIL, check, channel, msg, t0, t1, rel.r)
    if rel.r >= PASS_R:
        return Finding(PASS, check, channel, f"{what} agree: r = {rel.r:.2f} (slope {rel.slope:.2f})", t0, t1, rel.r)
    msg = (
        f"{what} hardly relate: r = {rel.r:.2f} (slope {rel.slope:.2f}); uncoordinated flight, wind or "
        "a frame defect: compare the channels' plots"
    )
    return Finding(WARN, check, channel, msg, t0, t1, rel.r)


def _coordinated_turn(fd: FlightData, heading) -> Finding | None:
    """g tan(phi) / V_h (the coordinated-turn rate) against the course rate of the track."""
    if _one_source(fd, ("phi", "vn")):
        return None
    pairs = []
    for df in _stretches(fd, ("phi", "vn", "ve")):
        dt = float(df["t"].iloc[1] - df["t"].iloc[0])
        _, chid, vh = _course(df)
        phi = np.clip(df["phi"].to_numpy(), -np.radians(75), np.radians(75))
        turn = _smooth(G0 * np.tan(phi) / np.maximum(np.nan_to_num(vh), MIN_SPEED), dt)
        pairs.append((df, np.where(np.isfinite(vh), turn, np.nan), chid))
    rel = _relation(pairs)
    if rel is None or rel.n < MIN_SAMPLES or rel.spread < np.radians(1.0) or not np.isfinite(rel.r):
        return None
    channel, advice = _roll_advice(fd, heading)
    what = (
        f"The bank angle {_origin(fd, 'phi')} as a turn rate g tan(phi)/V and the course rate dchi/dt of the "
        f"track ({_origin(fd, 'vn')}, ve)"
    )
    if rel.r <= FAIL_R:
        what += " (bank right, turn left)"
    return _finding("coordinated_turn", rel, channel, what, advice)


def _bank_frame(v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit velocity e (n, 3), the level right axis y0 and z0 = e x y0 (NaN when climbing
    or diving steeper than 84 deg)."""
    e = v / np.maximum(np.linalg.norm(v, axis=1), 1e-9)[:, None]
    y0 = np.cross(np.array([0.0, 0.0, 1.0]), e)
    ny = np.linalg.norm(y0, axis=1)
    y0 = np.where((ny > 0.1)[:, None], y0 / np.maximum(ny, 1e-12)[:, None], np.nan)
    return e, y0, np.cross(e, y0)


def _lift_bank(fd: FlightData, heading) -> Finding | None:
    """The bank of the lift the track needs about the velocity against the attitude's bank."""
    names = ("phi", "theta", "psi", "vn", "ve", "vd")
    pairs = []
    for df in _stretches(fd, names):
        dt = float(df["t"].iloc[1] - df["t"].iloc[0])
        v = df[["vn", "ve", "vd"]].to_numpy()
        f = np.column_stack([_smooth(v[:, i], dt, 1) for i in range(3)]) - np.array([0.0, 0.0, G0])
        e, y0, z0 = _bank_frame(v)
        fp = f - np.einsum("ij,ij->i", f, e)[:, None] * e
        nf = np.linalg.norm(fp, axis=1)
        d = -fp / np.maximum(nf, 1e-9)[:, None]
        mu_track = np.arctan2(-np.einsum("ij,ij->i", d, y0), np.einsum("ij,ij->i", d, z0))
        zb = quat_to_dcm(euler_to_quat(*(df[c].to_numpy() for c in ("phi", "theta", "psi"))))[:, :, 2]
        mu_att = np.arctan2(-np.einsum("ij,ij->i", zb, y0), np.einsum("ij,ij->i", zb, z0))
        ok = (nf >= 0.5 * G0) & (np.linalg.norm(v, axis=1) >= MIN_SPEED) & (np.abs(mu_att) < np.radians(80))
        pairs.append((df, np.where(ok, mu_att, np.nan), np.where(ok, mu_track, np.nan)))
    rel = _relation(pairs)
    if rel is None or rel.n < MIN_SAMPLES or rel.spread < np.radians(3.0) or not np.isfinite(rel.r):
        return None
    channel, advice = _roll_advice(fd, heading)
    what = (
        f"The attitude's bank about the velocity ({_origin(fd, 'phi')}) and the bank of the lift the track "
        f"needs (dv/dt - g across the velocity, from {_origin(fd, 'vn')} ve vd)"
    )
    return _finding("lift_bank", rel, channel, what, advice)


def _pitch_path(fd: FlightData) -> Finding | None:
    """theta against the flight-path angle gamma = atan2(-vd, V_h): reversed means the
    vertical axis of the track (z_d / vd) or the pitch is mirrored."""
    if _one_source(fd, ("theta", "vd")):
        return None
    pairs = []
    for df in _stretches(fd, ("theta", "vn", "ve", "vd")):
        _, _, vh = _course(df)
        pairs.append(
            (df, np.where(np.isfinite(vh), df["theta"].to_numpy(), np.nan), np.arctan2(-df["vd"].to_numpy(), vh))
        )
    rel = _relation(pairs)
    if rel is None or rel.n < MIN_SAMPLES or rel.spread < np.radians(2.0) or not np.isfinite(rel.r):
        return None
    if rel.r > FAIL_R:  # a weak relation is normal: gamma lags theta in fast pitching
        t0, t1 = _span(rel)
        msg = f"{_origin(fd, 'theta')} and the flight-path angle of the track: r = {rel.r:.2f}, not reversed"
        return Finding(PASS, "pitch_path", "theta", msg, t0, t1, rel.r)
    what = (
        f"The pitch {_origin(fd, 'theta')} and the flight-path angle atan2(-vd, V_h) of the track ({_origin(fd, 'vd')})"
    )
    advice = "The vertical axis is mirrored: flip z_d / vd (up read as down), or negate theta, in the channel map."
    return _finding("pitch_path", rel, "theta,z_d", what, advice)


def _vertical_speed(fd: FlightData) -> Finding | None:
    """dh/dt against -vd (from different sources)."""
    if _one_source(fd, ("h", "vd")) or fd.missing(("h", "vd")):
        return None
    pairs = []
    for df in _stretches(fd, ("h", "vd")):
        dt = float(df["t"].iloc[1] - df["t"].iloc[0])
        pairs.append((df, -df["vd"].to_numpy(), _smooth(df["h"].to_numpy(), dt, 1)))
    rel = _relation(pairs)
    if rel is None or rel.n < MIN_SAMPLES or rel.spread < 0.3 or not np.isfinite(rel.r):
        return None
    advice = "Negate vd (NED down, positive when descending) or h (up) in the channel map."
    return _finding("vertical_speed", rel, "vd", f"The climb rate dh/dt of {_origin(fd, 'h')} and -vd", advice)


def _euler_rates(df: pd.DataFrame) -> np.ndarray:
    """Body rates (n, 3) [rad/s] of the Euler angles' derivatives (the kinematic equations)."""
    dt = float(df["t"].iloc[1] - df["t"].iloc[0])
    phi, theta, psi = (df[c].to_numpy() for c in ("phi", "theta", "psi"))
    dphi, dtheta, dpsi = (_smooth(x, dt, 1) for x in (phi, theta, psi))
    p = dphi - dpsi * np.sin(theta)
    q = dtheta * np.cos(phi) + dpsi * np.sin(phi) * np.cos(theta)
    r = -dtheta * np.sin(phi) + dpsi * np.cos(phi) * np.cos(theta)
    return np.column_stack([p, q, r])


def _rates_attitude(fd: FlightData, roll_bad: bool) -> list[Finding]:
    """Logged gyros p q r against the attitude's derivative, per axis. A reversed p when
    the bank is already found mirrored is put on phi, not on the gyro."""
    out: list[Finding] = []
    for k, name in enumerate(("p", "q", "r")):
        if name not in fd or fd.missing(("phi", "theta", "psi")) or _one_source(fd, (name, "phi")):
            continue
        pairs = []
        for df in _stretches(fd, (name, "phi", "theta", "psi")):
            dt = float(df["t"].iloc[1] - df["t"].iloc[0])
            pairs.append((df, _euler_rates(df)[:, k], _smooth(df[name].to_numpy(), dt)))
        rel = _relation(pairs)
        if rel is None or rel.n < MIN_SAMPLES or rel.spread < np.radians(3.0) or not np.isfinite(rel.r):
            continue
        what = f"The body rate {_origin(fd, name)} and the rate of the attitude (phi theta psi, Euler kinematics)"
        if name == "p" and roll_bad:
            advice = "The bank checks above found the roll angle mirrored: mend phi; p is then consistent."
            out.append(_finding("rates_attitude", rel, "phi", what, advice))
        else:
            advice = f"The gyro axis is mounted or mapped the other way round: sign = -1 on {name} in the channel map."
            out.append(_finding("rates_attitude", rel, name, what, advice))
    return out


def _accel_track(fd: FlightData, roll_bad: bool) -> list[Finding]:
    """Logged specific force ax ay az against R^T (dv/dt - g) from the track and the
    attitude, per axis: fails when the axis fits better negated (rms of the difference at
    most half that of the sum), where the expected signal's rms is at least 0.3 m/s^2."""
    names = ("phi", "theta", "psi", "vn", "ve", "vd")
    logged = [c for c in ("ax", "ay", "az") if c in fd and not _pose_derived(fd, c)]
    if not logged or fd.missing(names):
        return []
    exp = {c: [] for c in logged}
    obs = {c: [] for c in logged}
    for df in _stretches(fd, names + tuple(logged)):
        dt = float(df["t"].iloc[1] - df["t"].iloc[0])
        f = np.column_stack([_smooth(df[c].to_numpy(), dt, 1) for c in ("vn", "ve", "vd")]) - np.array([0, 0, G0])
        R = quat_to_dcm(euler_to_quat(*(df[c].to_numpy() for c in ("phi", "theta", "psi"))))
        fb = np.einsum("nji,nj->ni", R, f)
        for c in logged:
            exp[c].append(fb[:, "xyz".index(c[1])])
            obs[c].append(_smooth(df[c].to_numpy(), dt))
    out: list[Finding] = []
    for c in logged:
        if not exp[c]:
            continue
        x, y = np.concatenate(exp[c]), np.concatenate(obs[c])
        if x.size < MIN_SAMPLES or np.sqrt(np.mean(x**2)) < 0.3:
            continue
        same, flip = float(np.sqrt(np.mean((y - x) ** 2))), float(np.sqrt(np.mean((y + x) ** 2)))
        what = f"{c} against R^T (dv/dt - g) from the track and the attitude"
        if flip <= 0.5 * same and not (roll_bad and c == "ay"):
            msg = (
                f"{what}: rms {same:.2f} m/s^2 as logged, {flip:.2f} negated: the accelerometer axis is mapped "
                f"the other way round (sign = -1 on {c} in the channel map)"
            )
            out.append(Finding(FAIL, "accel_track", c, msg, value=same))
        else:
            out.append(
                Finding(PASS, "accel_track", c, f"{what}: rms {same:.2f} m/s^2 ({flip:.2f} negated)", value=same)
            )
    return out
