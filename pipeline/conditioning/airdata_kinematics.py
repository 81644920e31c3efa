"""Airspeed, sideslip and angle of attack at the CG from the air data blended with the
integrated IMU.

Used by the lateral equation error (the lateral regressions of :mod:`pipeline.problems`):
vane noise on the beta regressor, which cross-controlled maneuvers make nearly collinear
with dr and r, biases every derivative (errors in variables).

Also the pseudo-inputs V and alpha of the lateral output error in calm air (the lateral
problem with ``kinematic=True``): output error takes its inputs as exact, and the pitot
noise between 0.1 and 1 Hz, which the pitot low-passed at 1 Hz kept, scales every moment
of a window; an alpha rebuilt from the 10 Hz GPS velocity (no vane) puts its noise into
the kinematic coupling. The part below 0.1 Hz is the air data's either way (the
per-maneuver correction dV with its prior covers the pitot's window mean).

Both are complementary filters (zero-phase, second-order Butterworth at ``fc``): the air
data below ``fc``, the integral of the kinematic rate above it.

    Vdot = (a + g_b) . V/|V|     (rotation terms drop out of the speed)
    vdot = ay + g cos(theta) sin(phi) + p w - r u
    wdot = az + g cos(theta) cos(phi) + q u - p v

with a the specific force moved from the IMU to the CG (centripetal terms; the
angular-acceleration lever arms of v and w, r x_imu - p z_imu and p y_imu - q x_imu, are
subtracted after integration), u, v, w from the air data. A constant accelerometer bias integrates to a ramp, which the
zero-phase low-pass of (measured - integrated) passes unchanged, so it cancels.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd
from scipy.signal import butter, filtfilt

G0 = 9.80665
#: complementary-filter corners (Hz): below them the air data, above the IMU integral
V_CORNER_HZ = 0.1
BETA_CORNER_HZ = 0.1
ALPHA_CORNER_HZ = 0.1
CHANNELS = ("V", "alpha", "beta", "theta", "phi", "ax", "ay", "az", "p", "q", "r")


def _lowpass(x: np.ndarray, fc: float, rate: float) -> np.ndarray:
    b, a = butter(2, fc / (0.5 * rate))
    return filtfilt(b, a, x, padtype="odd")


def _integral(x: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(t))])


def kinematic_air_data(
    fd,
    rate_hz: float,
    imu: Sequence[float] = (0.0, 0.0, 0.0),
    vane: Sequence[float] = (0.0, 0.0, 0.0),
    *,
    fc_V: float = V_CORNER_HZ,
    fc_beta: float = BETA_CORNER_HZ,
    fc_alpha: float = ALPHA_CORNER_HZ,
) -> pd.DataFrame | None:
    """DataFrame (t, V, beta, alpha) on a uniform ``rate_hz`` grid over the flight:
    airspeed, sideslip and angle of attack at the CG, complementary-filtered (module doc).
    None when the flight lacks a channel of CHANNELS, is too short, or has gaps in them
    (the caller keeps the air data as measured)."""
    if fd.missing(CHANNELS):
        return None
    df = fd.resample(rate_hz, list(CHANNELS), unwrap=True)
    if len(df) < 50 or not np.all(np.isfinite(df[list(CHANNELS)].to_numpy())):
        return None
    if 2.0 * max(fc_V, fc_beta, fc_alpha) >= 0.45 * rate_hz:
        return None
    t = df["t"].to_numpy()
    Vm, a, bm, th, ph = (df[k].to_numpy() for k in ("V", "alpha", "beta", "theta", "phi"))
    ax, ay, az = (df[k].to_numpy() for k in ("ax", "ay", "az"))
    p, q, r = (df[k].to_numpy() for k in ("p", "q", "r"))
    x, y, z = (float(v) for v in imu)
    xv, yv, zv = (float(v) for v in vane)
    # specific force at the CG (centripetal terms of the IMU position)
    ax = ax - (q * (p * y - q * x) - r * (r * x - p * z))
    ay = ay - (r * (q * z - r * y) - p * (p * y - q * x))
    az = az - (p * (r * x - p * z) - q * (q * z - r * y))
    gx, gy, gz = -G0 * np.sin(th), G0 * np.cos(th) * np.sin(ph), G0 * np.cos(th) * np.cos(ph)
    # airspeed: the acceleration along the air-velocity direction (vane beta is good enough
    # for the direction)
    ex, ey, ez = np.cos(a) * np.cos(bm), np.sin(bm), np.sin(a) * np.cos(bm)
    vint = _integral(ex * (ax + gx) + ey * (ay + gy) + ez * (az + gz), t)
    V = vint + _lowpass(Vm - vint, fc_V, rate_hz)
    # sideslip: v at the CG (vane moved to the CG, linear in the rates)
    bcg = bm - (r * xv - p * zv) / V
    u, w = V * np.cos(a) * np.cos(bcg), V * np.sin(a) * np.cos(bcg)
    vv = _integral(ay + gy + p * w - r * u, t) - (r * x - p * z)
    v = vv + _lowpass(V * np.sin(bcg) - vv, fc_beta, rate_hz)
    # angle of attack: w at the CG likewise (the vane's p y - q x moved out)
    acg = a - (p * yv - q * xv) / V
    ww = _integral(az + gz + q * u - p * v, t) - (p * y - q * x)
    w = ww + _lowpass(V * np.sin(acg) * np.cos(bcg) - ww, fc_alpha, rate_hz)
    return pd.DataFrame({"t": t, "V": V, "beta": np.arcsin(np.clip(v / V, -1.0, 1.0)), "alpha": np.arctan2(w, u)})
