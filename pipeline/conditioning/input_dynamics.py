"""The dynamics between a logged control input and the surface it moves: a pure delay and
a first-order lag per surface, estimated from the maneuvers and applied before estimation.

A log's surface position is often the servo *command* (ArduPilot RCOU/AETR, PX4 actuator
outputs, MAVLink SERVO_OUTPUT_RAW): the surface follows it through the servo's transport
delay and lag, tens of milliseconds on small-UAV servos. A measured position can instead
lag the surface (a filtered potentiometer: a negative delay). Output error and filter
error take the inputs as exact; at a 2 Hz short period a 40 ms delay is 29 deg of phase,
which a fit books on the damping and the control derivative. A pure delay does not stand
in for a lag: with a 50 ms servo lag on the commands of the default scenario (ArduPilot
.bin, ad hoc) output error put CLq 76 and Cldr 162 std off the truth as logged, still 14
and 74 std with the best pure delay (33, 16, 17 ms on de, da, dr), every derivative within
1.2 std with the delay and lag estimated here (lags 50, 57, 44 ms).

Model of surface s: delta_s(t) = L_tau_s[u_s](t - d_s), L_tau the first-order lag
1 / (tau s + 1) (tau = 0: none), d the delay (> 0: the surface acts after the logged value).

Estimate (equation error, no aircraft data needed): the angular acceleration of each
surface's axis (de -> pitch, da -> roll, dr -> yaw) is regressed on the measured variables,

    omega_dot(t) = a_k + sum_i c_i x_i(t) + sum_s b_s delta_s(t)          (k: the maneuver)

over the maneuvers on that surface, with x = p, q, r, the air-data angles (alpha, else
az; the sideslip is needed for the aileron and rudder), V and the throttle; the rates scaled by V / V_ref, the angles, the surfaces and a constant by
(V / V_ref)^2 (the dynamic pressure's share of each moment term). Every surface's (d, tau) is found over all the equations at once (variable
projection: the linear coefficients solved for inside a bounded least squares in the
delays and lags, each equation weighted by its residual rms), from a start where each
equation's surfaces share one (d, tau) found on a grid (aileron and rudder flown
together: one surface at a time stayed at the other's start). omega_dot is the central
difference of the gyro rate, and the response and every regressor are low-passed by the
same zero-phase filter: it commutes with the linear relation and with the lag, so the
regression stays consistent while the differentiated gyro noise above the maneuvers' band
goes. The surfaces are read between samples by cubic convolution (smooth in the delay).

std: the Cramér-Rao bound of the joint least squares, corrected for coloured residuals
(Morelli-Klein, :func:`estimators.validation.uncertainty.morelli_klein`), widened to the
delete-a-group jackknife over the maneuvers where that is larger (the maneuvers disagree
by more than one fit's residuals say: on the 50 ms lag above, the aileron's lag 57 +- 10
instead of +- 1.5 ms). A surface's dynamics are applied (:func:`with_input_dynamics`) when
its equivalent delay d + tau (the phase at low frequency) is at least SIGNIFICANT std from
zero and at least MIN_APPLIED_S (positive: a log lagging its surface by 10 ms or more
would need a position sensor filtered that slowly; on multiaxis_multisine_turbulence's
.bin, commands without lag, the gusts gave the rudder -19 +- 6 ms), and neither
estimate sits at an end of its range (DELAY_RANGE_S, LAG_RANGE_S: equation error is
biased in turbulence, see there).

Refined by output error (:func:`refine_by_output_error`, run by the pipeline when output
error is among the methods): the applied delays and lags are moved to where the output-
error fits match the data best (Gauss-Newton with the derivatives profiled out). Output
error sees a lag in every output, where equation error sees one differentiated rate. The
default scenario's .bin with a 50 ms servo lag (ad hoc): equation error's equivalent
delays 51.3, 56.9, 45.5 ms became 49.95, 49.88, 49.78, and the lateral proof of match,
which had failed on p (2.8 deg/s for a band of 1.5), passes (0.38). Over seeds
(benchmarks/input_dynamics_mc.py --refine 1) output error's Morelli-Klein std is honest
(empirical / reported 0.48-0.82 at 50 ms) but its estimates sit 0.2-0.7 ms off: the
refined std is at least REFINE_MIN_STD_S (1 ms), and widened to the difference from
equation error where the two disagree.

Known limits (ad hoc, the same flight logged more slowly):
* commands logged at 20 Hz (RCOU), angles rebuilt from the 10 Hz flight path: equation
  error gives the aileron and rudder 45 ms of pure delay and no lag, after which the
  lateral output error ended 61 std off (166 as logged); refined (43 ms and a 16 ms lag,
  std widened to the 16 ms difference) every derivative is within 0.9 std, but the
  lateral proof of match fails on p by a little (1.83 deg/s for 1.5);
* the IMU and the commands both at 25 Hz: refined, longitudinal within 3.8 std and
  lateral 2.7 (4.2 and 20 with equation error's values; 35 and 81 as logged); both proofs
  of match fail (q 1.9, p 4.0 deg/s). With the air data at 10 Hz and the GPS at 5 Hz too
  (the sideslip rebuilt at 5 Hz), equation error put 47 ms of delay and 86 ms of lag on
  the rudder (truth none) and the lateral output error did not converge with them: the
  run withdraws them when output error converges with the inputs as logged
  (:func:`pipeline.jobs.run.refine_input_dynamics_stage`; then within 1.9 std with the steps'
  unknown times carried, pipeline.conditioning.input_sampling, tests/test_input_sampling.py).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from pipeline.ingest.flightdata import CONTROL_INPUTS, Channel, FlightData

#: the rate each control input's moment equation is regressed on
AXIS_RATE = {"de": "q", "da": "p", "dr": "r"}
#: searched delays [s]: a servo command leads its surface by up to about 0.1 s; a measured
#: position lags it by a few ms (a negative delay). An estimate at an end of the range is
#: not applied: equation error is biased in turbulence (its rates carry the gusts' response),
#: and on multiaxis_multisine_turbulence's MCAP (the surfaces' own positions, no delay) it
#: put the aileron's delay at 216-228 ms (seeds 31-33, ad hoc) and the elevator's at the
#: lower end
DELAY_RANGE_S = (-0.02, 0.15)
#: searched lag time constants [s]
LAG_RANGE_S = (0.0, 0.15)
#: step of the grid the joint least squares starts from [s] (delays and lags)
GRID_STEP_S = 0.01
#: how close to an end of its range an estimate counts as at that end [s]
AT_END_S = 0.001
#: |equivalent delay| / std from which a surface's dynamics are applied
SIGNIFICANT = 3.0
#: the smallest equivalent delay applied [s]: one 100 Hz sample. Below it a shift is
#: within the logs' time-stamp resolution and the equation's own bias: the calm built-in
#: scenarios' ArduPilot .bin (commands, no servo lag) give -1.3 to +1.4 ms, significant on
#: sensor_errors_calm's rudder (ad hoc; an earlier version of this estimate 4.8 ms on the
#: default's aileron); servo lags are 20-100 ms
MIN_APPLIED_S = 0.01
#: corner of the zero-phase low-pass on the response and the regressors [Hz], at most
#: LOWPASS_FRACTION of the grid rate
LOWPASS_HZ = 15.0
LOWPASS_FRACTION = 0.3
#: highest rate of the regression grid [Hz]
MAX_RATE_HZ = 100.0
#: lowest gyro rate the delays are estimated from [Hz]: a 10-50 ms delay is a fraction of
#: a sample below it. At 25 Hz (an ArduPilot IMU; default.toml, seeds 1 and 3, ad hoc) the
#: estimates were the elevator's and aileron's delays at the -20 ms search bound and the
#: rudder's 43-57 ms with 79-85 ms of lag (truth none), withdrawn or, on a 100 Hz
#: regression grid, applied, the lateral fit then 2.8 total std off; a step between slow
#: samples is timed from the kink the surface's motion puts in the gyros instead
#: (pipeline.conditioning.input_sampling)
MIN_RATE_HZ = 40.0
#: samples kept off each end of a maneuver (the filter's edge transient)
EDGE_SAMPLES = 10
#: time before a maneuver the lag starts from (its initial transient settles) [s]
LAG_LEAD_S = 1.0
#: why the aileron's and rudder's dynamics are not estimated without a sideslip angle
LATERAL_NEEDS = (
    "needs the sideslip angle (a vane, or rebuilt from the flight path): with "
    "the lateral accelerometer instead the rudder's 50 ms lag came out 187 ms "
    "(the default scenario, ad hoc)"
)
#: groups of the delete-a-group jackknife over the maneuvers
JACKKNIFE_GROUPS = 10
#: function evaluations of the joint least squares before it stops unconverged (its
#: estimates are then not applied); the jackknife's refits get half
MAX_EVALUATIONS = 60

#: output-error refinement (:func:`refine_by_output_error`): Gauss-Newton iterations at
#: most, the step of its difference quotients [s], and when it stops (every change below
#: this fraction of its std)
REFINE_ITERATIONS = 10
REFINE_STEP_S = 0.002
REFINE_TOLERANCE = 0.1
#: ... or when a step lowers the weighted residual sum of squares (whitened by R: a
#: parameter 1 Cramér-Rao std off adds 1) by less than this (a delay and a lag seen on one
#: maneuver are nearly one parameter: steps trading them gain next to nothing)
REFINE_COST_GAIN = 1.0
#: the refinement's name in documents and reports
REFINE_METHOD = "output error"
#: what the refinement estimates
REFINED = ("delay_s", "lag_s")
#: output error's and equation error's values agree within this many combined std (else
#: the refined std is widened to their difference)
REFINE_AGREE = 3.0
#: the smallest std of a refined delay or lag [s]: over seeds (benchmarks/
#: input_dynamics_mc.py --refine 1) the aileron's and rudder's came out 0.2-0.5 ms off
#: (their Morelli-Klein std 0.1-0.2 ms; the simulator's servo and the log's sample timing),
#: and real logs stamp their samples no better than that
REFINE_MIN_STD_S = 0.001


def lagged(u: np.ndarray, tau: float, h: float) -> np.ndarray:
    """u (..., n) on a uniform grid of step h [s] through the first-order lag 1/(tau s + 1),
    exact for u linear between samples, started in steady state at u[..., 0]; tau [s] may
    be an array (K,) with u (n,) or (K, n): one lag per row."""
    from scipy.signal import lfilter

    taus = np.atleast_1d(np.asarray(tau, dtype=float))
    u = np.asarray(u, dtype=float)
    rows = np.broadcast_to(u, (taus.size, u.shape[-1])) if u.ndim == 1 else u
    out = np.array(rows, dtype=float, copy=True)
    for k, t in enumerate(taus):
        if t <= 1e-6 * h:  # no lag (or one far below a sample)
            continue
        a = np.exp(-h / t)
        b1 = 1.0 - t / h * (1.0 - a)  # weight of u_k (first-order hold)
        b = np.array([b1, 1.0 - a - b1])
        out[k] = lfilter(b, [1.0, -a], rows[k], zi=np.array([a * rows[k, 0]]))[0]
    return out if np.ndim(tau) or u.ndim > 1 else out[0]


def _regressors(fd: FlightData) -> list[str]:
    """The measured variables besides the surfaces every moment equation is regressed on:
    the rates, alpha (else az, which carries the elevator's lift through the same lag:
    the default scenario's 50 ms servo lag came out 49 ms either way), beta (required:
    see LATERAL_NEEDS), V and the throttle."""
    out = [c for c in ("p", "q", "r") if c in fd]
    out += ["alpha"] if "alpha" in fd else ["az"] if "az" in fd else []
    out += ["beta"] if "beta" in fd else []
    return out + [c for c in ("V", "throttle") if c in fd]


class _Maneuvers:
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
        from pipeline.conditioning.input_smoothing import zero_phase

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
            # V, the angles', the surfaces' and the constant's with V^2 (unscaled, the
            # small UAV's +-1-2 m/s put the aileron's lag 5 ms high on noise-free truth data)
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

    def subset(self, keep: Sequence[int]) -> _Maneuvers:
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


def cubic_at(v: np.ndarray, t0: float, h: float, x: np.ndarray) -> np.ndarray:
    """Samples v (n,) at t0 + k h interpolated at times x (any shape) by cubic convolution
    (Keys, a = -1/2: exact for quadratics, continuous first derivative); x is clipped to
    the samples' span."""
    n = v.size
    s = np.clip((np.asarray(x, dtype=float) - t0) / h, 0.0, n - 1.0)
    k = np.minimum(np.floor(s).astype(int), n - 2)
    f = s - k
    vp = np.concatenate([[2 * v[0] - v[1]], v, [2 * v[-1] - v[-2], 2 * v[-1] - v[-2]]])
    p0, p1, p2, p3 = vp[k], vp[k + 1], vp[k + 2], vp[k + 3]
    return p1 + 0.5 * f * (p2 - p0 + f * (2 * p0 - 5 * p1 + 4 * p2 - p3 + f * (3 * (p1 - p2) + p3 - p0)))


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


