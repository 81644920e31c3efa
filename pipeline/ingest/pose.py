"""Pose-only flight data (motion capture) turned into flight states.

A motion-capture log holds position ``x_n y_e z_d`` [m, local NED] and the attitude
quaternion ``q_w q_x q_y q_z`` (body -> NED, DESIGN.md section 3) and nothing else of the
aircraft's motion. :func:`derive_pose_states` differentiates them by smoothing
(Savitzky-Golay, :func:`scipy.signal.savgol_filter`) into

- inertial velocity ``vn ve vd`` [m/s] (first derivative of the position) and ``h = -z_d``;
- Euler angles ``phi theta psi`` [rad] from the smoothed quaternion;
- body rates ``p q r`` [rad/s] from the quaternion's derivative, omega = 2 vec(q* (x) dq/dt);
- specific force ``ax ay az`` [m/s^2]: a_body = R^T (dv/dt - g_ned), g_ned = (0, 0, G0);
- air data ``u v w`` [m/s], ``V`` [m/s], ``alpha beta`` [rad] from the body air velocity
  R^T (v_ned - wind_ned), in still air unless a wind is given.

Window: a local cubic (``POLYORDER`` 3) over ``window_s`` (default 0.2 s: 21 samples at
100 Hz), made odd in samples and at least ``POLYORDER + 2``. A cubic keeps a step response's
curvature while 0.2 s averages 1 mm / 0.1 deg camera noise at 100 Hz down to about 1 cm/s
and 1 deg/s; its half-power point is near 5 Hz, above the rigid-body modes of a small
aircraft. Half the window leaves the rates' noise 2.5 times larger; twice the window
rounds a doublet's rates off by more than the noise it removes. The pose is put on a uniform grid (its median interval) piece
by piece: a gap longer than ``MAX_GAP_INTERVALS`` median intervals or a non-finite sample
ends a piece, so nothing is differentiated across a gap. The quaternion's sign (q and -q
are the same attitude) is made continuous before smoothing.

Noise: the camera noise of each pose component is estimated from the smoother's own
residual r = x - S x. For white noise of std s the residual at a window's centre has
variance s^2 (1 - h0) (h0 the centre weight of the smoother), so s = std(r) / sqrt(1 - h0),
pooled over the pieces. Each derived channel's stated noise (``Channel.noise``) is that std
carried through the linear filter: s times the norm of the filter's weights for the
derivative (divided by dt or dt^2), with the small-angle rules that an attitude error is
twice the quaternion-vector error and that it tilts gravity (specific force) and the
velocity (air data) by that angle. Smoothing bias (a manoeuvre faster than the window) is
not in that number.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_coeffs, savgol_filter

from pipeline.errors import FsidError
from pipeline.ingest.flightdata import CANONICAL_UNITS, Channel, FlightData

#: the pose channels (DESIGN.md section 3)
POSITION = ("x_n", "y_e", "z_d")
QUATERNION = ("q_w", "q_x", "q_y", "q_z")
POSE = POSITION + QUATERNION
#: what a pose becomes, in the order they are added
DERIVED = (
    *("vn", "ve", "vd", "h", "phi", "theta", "psi", "p", "q", "r"),
    *("ax", "ay", "az", "u", "v", "w", "V", "alpha", "beta"),
)
#: the derived channels that depend on the wind
AIR = ("u", "v", "w", "V", "alpha", "beta")
#: ``Channel.source`` of a derived state by the part of the pose it comes from
SOURCES = {
    "position": "pose position (x_n y_e z_d)",
    "attitude": "pose attitude (q_w q_x q_y q_z)",
    "both": "pose position and attitude",
}
_PART = {n: "position" for n in ("vn", "ve", "vd", "h")} | {
    n: "attitude" for n in ("phi", "theta", "psi", "p", "q", "r")
}
#: standard gravity [m/s^2]
G0 = 9.80665
#: the smoothing window [s] and the local polynomial's order
DEFAULT_WINDOW_S = 0.2
POLYORDER = 3
#: a pose interval longer than this many median intervals ends a piece
MAX_GAP_INTERVALS = 3.0
#: the keywords of derive_pose_states a channel map may set (``[map] pose = {...}``)
MAP_OPTIONS = ("window_s", "polyorder", "wind_ned", "roll_sign")


@dataclass
class PoseNoise:
    """White-noise std of the pose as the smoother's residual measures it.

    position : (3,) m, per axis x_n y_e z_d; quaternion : std of the quaternion's noise per
    rotation axis (-, half the attitude noise in rad: the residual power of the 4
    components over 3);
    window : samples of the smoothing window, dt : its grid interval [s]."""

    position: np.ndarray
    quaternion: float
    window: int
    dt: float


def has_pose(fd: FlightData) -> bool:
    """Whether ``fd`` holds all seven pose channels with samples."""
    return not fd.missing(POSE)


def pose_part(ch: Channel) -> str | None:
    """The part of a pose ("position", "attitude" or "both") channel ``ch`` was derived
    from by :func:`derive_pose_states`; None for a logged channel."""
    return next((k for k, v in SOURCES.items() if ch.source == v and ch.noise is not None), None)


def map_pose_options(spec, map_name: str) -> dict:
    """A channel map's ``[map] pose = { roll_sign = -1, window_s = 0.2, wind_ned = [3, -4, 0] }``
    as keywords for :func:`derive_pose_states` ({} when absent): the place a user mends a
    pose export for good (a user map extending the built-in one, ``--map``)."""
    if spec is None:
        return {}
    if not isinstance(spec, dict) or set(spec) - set(MAP_OPTIONS):
        raise FsidError(
            f"channel map {map_name}: [map] pose must be a table with keys among {', '.join(MAP_OPTIONS)} "
            f"(got {spec!r}), e.g. pose = {{ roll_sign = -1 }}"
        )
    return dict(spec)


def needs_pose_states(fd: FlightData) -> bool:
    """Whether a pose is there and some flight state it gives is not logged."""
    return has_pose(fd) and bool(fd.missing(DERIVED))


def derive_pose_states(
    fd: FlightData,
    *,
    window_s: float = DEFAULT_WINDOW_S,
    polyorder: int = POLYORDER,
    wind_ned: Sequence[float] = (0.0, 0.0, 0.0),
    roll_sign: int = 1,
    strict: bool = True,
) -> FlightData:
    """A new FlightData with the flight states of ``fd``'s pose added (module docstring).

    Parameters
    ----------
    fd : a flight with x_n y_e z_d [m] and q_w q_x q_y q_z (body -> NED); not modified
    window_s : Savitzky-Golay window [s] from first to last sample (made an odd number of
        samples, at least polyorder + 2)
    polyorder : order of the local polynomial (>= 2: the specific force is a 2nd derivative)
    wind_ned : constant wind (north, east, down) [m/s] for the air data; still air by default
    roll_sign : -1 mirrors the pose's roll (phi -> -phi, theta and psi kept) before anything
        is derived: the mend for an export whose roll is mirrored, which the kinematic checks
        (:mod:`pipeline.conditioning.kinematics`: bank against turn) find
    strict : False: a pose that cannot be differentiated (too few samples, no unit
        quaternion) leaves ``fd`` as it is and says why in ``meta["pose"]["error"]`` and
        ``meta["unmapped"]`` instead of raising (the ingest reads the rest of the log)

    Returns
    -------
    FlightData sharing ``fd``'s channels, with each of :data:`DERIVED` that ``fd`` lacks
    added (logged channels win), marked ``derived`` with its window and stated ``noise``;
    ``meta["pose"]`` says how (window, order, rate, pose noise, pieces, wind).
    """
    if not has_pose(fd):
        raise FsidError(
            f"derive_pose_states: the flight lacks pose channel(s) {', '.join(fd.missing(POSE))}; "
            "map position x_n y_e z_d [m, NED] and quaternion q_w q_x q_y q_z (body -> NED) in the channel map"
        )
    if not (window_s > 0 and 2 <= polyorder <= 5 and roll_sign in (1, -1)):
        raise FsidError(
            f"derive_pose_states: window_s {window_s!r} must be > 0, polyorder {polyorder!r} in 2..5 "
            f"and roll_sign {roll_sign!r} 1 or -1"
        )
    wind = np.asarray(wind_ned, dtype=float).reshape(3)
    try:
        pieces, dt, window = _differentiate(fd, window_s, polyorder, wind, roll_sign)
    except FsidError as exc:
        if strict:
            raise
        meta = dict(fd.meta)
        meta["pose"] = {"error": str(exc)}
        meta["unmapped"] = dict(meta.get("unmapped") or {}) | {n: f"not derived: {exc}" for n in fd.missing(DERIVED)}
        return FlightData(dict(fd.channels), meta, list(fd.segments))
    noise = _pooled_noise(pieces, window, polyorder, dt)
    stated = _stated_noise(noise, polyorder, pieces)
    tt = np.concatenate([p["t"] for p in pieces])
    how = (
        f"smoothing differentiation of the pose (Savitzky-Golay, {window} samples = {(window - 1) * dt:.3g} s, "
        f"order {polyorder})"
    ) + (" with the pose's roll negated (roll_sign -1)" if roll_sign == -1 else "")
    air = f"the wind {tuple(float(x) for x in wind)} m/s (NED) removed" if wind.any() else "still air assumed"
    chans = dict(fd.channels)
    added = fd.missing(DERIVED)
    for name in added:
        why = how + (f"; air-relative with {air}" if name in AIR else "")
        chans[name] = Channel(
            tt.copy(),
            np.concatenate([p[name] for p in pieces]),
            CANONICAL_UNITS[name],
            SOURCES[_PART.get(name, "both")],
            derived=f"{why}; noise std {stated[name]:.3g} {CANONICAL_UNITS[name]} from the smoother's residual",
            noise=stated[name],
        )
    meta = dict(fd.meta)
    meta["pose"] = {
        "window_samples": window,
        "window_s": (window - 1) * dt,
        "polyorder": polyorder,
        "rate_hz": 1.0 / dt,
        "noise_position_m": [float(x) for x in noise.position],
        "noise_quaternion": noise.quaternion,
        "noise": stated,
        "pieces": [(float(p["t"][0]), float(p["t"][-1])) for p in pieces],
        "wind_ned": [float(x) for x in wind],
        "roll_sign": roll_sign,
        "derived": added,
    }
    return FlightData(chans, meta, list(fd.segments))


def _differentiate(fd: FlightData, window_s: float, polyorder: int, wind: np.ndarray, roll_sign: int):
    """The derived states of every gap-free piece of the pose, the grid interval [s] and the
    window [samples]; FsidError when no piece can be differentiated."""
    t, pos, quat = _pose_samples(fd)
    if roll_sign == -1:
        phi, theta, psi = quat_to_euler(quat / np.linalg.norm(quat, axis=1)[:, None])
        quat = euler_to_quat(-phi, theta, psi)
    dt = float(np.median(np.diff(t))) if t.size > 1 else float("nan")
    if not (t.size >= polyorder + 2 and dt > 0):
        raise FsidError(
            f"the pose has {t.size} sample(s) at distinct times; it needs at least {polyorder + 2} to be differentiated"
        )
    ok = np.isfinite(pos).all(axis=1)
    if not ok.any():
        norm = np.linalg.norm(np.column_stack([fd[c].values for c in QUATERNION]), axis=1)
        raise FsidError(
            f"no pose sample has a finite position and a unit quaternion (median |q| "
            f"{np.nanmedian(norm) if np.isfinite(norm).any() else float('nan'):.3g}); check the channel map of "
            "x_n y_e z_d [m] and q_w q_x q_y q_z"
        )
    window = _odd_window(window_s / dt + 1, polyorder)
    pieces = [_derive_piece(t[a:b], pos[a:b], quat[a:b], dt, window, polyorder, wind) for a, b in _pieces(t, ok, dt)]
    pieces = [p for p in pieces if p is not None]
    if not pieces:
        raise FsidError(
            f"no stretch of the pose without gaps has {polyorder + 2} samples (median interval {dt:.4g} s); "
            "the pose cannot be differentiated"
        )
    return pieces, dt, window


def _pose_samples(fd: FlightData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times (n,) [s] of the quaternion, sorted and distinct, with the position (n, 3)
    interpolated onto them where its own times differ, and the quaternion (n, 4); rows with
    a non-finite value are NaN (they end a piece)."""
    qw = fd.channels["q_w"]
    t = np.asarray(qw.t, dtype=float)
    order = np.argsort(t, kind="stable")
    t = t[order]
    keep = np.r_[True, np.diff(t) > 0] & np.isfinite(t)
    t = t[keep]

    def on_t(name: str) -> np.ndarray:
        ch = fd.channels[name]
        tc, vc = np.asarray(ch.t, dtype=float), np.asarray(ch.values, dtype=float)
        if tc.shape == qw.t.shape and np.array_equal(tc, qw.t):
            return vc[order][keep]
        ok = np.isfinite(tc) & np.isfinite(vc)
        o = np.argsort(tc[ok], kind="stable")
        return np.interp(t, tc[ok][o], vc[ok][o], left=np.nan, right=np.nan)

    pos = np.column_stack([on_t(c) for c in POSITION])
    quat = np.column_stack([on_t(c) for c in QUATERNION])
    norm = np.linalg.norm(quat, axis=1)
    bad = ~(np.isfinite(pos).all(axis=1) & np.isfinite(quat).all(axis=1) & (norm > 0.5) & (norm < 1.5))
    pos[bad] = np.nan
    quat[bad] = np.nan
    return t, pos, quat


