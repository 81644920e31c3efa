"""The equation-error regression behind the control-input delays and lags: each surface's
axis's angular acceleration regressed on the measured variables and the surfaces moved by
trial delays and lags, over the maneuvers, with the linear coefficients profiled out
(variable projection); the joint least squares and its delete-a-group jackknife.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.optimize import least_squares

from pipeline.conditioning.input_dynamics.model import cubic_at, lagged
from pipeline.conditioning.input_smoothing import zero_phase
from pipeline.ingest.flightdata import FlightData

#: searched delays [s]: a servo command leads its surface by up to about 0.1 s; a measured
#: position lags it by a few ms (a negative delay). An estimate at an end of the range is
#: not applied: equation error is biased in turbulence (its rates carry the gusts' response)
DELAY_RANGE_S = (-0.02, 0.15)
#: searched lag time constants [s]
LAG_RANGE_S = (0.0, 0.15)
#: step of the grid the joint least squares starts from [s] (delays and lags)
GRID_STEP_S = 0.01
#: how close to an end of its range an estimate counts as at that end [s]
AT_END_S = 0.001
#: corner of the zero-phase low-pass on the response and the regressors [Hz], at most
#: LOWPASS_FRACTION of the grid rate
LOWPASS_HZ = 15.0
LOWPASS_FRACTION = 0.3
#: samples kept off each end of a maneuver (the filter's edge transient)
EDGE_SAMPLES = 10
#: time before a maneuver the lag starts from (its initial transient settles) [s]
LAG_LEAD_S = 1.0
#: groups of the delete-a-group jackknife over the maneuvers
JACKKNIFE_GROUPS = 10
#: function evaluations of the joint least squares before it stops unconverged (its
#: estimates are then not applied); the jackknife's refits get half
MAX_EVALUATIONS = 60


def moment_regressors(fd: FlightData) -> list[str]:
    """The measured variables besides the surfaces every moment equation is regressed on:
    the rates, alpha (else az, which carries the elevator's lift through the same lag),
    beta (required for the aileron and rudder), V and the throttle."""
    out = [c for c in ("p", "q", "r") if c in fd]
    out += ["alpha"] if "alpha" in fd else ["az"] if "az" in fd else []
    out += ["beta"] if "beta" in fd else []
    return out + [c for c in ("V", "throttle") if c in fd]


class Maneuvers:
    """The maneuvers of one axis on the regression grid: response, regressors and each
    surface low-passed on a grid reaching beyond the maneuver's ends (for the delays and
    the lag's start)."""

    def __init__(
        self,
        fd: FlightData,
        spans: Sequence[tuple[float, float]],
        rate: str,
        regressors: Sequence[str],
        surfaces: Sequence[str],
        rate_hz: float,
        corners: Mapping[str, float] | None = None,
    ):
        fc = min(LOWPASS_HZ, LOWPASS_FRACTION * rate_hz)
        after = max(abs(d) for d in DELAY_RANGE_S) + (EDGE_SAMPLES + 2) / rate_hz
        before = after + LAG_LEAD_S
        self.h = 1.0 / rate_hz
        self.surfaces = list(surfaces)
        self.t: list[np.ndarray] = []  # core times per maneuver
        self.y: list[np.ndarray] = []  # omega_dot [rad/s^2]
        self.X: list[np.ndarray] = []  # (n, len(regressors))
        self.grid: list[np.ndarray] = []  # times with the margins
        self.u: list[dict[str, np.ndarray]] = []  # surface -> low-passed on that grid
        self.qs: list[np.ndarray] = []  # dynamic pressure / its reference
        self._lagged: dict[tuple[str, float], list[np.ndarray]] = {}
        chans = [rate, *regressors, *surfaces]
        v_ref = float(np.nanmedian(fd["V"].values)) if "V" in regressors else 1.0
        for t0, t1 in spans:
            df = fd.resample(rate_hz, chans, t0=t0 - before, t1=t1 + after, unwrap=True)
            if len(df) < 4 * EDGE_SAMPLES + 20 or not np.all(np.isfinite(df[chans].to_numpy())):
                continue
            tg = df["t"].to_numpy()
            lp = {c: zero_phase(df[c].to_numpy(), rate_hz, min(fc, (corners or {}).get(c, fc)), order=4) for c in chans}
            idx = np.arange(tg.size)
            core = (tg >= t0) & (tg <= t1) & (idx >= EDGE_SAMPLES) & (idx < tg.size - EDGE_SAMPLES)
            if core.sum() < 20:
                continue
            # the moments scale with the dynamic pressure: the rate terms (p b / 2V) with
            # V, the angles', the surfaces' and the constant's with V^2 (unscaled, a few m/s
            # of airspeed change bias the lags)
            w = lp["V"][core] / v_ref if "V" in lp else np.ones(int(core.sum()))
            power = {"p": 1, "q": 1, "r": 1, "alpha": 2, "beta": 2, "V": 2}
            self.t.append(tg[core])
            self.y.append(np.gradient(lp[rate], tg)[core])
            self.X.append(
                np.column_stack([(w**2 if c == "V" else lp[c][core] * w ** power.get(c, 0)) for c in regressors])
            )
            self.qs.append(w**2)
            self.grid.append(tg)
            self.u.append({s: lp[s] for s in surfaces})

    def __len__(self) -> int:
        return len(self.t)

    def subset(self, keep: Sequence[int]) -> Maneuvers:
        """The same equation on the maneuvers ``keep`` (indices) only."""
        out = copy.copy(self)
        for name in ("t", "y", "X", "qs", "grid", "u"):
            setattr(out, name, [getattr(self, name)[k] for k in keep])
        out._lagged = {}
        return out

    def surface(self, s: str, delays: np.ndarray, lag: float) -> list[np.ndarray]:
        """Surface ``s`` through the lag, at t - d for each delay d, times the dynamic
        pressure's ratio: (K, n) per maneuver. Cubic between the samples (:func:`cubic_at`,
        smooth in d; linear reads kinked the residuals at every sample and the least
        squares stopped short). The lagged series are kept per lag (the delays' finite
        differences reuse them)."""
        key = (s, float(lag))
        if key not in self._lagged:
            if len(self._lagged) > 64:
                self._lagged.clear()
            self._lagged[key] = [lagged(u[s], lag, self.h) for u in self.u]
        return [
            q * cubic_at(v, g[0], self.h, t[None, :] - delays[:, None])
            for t, g, v, q in zip(self.t, self.grid, self._lagged[key], self.qs)
        ]


def _demeaned(parts: Sequence[np.ndarray], axis: int = 0) -> np.ndarray:
    """The maneuvers' arrays joined along ``axis``, each with its own mean removed (the
    per-maneuver intercept a_k profiled out)."""
    return np.concatenate([p - p.mean(axis=axis, keepdims=True) for p in parts], axis=axis)


def _basis(X: np.ndarray) -> np.ndarray:
    """Orthonormal basis (n, r) of the range of X (n, P): columns without independent
    variation (a throttle held through the maneuvers) drop out."""
    if not X.shape[1]:
        return X[:, :0]
    Q, sv, _ = np.linalg.svd(X, full_matrices=False)
    return Q[:, sv > 1e-9 * sv[0]] if sv.size and sv[0] > 0 else Q[:, :0]


def _ls_residuals(Z: np.ndarray, y: np.ndarray) -> np.ndarray:
    """y - Z c with c the least squares (normal equations of the column-scaled Z, a
    pseudo-inverse for columns without independent variation)."""
    scale = np.sqrt(np.einsum("ij,ij->j", Z, Z))
    Zs = Z / np.where(scale > 0, scale, 1.0)
    c = np.linalg.pinv(Zs.T @ Zs, rcond=1e-12, hermitian=True) @ (Zs.T @ y)
    return y - Zs @ c


def _rss(y: np.ndarray, Q: np.ndarray, U: np.ndarray) -> np.ndarray:
    """Residual sum of squares of y on [range(Q), U_k] for each stack U_k (ns, n) of U
    (K, ns, n): (K,)."""
    yp = y - Q @ (Q.T @ y)
    Up = U - (U @ Q) @ Q.T
    G = np.einsum("kin,kjn->kij", Up, Up)
    b = Up @ yp
    return float(yp @ yp) - np.einsum("ki,ki->k", b, (np.linalg.pinv(G, hermitian=True) @ b[..., None])[..., 0])


def _common_profile(m: Maneuvers, delays: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """RSS of the equation with every surface at the same (delay, lag): (n_lag, n_delay)."""
    Q = _basis(_demeaned(m.X))
    y = _demeaned(m.y)
    return np.array(
        [
            _rss(y, Q, np.stack([_demeaned(m.surface(s, delays, lag), axis=1) for s in m.surfaces], axis=1))
            for lag in lags
        ]
    )


def grid_start(m: Maneuvers) -> tuple[float, float]:
    """The start of the joint least squares for the surfaces of equation ``m``: the
    (delay, lag) they best share on the grid of GRID_STEP_S over the searched ranges,
    refined by the quadratic through the 3 x 3 points around the grid minimum (log RSS)
    when that is a minimum within them."""
    delays = np.arange(DELAY_RANGE_S[0], DELAY_RANGE_S[1] + 0.5 * GRID_STEP_S, GRID_STEP_S)
    lags = np.arange(LAG_RANGE_S[0], LAG_RANGE_S[1] + 0.5 * GRID_STEP_S, GRID_STEP_S)
    rss = _common_profile(m, delays, lags)
    j, k = np.unravel_index(int(np.argmin(rss)), rss.shape)
    d, tau = float(delays[k]), float(lags[j])
    if not (0 < k < delays.size - 1 and 0 < j < lags.size - 1):
        return d, tau
    z = np.log(np.maximum(rss[j - 1 : j + 2, k - 1 : k + 2], 1e-300))
    g = np.array([z[1, 2] - z[1, 0], z[2, 1] - z[0, 1]]) / 2.0
    H = np.array(
        [
            [z[1, 2] - 2 * z[1, 1] + z[1, 0], (z[2, 2] - z[2, 0] - z[0, 2] + z[0, 0]) / 4.0],
            [0.0, z[2, 1] - 2 * z[1, 1] + z[0, 1]],
        ]
    )
    H[1, 0] = H[0, 1]
    if np.all(np.linalg.eigvalsh(H) > 0):
        step = -np.linalg.solve(H, g)
        if np.all(np.abs(step) <= 1.0):
            d, tau = d + step[0] * GRID_STEP_S, max(tau + step[1] * GRID_STEP_S, 0.0)
    return d, tau


def _residuals(
    axes: Mapping[str, Maneuvers], dyn: Mapping[str, tuple[float, float]], weights: Mapping[str, float] | None = None
) -> list[np.ndarray]:
    """Per maneuver of each equation (``axes``: surface -> its equation's maneuvers), the
    residuals of the least-squares fit with every surface at its (delay, lag) in ``dyn``
    (the linear coefficients and intercepts solved for), times the equation's weight."""
    out = []
    for e, m in axes.items():
        moved = {o: m.surface(o, np.array([dyn[o][0]]), dyn[o][1]) for o in m.surfaces}
        cols = [np.column_stack([X] + [moved[o][k][0] for o in m.surfaces]) for k, X in enumerate(m.X)]
        r = _ls_residuals(_demeaned(cols), _demeaned(m.y)) * (1.0 if weights is None else weights[e])
        out += np.split(r, np.cumsum([t.size for t in m.t])[:-1])
    return out


def joint(
    axes: Mapping[str, Maneuvers],
    start: Mapping[str, tuple[float, float]],
    weights: Mapping[str, float] | None = None,
    max_nfev: int = MAX_EVALUATIONS,
) -> tuple[dict[str, tuple[float, float]], dict[str, float], list[np.ndarray], list[np.ndarray], bool]:
    """Every surface with maneuvers at once, over every equation (variable projection:
    the linear coefficients profiled out; each equation weighted by ``weights``, default
    1 / its residual rms at ``start``): (surface -> (delay, lag), the weights, Jacobian
    blocks (n, 1, 2 k) of the weighted prediction per maneuver, the weighted residuals per
    maneuver, converged within ``max_nfev`` evaluations)."""
    free = list(axes)
    dyn0 = dict(start)
    lo = np.array([DELAY_RANGE_S[0], LAG_RANGE_S[0]] * len(free))
    hi = np.array([DELAY_RANGE_S[1], LAG_RANGE_S[1]] * len(free))
    x0 = np.clip(np.array([v for s in free for v in start[s]]), lo, hi)

    def dyn(x: np.ndarray) -> dict[str, tuple[float, float]]:
        return {**dyn0, **{s: (float(x[2 * i]), float(x[2 * i + 1])) for i, s in enumerate(free)}}

    if weights is None:
        weights = {}
        for e, m in axes.items():
            r = np.concatenate(_residuals({e: m}, dyn(x0)))
            weights[e] = 1.0 / max(float(np.sqrt(np.mean(r**2))), 1e-300)

    def fun(x: np.ndarray) -> np.ndarray:
        return np.concatenate(_residuals(axes, dyn(x), weights))

    # diff_step is relative to max(1, |x|): 2e-4 s steps (delays and lags of 0.001-0.2 s);
    # xtol: steps below 0.01 ms end it. In strong gusts the landscape is flat and an
    # unbounded search runs for hundreds of iterations, hence the cap
    sol = least_squares(
        fun, x0, bounds=(lo, hi), x_scale=0.01, diff_step=2e-4, method="trf", xtol=1e-3, max_nfev=max_nfev
    )
    v = _residuals(axes, dyn(sol.x), weights)
    parts = np.cumsum([r.size for r in v])[:-1]
    return dyn(sol.x), weights, [-j[:, None, :] for j in np.split(sol.jac, parts)], v, sol.status > 0


def jackknife(
    axes: Mapping[str, Maneuvers], dyn: Mapping[str, tuple[float, float]], weights: Mapping[str, float]
) -> np.ndarray | None:
    """Delete-a-group jackknife covariance (2 k, 2 k) of the joint estimate over the
    maneuvers of every equation (at most JACKKNIFE_GROUPS groups; None with fewer than 3
    maneuvers): the spread the maneuvers' disagreement gives, which the Morelli-Klein
    bound of one fit cannot see (model error that differs between maneuvers)."""
    pairs = [(e, k) for e, m in axes.items() for k in range(len(m))]
    if len(pairs) < 3:
        return None
    groups = np.array_split(np.arange(len(pairs)), min(len(pairs), JACKKNIFE_GROUPS))
    est = []
    for grp in groups:
        drop = {pairs[i] for i in grp}
        sub = {e: m.subset([k for k in range(len(m)) if (e, k) not in drop]) for e, m in axes.items()}
        sub = {e: m for e, m in sub.items() if len(m)}
        if not sub:
            continue
        got = joint(sub, dyn, weights, max_nfev=MAX_EVALUATIONS // 2)[0]
        est.append([v for e in axes for v in got[e]])
    E = np.asarray(est)
    g = len(E)
    if g < 3:
        return None
    dev = E - E.mean(axis=0)
    return (g - 1) / g * dev.T @ dev