def _common_profile(m: _Maneuvers, delays: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """RSS of the equation with every surface at the same (delay, lag): (n_lag, n_delay)."""
    Q = _basis(_demeaned(m.X))
    y = _demeaned(m.y)
    return np.array(
        [
            _rss(y, Q, np.stack([_demeaned(m.surface(s, delays, lag), axis=1) for s in m.surfaces], axis=1))
            for lag in lags
        ]
    )


def _grid_start(m: _Maneuvers) -> tuple[float, float]:
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
    axes: Mapping[str, _Maneuvers], dyn: Mapping[str, tuple[float, float]], weights: Mapping[str, float] | None = None
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


def _joint(
    axes: Mapping[str, _Maneuvers],
    start: Mapping[str, tuple[float, float]],
    weights: Mapping[str, float] | None = None,
    max_nfev: int = MAX_EVALUATIONS,
) -> tuple[dict[str, tuple[float, float]], dict[str, float], list[np.ndarray], list[np.ndarray], bool]:
    """Every surface with maneuvers at once, over every equation (variable projection:
    the linear coefficients profiled out; each equation weighted by ``weights``, default
    1 / its residual rms at ``start``): (surface -> (delay, lag), the weights, Jacobian
    blocks (n, 1, 2 k) of the weighted prediction per maneuver, the weighted residuals per
    maneuver, converged within ``max_nfev`` evaluations)."""
    from scipy.optimize import least_squares

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
    # xtol: steps below 0.01 ms end it. Calm flights converge in 5-15 evaluations; in
    # strong gusts the landscape is flat and an unbounded search took 270 iterations
    # per fit (multiaxis_multisine_turbulence's MCAP: 153 s), hence the cap
    sol = least_squares(
        fun, x0, bounds=(lo, hi), x_scale=0.01, diff_step=2e-4, method="trf", xtol=1e-3, max_nfev=max_nfev
    )
    v = _residuals(axes, dyn(sol.x), weights)
    parts = np.cumsum([r.size for r in v])[:-1]
    return dyn(sol.x), weights, [-j[:, None, :] for j in np.split(sol.jac, parts)], v, sol.status > 0


def _jackknife(
    axes: Mapping[str, _Maneuvers], dyn: Mapping[str, tuple[float, float]], weights: Mapping[str, float]
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
        got = _joint(sub, dyn, weights, max_nfev=MAX_EVALUATIONS // 2)[0]
        est.append([v for e in axes for v in got[e]])
    E = np.asarray(est)
    g = len(E)
    if g < 3:
        return None
    dev = E - E.mean(axis=0)
    return (g - 1) / g * dev.T @ dev


def estimate_input_dynamics(fd: FlightData, *, surfaces: Sequence[str] = CONTROL_INPUTS) -> dict[str, Any]:
    """The delay and lag of each control input with maneuvers in ``fd`` (module doc).
    Returns a JSON-ready document: ``surfaces`` (name -> delay_s, lag_s, their std
    (delay_std, lag_std: Morelli-Klein widened to the jackknife; std_from says which)
    and correlation, equivalent_delay_s (d + tau) and equivalent_std, crb_std and mk_std
    of both, response (the rate whose derivative was regressed), maneuvers, samples,
    rate_hz, at_bound, significant, applied), ``applied`` (name -> {"delay_s", "lag_s"}),
    ``covariance`` (names "<surface> delay|lag" and the joint matrix), ``converged``,
    ``smoothed_hz`` (the regressors low-passed at their noise floor), ``method``,
    ``regressors``, and ``not_estimated`` (name -> why) for surfaces without maneuvers,
    gyro or sideslip."""
    from estimators.validation.uncertainty import morelli_klein
    from pipeline.conditioning.input_smoothing import control_input_corners

    doc: dict[str, Any] = {
        "method": (
            "equation error of the rate derivatives, all surfaces and axes at once; "
            f"delays {DELAY_RANGE_S[0] * 1e3:g}..{DELAY_RANGE_S[1] * 1e3:g} ms, first-order "
            f"lags {LAG_RANGE_S[0] * 1e3:g}..{LAG_RANGE_S[1] * 1e3:g} ms; Morelli-Klein std, "
            "widened to the maneuvers' jackknife"
        ),
        "surfaces": {},
        "applied": {},
        "not_estimated": {},
    }
    regs = _regressors(fd)
    doc["regressors"] = regs
    present = [s for s in surfaces if s in fd and len(fd[s]) > 1]
    # noisy measured variables are low-passed where their white noise floor begins: the
    # noise of a regressor biases least squares (errors in variables; the default
    # scenario's 0.17 deg vane noise put the lateral lags 7-15 ms high on 20 ms)
    corners = control_input_corners(fd, [c for c in (*regs, *present) if c not in AXIS_RATE.values()])
    doc["smoothed_hz"] = corners
    axes: dict[str, _Maneuvers] = {}
    for s in present:
        rate = AXIS_RATE[s]
        # its own maneuvers, and spans given without an axis (user or mode segments)
        spans = [(sg.t0, sg.t1) for sg in fd.segments if sg.axis in (s, None)]
        if rate not in fd:
            doc["not_estimated"][s] = f"no {rate} gyro channel"
            continue
        if s in ("da", "dr") and "beta" not in fd:
            doc["not_estimated"][s] = LATERAL_NEEDS
            continue
        if fd[rate].rate_hz < MIN_RATE_HZ:
            doc["not_estimated"][s] = (
                f"needs the {rate} gyro at >= {MIN_RATE_HZ:g} Hz, the log has "
                f"it at {fd[rate].rate_hz:.3g} Hz: a servo's 10-50 ms are a "
                "fraction of its sample interval (telemetry? use the onboard "
                "log; else log the IMU faster)"
            )
            continue
        if not spans:
            doc["not_estimated"][s] = "no maneuver on it"
            continue
        m = _Maneuvers(
            fd,
            spans,
            rate,
            [r for r in regs if r != rate] + [rate],
            present,
            float(min(fd[rate].rate_hz, MAX_RATE_HZ)),
            corners,
        )
        if len(m) == 0:
            doc["not_estimated"][s] = "its maneuvers lack samples of the needed channels"
            continue
        axes[s] = m
    if not axes:
        return doc
    # start: each equation's best with all its surfaces at one (delay, lag) (a grid
    # profile); then every surface's own pair over every equation at once
    start: dict[str, tuple[float, float]] = {s: (0.0, 0.0) for s in present}
    for s, m in axes.items():
        start[s] = _grid_start(m)
    dyn, weights, S, v, converged = _joint(axes, start)
    doc["converged"] = converged
    unc = morelli_klein(S, v)
    crb = np.sqrt(np.clip(np.diag(unc.crb_cov), 0.0, None))
    mk_all = np.sqrt(np.clip(np.diag(unc.cov), 0.0, None))
    widen = np.ones(mk_all.size)
    jk = _jackknife(axes, dyn, weights)
    if jk is not None:
        spread = np.sqrt(np.clip(np.diag(jk), 0.0, None))
        ok = mk_all > 1e-9  # (a lag at 0 has no std of its own)
        widen = np.where(ok, np.maximum(1.0, spread / np.where(ok, mk_all, 1.0)), 1.0)
    cov = unc.cov * np.outer(widen, widen)
    doc["covariance"] = {"names": [f"{s} {k}" for s in axes for k in ("delay", "lag")], "matrix": cov.tolist()}
    for i, s in enumerate(axes):
        d, tau = dyn[s]
        C = cov[2 * i : 2 * i + 2, 2 * i : 2 * i + 2]
        mk = mk_all[2 * i : 2 * i + 2]
        sd, sl = np.sqrt(np.clip(np.diag(C), 0.0, None))
        eq, eq_sd = d + tau, float(np.sqrt(max(C.sum(), 0.0)))
        inside = DELAY_RANGE_S[0] + AT_END_S < d < DELAY_RANGE_S[1] - AT_END_S and tau < LAG_RANGE_S[1] - AT_END_S
        significant = bool(converged and inside and np.isfinite(eq_sd) and eq_sd > 0 and abs(eq) >= SIGNIFICANT * eq_sd)
        applied = significant and eq >= MIN_APPLIED_S
        m = axes[s]
        doc["surfaces"][s] = {
            "delay_s": d,
            "delay_std": float(sd),
            "lag_s": tau,
            "lag_std": float(sl),
            "corr": float(C[0, 1] / (sd * sl)) if sd > 0 and sl > 0 else None,
            "equivalent_delay_s": eq,
            "equivalent_std": eq_sd,
            "crb_std": [float(crb[2 * i]), float(crb[2 * i + 1])],
            "mk_std": [float(x) for x in mk],
            "std_from": ("jackknife over maneuvers" if np.any(widen[2 * i : 2 * i + 2] > 1.0) else "Morelli-Klein"),
            "response": f"d{AXIS_RATE[s]}/dt",
            "maneuvers": len(m),
            "samples": int(sum(t.size for t in m.t)),
            "rate_hz": 1.0 / m.h,
            "at_bound": not inside,
            "significant": significant,
            "applied": bool(applied),
        }
        if applied:
            doc["applied"][s] = {"delay_s": d, "lag_s": tau}
    return doc


def covariance(doc: Mapping[str, Any]) -> tuple[list[str], np.ndarray, dict[str, tuple[str, str]]]:
    """(names, covariance, name -> (surface, "delay_s" | "lag_s")) of the applied
    dynamics of ``doc``: each applied surface's delay and lag with their joint covariance
    (``doc["covariance"]``; a value without a std - a lag at its bound 0 - left out)."""
    joint = doc.get("covariance") or {"names": [], "matrix": []}
    pos = {n: k for k, n in enumerate(joint["names"])}
    full = np.asarray(joint["matrix"], dtype=float)
    names, where = [], {}
    for s in doc.get("applied") or {}:
        for key in ("delay_s", "lag_s"):
            name = f"{s} {key[:-2]}"
            if name in pos and full[pos[name], pos[name]] > 0:
                names.append(name)
                where[name] = (s, key)
    if not names:
        return [], np.zeros((0, 0)), {}
    idx = [pos[n] for n in names]
    return names, full[np.ix_(idx, idx)], where


def _whitened(
    results: Mapping[str, Any], weights: Mapping[str, np.ndarray] | None = None
) -> tuple[list[np.ndarray], dict[str, np.ndarray]]:
    """Per fitted segment of every result (keys sorted) its residuals (N, n_out) times the
    whitening W of its result (W W^T = R^-1), missing samples 0; and the W used
    (``weights``, else each result's own R)."""
    from estimators.statistics import whitener

    if weights is None:
        weights = {k: whitener(np.atleast_2d(r.R)) for k, r in results.items()}
    if set(weights) != set(results):
        raise ValueError(f"the fits changed ({sorted(weights)} -> {sorted(results)})")
    out = []
    for k in sorted(results):
        for df in results[k].residuals:
            v = df.to_numpy(dtype=float)
            out.append(np.where(np.isfinite(v), v, 0.0) @ weights[k])
    return out, weights


def logged_inputs_fit_better(applied: Mapping[str, Mapping[str, float]], fit) -> str | None:
    """Why the output-error fits want the inputs as logged rather than with the delays and
    lags ``applied`` (surface -> {"delay_s", "lag_s"}), or None: ``fit(dynamics, None)``
    (as :func:`refine_by_output_error`'s) is run both ways; the logged inputs win when
    their fits converge and the fits with ``applied`` do not, or leave weighted residuals
    at least as large (each fit's residuals whitened by the logged fit's R: the same
    yardstick). For a refinement that could not settle: equation error's values are then
    worse than none."""
    try:
        logged = fit({}, None)
        moved = fit({s: dict(v) for s, v in applied.items()}, None)
    except Exception:  # noqa: BLE001 - either way failing: no verdict
        return None
    if not logged or not all(r.converged for r in logged.values()):
        return None
    if not all(r.converged for r in moved.values()):
        return "output error did not converge with them and did with the inputs as logged"
    v0, W = _whitened(logged)
    v1, _ = _whitened(moved, W)
    c0, c1 = (sum(float(np.sum(v * v)) for v in vs) for vs in (v0, v1))
    if c0 <= c1:
        return f"output error fits the inputs as logged at least as well (weighted residuals {c0:.6g} against {c1:.6g} with them)"
    return None


def refine_by_output_error(doc: dict[str, Any], fit, progress: Any = None) -> dict[str, Any]:
    """Refine the delays and lags ``doc`` applies (the document of
    :func:`estimate_input_dynamics`) by the output-error fits' own likelihood; when that
    succeeds they and their covariance replace the equation-error ones in ``doc``
    (``applied``, ``covariance``, each surface's ``refined``; the equation-error ones kept
    under ``equation_error``). Returns the refinement's document, also ``doc["refined"]``:
    status ("refined" or "not refined" with a reason), iterations, fits, seconds.

    ``fit(dynamics, starts)`` -> the output-error results (key -> EstimationResult) with
    ``dynamics`` (surface -> {"delay_s", "lag_s"}) applied to the data; ``starts``: None
    (a fit from the model's starts), key -> parameter values (a fit from there) or key ->
    EstimationResult (that result moved by one Gauss-Newton step, OutputError.step_from).

    Gauss-Newton on the delays and lags with the aerodynamic estimates profiled out: the
    sensitivity of the fits' whitened residuals to a delay or lag is the difference
    quotient of a fit and its one-step move (so the derivatives absorb what they can),
    REFINE_STEP_S apart; steps halved while the weighted residuals grow, bounded to
    DELAY_RANGE_S and LAG_RANGE_S; at most REFINE_ITERATIONS, done when every change is
    below REFINE_TOLERANCE std or a step gains less than REFINE_COST_GAIN. std: those
    sensitivities' Cramér-Rao bound corrected for coloured residuals (Morelli-Klein), at
    least REFINE_MIN_STD_S, widened to the difference from equation error's value where
    the two disagree by more than REFINE_AGREE combined std. A delay or lag the fits do
    not see (a surface whose axis is not fitted) keeps its equation-error value and std.
    Nothing changes when a fit fails or does not converge, or an estimate ends at its
    range's end."""
    import time

    t0 = time.perf_counter()
    applied = {s: dict(v) for s, v in doc["applied"].items()}
    keys = [(s, k) for s in applied for k in REFINED]
    lo = np.array([(DELAY_RANGE_S if k == "delay_s" else LAG_RANGE_S)[0] for _, k in keys])
    hi = np.array([(DELAY_RANGE_S if k == "delay_s" else LAG_RANGE_S)[1] for _, k in keys])
    x = np.array([applied[s][k] for s, k in keys], dtype=float)
    ref: dict[str, Any] = {
        "method": f"{REFINE_METHOD}: Gauss-Newton on the delays and lags, the derivatives profiled out; Morelli-Klein std",
        "status": "not refined",
    }
    doc["refined"] = ref
    count = [0]

    def dynamics(xv: np.ndarray) -> dict[str, dict[str, float]]:
        out = {s: dict(v) for s, v in applied.items()}
        for (s, k), val in zip(keys, xv):
            out[s][k] = float(val)
        return out

    def run(xv: np.ndarray, starts: Any) -> Mapping[str, Any]:
        count[0] += 1
        if progress is not None:
            progress.tick(str(count[0]))
        return fit(dynamics(xv), starts)

    def done(reason: str | None) -> dict[str, Any]:
        ref.update(fits=count[0], seconds=time.perf_counter() - t0)
        if reason:
            ref["reason"] = reason
        return ref

    try:
        base = run(x, None)
        bad = [k for k, r in base.items() if not r.converged]
        if not base:
            return done("no output-error fit on this log")
        if bad:
            return done(f"output error did not converge with the equation-error values ({', '.join(bad)})")
        it, converged = 0, False
        while True:
            v0, W = _whitened(base)
            cost0 = sum(float(np.sum(v * v)) for v in v0)
            cols = []
            for j in range(len(keys)):
                h = REFINE_STEP_S if x[j] + REFINE_STEP_S <= hi[j] else -REFINE_STEP_S
                xj = x.copy()
                xj[j] += h
                vj, _ = _whitened(run(xj, base), W)
                cols.append([(b - a) / h for a, b in zip(vj, v0)])  # d(output)/d(value)
            S = [np.stack([c[i] for c in cols], axis=-1) for i in range(len(v0))]
            M = sum(np.einsum("nap,naq->pq", s, s) for s in S)
            seen = np.diag(M) > 1e-12 * max(float(np.max(np.diag(M))), 1e-300)
            Minv = np.zeros_like(M)
            Minv[np.ix_(seen, seen)] = np.linalg.pinv(M[np.ix_(seen, seen)], hermitian=True)
            step = Minv @ sum(np.einsum("nap,na->p", s, v) for s, v in zip(S, v0))
            sd = np.sqrt(np.clip(np.diag(Minv), 0.0, None))
            it += 1
            moved, lam = None, 1.0
            for _ in range(4):
                xn = np.clip(x + lam * step, lo, hi)
                new = run(xn, {k: dict(r.params) for k, r in base.items()})
                if all(r.converged for r in new.values()):
                    vn, _ = _whitened(new, W)
                    cn = sum(float(np.sum(v * v)) for v in vn)
                    if cn < cost0:
                        moved = (xn, new, cost0 - cn)
                        break
                lam *= 0.5
            if moved is None:  # no better point along the step: at the minimum
                converged = True
                break
            change = np.abs(moved[0] - x)
            x, base, gain = moved
            if np.all(change <= REFINE_TOLERANCE * sd) or gain < REFINE_COST_GAIN:
                converged = True
                break
            if it >= REFINE_ITERATIONS:
                break
    except Exception as exc:  # noqa: BLE001 - a failed refinement keeps equation error's values
        return done(f"a fit failed ({type(exc).__name__}: {exc})")
    ref["iterations"] = it
    if not converged:
        return done(f"not converged in {REFINE_ITERATIONS} Gauss-Newton iterations")
    ends = [
        f"{s} {k[:-2]}"
        for (s, k), val, a, b in zip(keys, x, lo, hi)
        if val >= b - AT_END_S or (k == "delay_s" and val <= a + AT_END_S)
    ]
    if ends:
        return done(f"{', '.join(ends)} at the end of its range")
    names = [f"{s} {k[:-2]}" for s, k in keys]
    cov, mk, crb, apart = _refined_covariance(
        S, v0, Minv, seen, x, np.array([applied[s][k] for s, k in keys]), names, doc
    )
    refined = dynamics(x)
    doc["equation_error"] = {"applied": applied, "covariance": doc["covariance"]}
    doc["applied"] = refined
    doc["covariance"] = {"names": names, "matrix": cov.tolist()}
    sd = np.sqrt(np.diag(cov))
    for j, (s, k) in enumerate(keys):
        if seen[j]:
            doc["surfaces"][s].setdefault("refined", {}).update(
                {
                    k: float(x[j]),
                    k[:-2] + "_std": float(sd[j]),
                    k[:-2] + "_crb_std": float(crb[j]),
                    k[:-2] + "_mk_std": float(mk[j]),
                    k[:-2] + "_widened": bool(apart[j]),
                }
            )
    if not np.all(seen):
        ref["not_seen"] = [n for n, ok in zip(names, seen) if not ok]
    ref["status"] = "refined"
    return done(None)


def _refined_covariance(
    S: list[np.ndarray],
    v0: list[np.ndarray],
    Minv: np.ndarray,
    seen: np.ndarray,
    x: np.ndarray,
    was: np.ndarray,
    names: list[str],
    doc: Mapping[str, Any],
) -> tuple[np.ndarray, ...]:
    """(covariance, Morelli-Klein std, Cramér-Rao std, apart) of the refined values ``x``
    (equation error's ``was``; named ``names``, "<surface> delay|lag"; ``seen`` by the
    fits) from the last Gauss-Newton iteration of :func:`refine_by_output_error` (its
    whitened sensitivities ``S`` and residuals ``v0`` per segment, ``Minv``), ``doc``
    still equation error's; ``apart``: where the two methods disagree."""
    from estimators.validation.uncertainty import coloured_information

    # the std: output error's Morelli-Klein one, at least REFINE_MIN_STD_S, where equation
    # error agrees (within REFINE_AGREE combined std); where it does not, the data cannot
    # tell them apart (the commands or the gyro logged slowly: a delay and a lag of a few
    # samples trade against each other) and the std is widened to their difference. A
    # value output error does not see keeps equation error's std. Equation error's value
    # at its bound (a lag of 0) has no std of its own: 0 there.
    n_out = [v.shape[1] for v in v0]
    mid, _ = coloured_information(S, v0, [np.eye(n) for n in n_out])
    cov = Minv @ mid @ Minv
    mk = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    crb = np.sqrt(np.clip(np.diag(Minv), 0.0, None))
    old = doc["covariance"]
    pos = {n: i for i, n in enumerate(old["names"])}
    ee = np.asarray(old["matrix"], dtype=float)
    sd_ee = np.array([np.sqrt(max(ee[pos[n], pos[n]], 0.0)) if n in pos else 0.0 for n in names])
    diff = np.abs(x - was)
    apart = seen & (diff > REFINE_AGREE * np.hypot(sd_ee, mk))
    want = np.maximum(np.where(apart, np.maximum(mk, diff), mk), REFINE_MIN_STD_S)
    widen = np.where(mk > 0, want / np.where(mk > 0, mk, 1.0), 1.0)
    cov = cov * np.outer(widen, widen)
    for j in np.flatnonzero(~seen | ~(mk > 0)):
        cov[j, :] = cov[:, j] = 0.0
        cov[j, j] = sd_ee[j] ** 2 if not seen[j] else want[j] ** 2
    return 0.5 * (cov + cov.T), mk, crb, apart


def with_input_dynamics(fd: FlightData, dynamics: Mapping[str, Mapping[str, float]]) -> FlightData:
    """``fd`` with each control input of ``dynamics`` (name -> {"delay_s", "lag_s"}) as
    its surface moves: the logged values through the lag, read back at the channel's own
    times less the delay (the models see L[u](t - d)); ``fd`` itself unchanged, and
    returned as it is when nothing changes. The lag runs on a uniform grid at the channel's
    median interval, started in steady state; before its first sample (after its last)
    the channel holds its first (last) value. The time stamps stay the log's, so every
    grid built from the data is the same whatever the dynamics (the output-error
    refinement compares fits sample by sample)."""
    todo = {
        s: (float(v.get("delay_s", 0.0)), float(v.get("lag_s", 0.0)))
        for s, v in dynamics.items()
        if s in fd.channels and len(fd.channels[s]) > 1
    }
    todo = {s: dl for s, dl in todo.items() if dl != (0.0, 0.0)}
    if not todo:
        return fd
    chans = dict(fd.channels)
    for s, (d, tau) in todo.items():
        c = chans[s]
        g, vals = c.t, c.values
        if tau > 0.0:
            h = float(np.median(np.diff(c.t)))
            g = np.arange(c.t[0], c.t[-1] + 0.5 * h, h)
            vals = lagged(np.interp(g, c.t, c.values), tau, h)
        chans[s] = Channel(
            c.t,
            np.interp(c.t - d, g, vals),
            c.unit,
            f"{c.source} (as its surface: delay {d * 1e3:.1f} ms, lag {tau * 1e3:.1f} ms estimated)",
            c.notes,
            c.derived,
        )
    meta = dict(fd.meta)
    meta["input_dynamics"] = {s: {"delay_s": d, "lag_s": tau} for s, (d, tau) in todo.items()}
    return FlightData(chans, meta, list(fd.segments))


def summary(doc: Mapping[str, Any]) -> str:
    """One line for report.md from the document of :func:`estimate_input_dynamics` or of
    the run's stage (skipped, given, failed)."""
    status = doc.get("status", "estimated")
    if status == "skipped":
        return f"not estimated: {doc.get('reason', 'skipped')}"
    if status == "failed":
        return f"estimate failed ({doc.get('reason', '')}); inputs as logged"
    if status == "given":
        return (
            ", ".join(
                f"{s} delay {v['delay_s'] * 1e3:+.1f} ms, lag {v['lag_s'] * 1e3:.1f} ms"
                for s, v in doc["applied"].items()
            )
            + " (given)"
        )
    parts = []
    for s, d in (doc.get("surfaces") or {}).items():
        state = (
            "applied"
            if d["applied"]
            else "withdrawn: " + d["withdrawn"]
            if d.get("withdrawn")
            else "at the search bound, not applied"
            if d["at_bound"]
            else "the log lagging its surface, not applied"
            if d["significant"] and d["equivalent_delay_s"] < 0
            else f"below {MIN_APPLIED_S * 1e3:g} ms, not applied"
            if d["significant"]
            else "not significant"
        )
        ref = d.get("refined") or {}
        if ref:  # (a surface no output-error fit sees keeps equation error's values)
            apart = [k for k in ("delay", "lag") if ref.get(f"{k}_widened")]
            state = (
                f"{REFINE_METHOD}; equation error {d['delay_s'] * 1e3:+.1f} and "
                f"{d['lag_s'] * 1e3:.1f} ms"
                + (f", the two apart on the {' and '.join(apart)}: std widened to the difference" if apart else "")
                + f"; {state}"
            )
        v = {k: ref[k] if ref.get(k) is not None else d[k] for k in ("delay_s", "delay_std", "lag_s", "lag_std")}
        parts.append(
            f"{s} delay {v['delay_s'] * 1e3:+.1f} +- {v['delay_std'] * 1e3:.1f} ms, lag "
            f"{v['lag_s'] * 1e3:.1f} +- {v['lag_std'] * 1e3:.1f} ms ({state})"
        )
    parts += [f"{s}: {why}" for s, why in (doc.get("not_estimated") or {}).items()]
    line = "; ".join(parts) or "no control input with maneuvers"
    if not doc.get("converged", True):
        line += (
            f"; the least squares did not converge in {MAX_EVALUATIONS} evaluations (strong gusts?): nothing applied"
        )
    refinement = doc.get("refined") or {}
    if refinement.get("status") == "not refined":
        line += f"; not refined by {REFINE_METHOD} ({refinement.get('reason', '')})"
    unc = doc.get("uncertainty") or {}
    if unc:
        bad = {k: v for k, v in unc["methods"].items() if v != "propagated"}
        line += "; their std carried to the estimates' std as a consider part" + (
            f" (except {'; '.join(f'{k}: {v}' for k, v in bad.items())})" if bad else ""
        )
    return line