def _pieces(t: np.ndarray, ok: np.ndarray, dt: float) -> list[tuple[int, int]]:
    """(start, stop) index ranges of rows ``ok`` (finite pose) with no interval longer than
    MAX_GAP_INTERVALS x dt inside."""
    brk = np.r_[False, np.diff(t) > MAX_GAP_INTERVALS * dt]
    e = np.flatnonzero(np.diff(np.r_[0, ok.astype(np.int8), 0]))
    out = []
    for a, b in zip(e[::2], e[1::2]):
        cuts = [int(a)] + [int(k) for k in np.flatnonzero(brk[a + 1 : b]) + a + 1] + [int(b)]
        out += list(zip(cuts[:-1], cuts[1:]))
    return out


def _odd_window(samples: float, polyorder: int) -> int:
    """The odd window length nearest ``samples``, at least polyorder + 2 (rounded up to odd)."""
    n = max(int(round(samples)), polyorder + 2)
    return n if n % 2 else n + 1


def _continuous_sign(quat: np.ndarray) -> np.ndarray:
    """``quat`` (n, 4) with each row's sign chosen so that neighbours point the same way
    (q and -q are one attitude; a logger may switch between them)."""
    flips = np.r_[1.0, np.where(np.einsum("ij,ij->i", quat[1:], quat[:-1]) < 0, -1.0, 1.0)]
    return quat * np.cumprod(flips)[:, None]


