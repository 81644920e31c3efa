"""Equation-error regressions of the force and moment coefficients on the maneuver windows,
and the start values of output error drawn from them.

The coefficients are computed from the measured specific forces and the differentiated
angular rates, with the sensors moved to the CG, and regressed on the states and inputs
the built-in models use; least squares on them gives flyable start values.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
import pandas as pd

from pipeline.conditioning.input_smoothing import zero_phase
from pipeline.problems.pseudo_inputs import PSEUDO_INPUT_CORNER_HZ

#: zero-phase low-pass corner (Hz) of the lateral equation-error regressions
LATERAL_LS_CORNER_HZ = 3.0


class Regression(NamedTuple):
    """One equation-error regression on the maneuver windows: the coefficient, the
    parameter names of X's columns (None: an intercept that is no model parameter), X
    (N, k), y (N,), the window (N,) each row comes from (0, 1, ... in the order given:
    the maneuver clusters of estimators.covariance.cluster) and its time t (N,) in s (the
    frequency-domain regression transforms each window's rows)."""

    coef: str
    names: list
    X: np.ndarray
    y: np.ndarray
    window: np.ndarray
    t: np.ndarray


def _window_rows(parts: Sequence[np.ndarray]) -> np.ndarray:
    """The window index of each row of the stacked ``parts``."""
    return np.concatenate([np.full(len(a), k) for k, a in enumerate(parts)]) if parts else np.zeros(0, int)


def longitudinal_regressions(
    frames: Sequence[pd.DataFrame], c: Mapping[str, float], thrusts: Sequence[np.ndarray]
) -> list[Regression]:
    """Equation-error regressions of the longitudinal coefficients on the maneuver windows:
    CL, CD, Cm computed from the measured specific forces and the differentiated pitch rate,
    regressed on [1, alpha, q cbar/2V, de] (CL, Cm) and [1, alpha, alpha^2] (CD), NaN rows
    removed. Rows at the samples of the pitch rate (an IMU slower than the grid is NaN
    between its samples; the rate is differentiated over its own samples), the other
    channels read there (:func:`_at_rows`); those with air data of their own when most
    have."""
    rows = {"L": [], "D": [], "M": []}
    yL, yD, yM, times = [], [], [], []
    xv, zv = c.get("x_vane", 0.0), c.get("z_vane", 0.0)
    yv = c.get("y_vane", 0.0)
    xi, zi = c.get("x_imu", 0.0), c.get("z_imu", 0.0)
    for df, T in zip(frames, thrusts):
        at = np.flatnonzero(np.isfinite(df["q"].to_numpy(dtype=float)))
        t = df["t"].to_numpy()[at]
        q = df["q"].to_numpy(dtype=float)[at]
        Vv, av, de, ax, az = (_at_rows(df, k, at) for k in ("V", "alpha", "de", "ax", "az"))
        T = np.asarray(T, dtype=float)[at] if np.ndim(T) else np.full(at.size, float(T))
        qdot = np.gradient(q, t) if at.size > 1 else np.full(at.size, np.nan)
        # air data and accelerations moved from the sensors to the CG (the inverse of the
        # model's sensor terms): the vane reads alpha - q x_vane / V, which a regression
        # would otherwise book on CLq and Cmq
        u = Vv * np.cos(av) - q * zv
        w = Vv * np.sin(av) + q * xv
        if yv and "p" in df and "r" in df:  # wing-tip boom: + p y_vane in w, - r y_vane in u
            u = u + _at_rows(df, "r", at) * yv
            w = w - _at_rows(df, "p", at) * yv
        V, a = np.hypot(u, w), np.arctan2(w, u)
        ax = ax - qdot * zi + q * q * xi
        az = az + qdot * xi + q * q * zi
        qbar = 0.5 * c["rho"] * V**2
        CX = (c["m"] * ax - T) / (qbar * c["S"])
        CZ = c["m"] * az / (qbar * c["S"])
        CL = -CZ * np.cos(a) + CX * np.sin(a)
        CD = -CX * np.cos(a) - CZ * np.sin(a)
        Cm = c["Iyy"] * qdot / (qbar * c["S"] * c["cbar"])
        qh = q * c["cbar"] / (2 * V)
        one = np.ones_like(a)
        # rows where the air data are measured too (an air-data sensor slower than the IMU,
        # on its clock) when at least half the rate's samples have them; else (another phase,
        # another clock) every rate sample, the air data read between their own samples
        own = np.isfinite(df["V"].to_numpy(dtype=float)[at]) & np.isfinite(df["alpha"].to_numpy(dtype=float)[at])
        sel = own if own.sum() >= 0.5 * at.size else np.ones(at.size, dtype=bool)
        times.append(t[sel])
        rows["L"].append(np.column_stack([one, a, qh, de])[sel])
        yL.append(CL[sel])
        rows["D"].append(np.column_stack([one, a, a * a])[sel])
        yD.append(CD[sel])
        # the differentiated rate is the mean of qdot between the neighbouring samples: Cm's
        # regressors are their means over the same span (else a 25 Hz IMU's elevator steps,
        # sharp against a pitch acceleration averaged over 80 ms, bias Cmde and Cmq low)
        rows["M"].append(np.column_stack([one, _simpson_means(a), _simpson_means(qh), _span_means(df, "de", at)])[sel])
        yM.append(Cm[sel])
    out = []
    t_rows = np.concatenate(times) if times else np.zeros(0)
    for key, coef, y, names in (
        ("L", "CL", yL, ["CL0", "CLalpha", "CLq", "CLde"]),
        ("D", "CD", yD, ["CD0", "CDalpha", "CDalpha2"]),
        ("M", "Cm", yM, ["Cm0", "Cmalpha", "Cmq", "Cmde"]),
    ):
        X = np.vstack(rows[key])
        Y = np.concatenate(y)
        ok = np.all(np.isfinite(X), axis=1) & np.isfinite(Y)
        out.append(Regression(coef, names, X[ok], Y[ok], _window_rows(rows[key])[ok], t_rows[ok]))
    return out


def _simpson_means(x: np.ndarray) -> np.ndarray:
    """x's mean between each sample's neighbours by Simpson's rule, (x[k-1] + 4 x[k] +
    x[k+1]) / 6 (the ends as they are): a smooth signal's mean over the span np.gradient
    differentiates over, to second order in the sample interval."""
    out = x.copy()
    out[1:-1] = (x[:-2] + 4.0 * x[1:-1] + x[2:]) / 6.0
    return out


def _span_means(df: pd.DataFrame, k: str, at: np.ndarray) -> np.ndarray:
    """Column k of the grid ``df`` (NaN between slow samples filled) averaged, for each of
    the rows ``at`` (grid indices, increasing), over the grid samples strictly between its
    neighbouring rows (at either end: from the row to the next one's): the span np.gradient
    differentiates over, each grid sample standing for its own step. On rows at every grid
    time that is the row's own value."""
    x = _filled(df, k)
    if at.size < 2:
        return x[at]
    lo = np.r_[at[0], at[:-2] + 1, at[-2] + 1]
    hi = np.r_[at[1] - 1, at[2:] - 1, at[-1]]
    hi = np.maximum(hi, lo)
    csum = np.r_[0.0, np.cumsum(x)]
    return (csum[hi + 1] - csum[lo]) / (hi - lo + 1)


def longitudinal_starts(
    frames: Sequence[pd.DataFrame], c: Mapping[str, float], thrusts: Sequence[np.ndarray]
) -> dict[str, float]:
    """Equation-error start values: least squares of CL, CD, Cm computed from the measured
    specific forces and the differentiated pitch rate on the maneuver windows."""
    sol = {}
    for reg in longitudinal_regressions(frames, c, thrusts):
        names, X, Y = reg.names, reg.X, reg.y
        beta = np.linalg.lstsq(X, Y, rcond=None)[0]
        sol.update(zip(names, beta))
    # keep the signs that make a flyable start (stable pitch damping, positive lift slope)
    sol["Cmq"] = min(sol["Cmq"], -1.0)
    sol["Cmalpha"] = min(sol["Cmalpha"], -0.05)
    sol["CLalpha"] = max(sol["CLalpha"], 1.0)
    return {k: float(v) for k, v in sol.items()}


def _filled(df: pd.DataFrame, k: str) -> np.ndarray:
    """Column k with NaN gaps (a slow channel between its samples) linearly interpolated."""
    x = df[k].to_numpy(dtype=float)
    ok = np.isfinite(x)
    if ok.all() or ok.sum() < 2:
        return x
    t = df["t"].to_numpy()
    return np.interp(t, t[ok], x[ok])


def _at_rows(df: pd.DataFrame, k: str, rows: np.ndarray) -> np.ndarray:
    """Column k at the rows ``rows`` of ``df``: its value where it has one, else linear
    between its own neighbouring samples when those are no further apart than 1.5 of its
    typical (median) spacing: a channel slower than the grid or on another phase is read
    between its samples, never across a gap in them (a dropout, or the accelerometers left
    out inside a control-input step, :data:`pipeline.problems.windows.FEEDTHROUGH_OUTPUTS`),
    which stays NaN."""
    x = df[k].to_numpy(dtype=float)
    if np.isfinite(x[rows]).all():
        return x[rows]
    t = df["t"].to_numpy()
    ok = np.flatnonzero(np.isfinite(x))
    if ok.size < 2:
        return x[rows]
    spacing = np.diff(t[ok])
    j = np.clip(np.searchsorted(t[ok], t[rows]), 1, ok.size - 1)  # the samples either side
    near = spacing[j - 1] <= 1.5 * np.median(spacing)
    out = np.interp(t[rows], t[ok], x[ok])
    inside = (t[rows] >= t[ok[0]]) & (t[rows] <= t[ok[-1]])
    return np.where(np.isfinite(x[rows]), x[rows], np.where(near & inside, out, np.nan))


def lateral_regressions(frames: Sequence[pd.DataFrame], c: Mapping[str, float]) -> list[Regression]:
    """Equation-error regressions: CY (from ay), Cl and Cn (from the differentiated roll and
    yaw rates with the inertia coupling) on [1, beta, p b/2V, r b/2V, da, dr]; the intercept
    is the trim-asymmetry term CY0, Cl0, Cn0 (with the measured sideslip as regressor: the
    vane's bias is in it, and the accelerometer's in CY0). The dynamic pressure and b/2V follow the
    measured airspeed sample by sample (column ``V`` when the frames have it, else the
    constant ``c["V"]``), as the airspeed wanders during cross-controlled sideslips.
    Columns ``V_kin``, ``beta_kin`` (:mod:`pipeline.conditioning.airdata_kinematics`), when present,
    replace the measured airspeed and sideslip: vane noise on the beta regressor (errors
    in variables, nearly collinear with dr and r in cross-controlled maneuvers) biases
    CYbeta, CYdr and Cndr. Slow outputs (NaN between their samples) are interpolated, then
    every signal is low-passed at LATERAL_LS_CORNER_HZ."""
    X, Y, times = [], {"CY": [], "Cl": [], "Cn": []}, []
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
        # differentiated after it): np.gradient of the raw rates would average the fast
        # roll response at each surface step over two samples while the steps in da, dr
        # stay sharp, and bias Cl, Cn low
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
        times.append(t[keep])
        X.append(np.column_stack([np.ones_like(p), beta, p * k, r * k, da, dr])[keep])
        Y["CY"].append((c["m"] * ay / (qbar * c["S"]))[keep])
        Y["Cl"].append((L / (qbar * c["S"] * c["b"]))[keep])
        Y["Cn"].append((N / (qbar * c["S"] * c["b"]))[keep])
    A = np.vstack(X)
    window = _window_rows(X)
    t_rows = np.concatenate(times) if times else np.zeros(0)
    out = []
    for coef, ys in Y.items():
        y = np.concatenate(ys)
        ok = np.all(np.isfinite(A), axis=1) & np.isfinite(y)
        # the intercept is the model's trim-asymmetry term (CY0, Cl0, Cn0), estimated when free
        names = [f"{coef}{n}" for n in ("0", "beta", "p", "r", "da", "dr")]
        out.append(Regression(coef, names, A[ok], y[ok], window[ok], t_rows[ok]))
    return out


def lateral_starts(
    frames: Sequence[pd.DataFrame], c: Mapping[str, float], regressions: Sequence | None = None
) -> dict[str, float]:
    """Equation-error start values: least squares of CY (from ay), Cl and Cn (from the
    differentiated roll and yaw rates with the inertia coupling) on the maneuver windows
    (``regressions``: those of :func:`lateral_regressions` when already formed)."""
    out: dict[str, float] = {}
    for reg in regressions if regressions is not None else lateral_regressions(frames, c):
        names, A, y = reg.names, reg.X, reg.y
        sol = np.linalg.lstsq(A, y, rcond=None)[0]
        for name, v in zip(names[1:], sol[1:]):
            out[name] = float(v)
    # flyable start: directional stability, roll and yaw damping of the usual sign
    out["Cnbeta"] = max(out["Cnbeta"], 0.01)
    out["Clp"] = min(out["Clp"], -0.05)
    out["Cnr"] = min(out["Cnr"], -0.01)
    return out


def start_note(start: Mapping[str, float]) -> str:
    """The problem note listing the equation-error start values."""
    return "start values from equation error: " + ", ".join(f"{k}={v:.3g}" for k, v in start.items())