def _derive_piece(t, pos, quat, dt, window, polyorder, wind) -> dict | None:
    """The flight states of one gap-free stretch (times t (n,), pos (n, 3), quat (n, 4)) on
    a uniform grid of interval ``dt``, and the smoother's residuals; None when it is
    shorter than polyorder + 2 grid points. A stretch shorter than the window is smoothed
    with the longest odd window it holds."""
    tu = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt + 1e-6)) + 1)
    n = tu.size
    if n < polyorder + 2:
        return None
    wl = window if n >= window else (n if n % 2 else n - 1)
    if wl < polyorder + 2:
        return None
    P = np.column_stack([np.interp(tu, t, pos[:, i]) for i in range(3)])
    Qc = _continuous_sign(quat)
    Q = np.column_stack([np.interp(tu, t, Qc[:, i]) for i in range(4)])
    return _states(tu, P, Q, dt, wl, polyorder, wind)


def _sg(x: np.ndarray, wl: int, polyorder: int, deriv: int, dt: float) -> np.ndarray:
    return savgol_filter(x, wl, polyorder, deriv=deriv, delta=dt, axis=0, mode="interp")


def quat_to_dcm(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3), body -> NED (v_ned = R v_body), of unit quaternions
    ``q`` (n, 4) as (w, x, y, z)."""
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def quat_to_euler(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(phi, theta, psi) [rad], ZYX Euler angles, of unit quaternions ``q`` (n, 4) body -> NED."""
    w, x, y, z = q.T
    phi = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    theta = np.arcsin(np.clip(2 * (w * y - x * z), -1.0, 1.0))
    psi = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return phi, theta, psi


def euler_to_quat(phi, theta, psi) -> np.ndarray:
    """Unit quaternions (n, 4) as (w, x, y, z), body -> NED, of ZYX Euler angles [rad]."""
    cr, sr = np.cos(np.asarray(phi) / 2), np.sin(np.asarray(phi) / 2)
    cp, sp = np.cos(np.asarray(theta) / 2), np.sin(np.asarray(theta) / 2)
    cy, sy = np.cos(np.asarray(psi) / 2), np.sin(np.asarray(psi) / 2)
    return np.column_stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def _states(t, P, Q, dt, wl, polyorder, wind) -> dict:
    """Every derived state on the uniform grid ``t`` (n,) from position P (n, 3) and a
    sign-continuous quaternion Q (n, 4); plus the residuals and the window used."""
    Ps, V, A = (_sg(P, wl, polyorder, k, dt) for k in (0, 1, 2))
    Qs, Qd = (_sg(Q, wl, polyorder, k, dt) for k in (0, 1))
    nq = np.linalg.norm(Qs, axis=1)
    Qu = Qs / nq[:, None]
    w, x, y, z = Qu.T
    dw, dx, dy, dz = (Qd / nq[:, None]).T
    # omega_body = 2 vec(conj(q) (x) dq/dt); the part of dq/dt along q (norm change) drops out
    p = 2 * (w * dx - x * dw - y * dz + z * dy)
    q = 2 * (w * dy + x * dz - y * dw - z * dx)
    r = 2 * (w * dz - x * dy + y * dx - z * dw)
    R = quat_to_dcm(Qu)
    f_body = np.einsum("nji,nj->ni", R, A - np.array([0.0, 0.0, G0]))
    uvw = np.einsum("nji,nj->ni", R, V - wind)
    Va = np.linalg.norm(uvw, axis=1)
    phi, theta, psi = quat_to_euler(Qu)
    out = {"t": t, "vn": V[:, 0], "ve": V[:, 1], "vd": V[:, 2], "h": -Ps[:, 2], "phi": phi, "theta": theta}
    out |= {"psi": psi, "p": p, "q": q, "r": r, "ax": f_body[:, 0], "ay": f_body[:, 1], "az": f_body[:, 2]}
    out |= {"u": uvw[:, 0], "v": uvw[:, 1], "w": uvw[:, 2], "V": Va, "alpha": np.arctan2(uvw[:, 2], uvw[:, 0])}
    out |= {"beta": np.arcsin(np.clip(uvw[:, 1] / np.maximum(Va, 1e-9), -1.0, 1.0))}
    out |= {"res_pos": P - Ps, "res_quat": Q - Qs, "window": np.full(t.size, wl)}
    return out


def _pooled_noise(pieces: list[dict], window: int, polyorder: int, dt: float) -> PoseNoise:
    """The pose's white-noise std from the smoothers' residuals away from the pieces' edges
    (s = std(r) / sqrt(1 - h0) for the window each piece used), pooled over the pieces."""
    num_p, num_q, den = np.zeros(3), 0.0, 0
    for pc in pieces:
        wl = int(pc["window"][0])
        h0 = savgol_coeffs(wl, polyorder)[wl // 2]
        inner = slice(wl // 2, pc["t"].size - wl // 2)
        rp, rq = pc["res_pos"][inner], pc["res_quat"][inner]
        if rp.shape[0] < 2:
            continue
        num_p += np.sum(rp**2, axis=0) / (1 - h0)
        num_q += float(np.sum(rq**2)) / (1 - h0) / 3  # a small rotation moves 3 of 4 components
        den += rp.shape[0]
    if den == 0:
        return PoseNoise(np.full(3, np.nan), float("nan"), window, dt)
    return PoseNoise(np.sqrt(num_p / den), float(np.sqrt(num_q / den)), window, dt)


def _stated_noise(noise: PoseNoise, polyorder: int, pieces: list[dict]) -> dict[str, float]:
    """Each derived channel's white-noise std (module docstring): the pose noise through the
    filter's weights for the derivative, an attitude error of twice the quaternion error."""
    wl, dt = noise.window, noise.dt
    g0, g1, g2 = (float(np.linalg.norm(savgol_coeffs(wl, polyorder, deriv=k, delta=dt, use="dot"))) for k in (0, 1, 2))
    sp, sq = noise.position, noise.quaternion
    angle = 2 * sq * g0
    vel = sp * g1
    s_v = float(np.sqrt(np.mean(vel**2)))
    speed = float(np.nanmedian(np.concatenate([p["V"] for p in pieces])))
    s_f = float(np.sqrt(np.mean((sp * g2) ** 2) + (G0 * angle) ** 2))
    s_uvw = float(np.hypot(s_v, speed * angle))
    s_flow = float(np.hypot(s_v / max(speed, 1e-3), angle))
    out = {"vn": vel[0], "ve": vel[1], "vd": vel[2], "h": sp[2] * g0, "phi": angle, "theta": angle, "psi": angle}
    out |= {"p": 2 * sq * g1, "q": 2 * sq * g1, "r": 2 * sq * g1, "ax": s_f, "ay": s_f, "az": s_f}
    out |= {"u": s_uvw, "v": s_uvw, "w": s_uvw, "V": s_v, "alpha": s_flow, "beta": s_flow}
    return {k: float(v) for k, v in out.items()}
