"""The main job: scenario -> JSBSim flight -> log files -> ingest -> checks -> estimate ->
validate -> report.md / report.json / run.rrd (DESIGN.md section 5).

Estimation always starts from the written log files (the path a user's real log takes),
never from the simulator's in-memory tables. ``estimate_log`` is the same chain for a
real log with an aircraft description.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.conditioning.flow_angles import rebuilt
from pipeline.conditioning.input_sampling import step_times, time_steps
from pipeline.conditioning.input_sampling import summary as step_summary
from pipeline.errors import FsidError
from pipeline.paths import atomic_write_text
from pipeline.problems.identify import (
    LAT_OUTPUTS,
    LONG_OUTPUTS,
    MAX_RATE_HZ,
    AircraftConstants,
    Problem,
    lateral_problem,
    longitudinal_problem,
    multi_axis,
    multiaxis_problem,
    with_airspeed_offsets,
)
from pipeline.problems.sixdof import sixdof_lateral_problem

#: methods the run knows; the scenario or the command line picks among them
METHODS = ("oem", "ls", "fem", "ekf", "ukf", "soem", "eigen", "decouple")
#: what each name runs (for --help and the report)
METHOD_HELP = {
    "oem": "output error (calm air)",
    "ls": "equation error: least squares on the coefficients from measured accelerations",
    "fem": "filter error (process and measurement noise; turbulence)",
    "ekf": "extended Kalman filter with the parameters in the state",
    "ukf": "unscented Kalman filter with the parameters in the state",
    "soem": "stabilised output error (unstable aircraft)",
    "eigen": "output error with eigenvalue transformation (unstable aircraft)",
    "decouple": "output error with equation decoupling (unstable aircraft)",
}
#: methods whose problem is built on the grid of the slowest output channel (FEM's
#: steady-state gain is that of every output; the Kalman filters would update on some
#: outputs only); filter error's multi-axis gust models leave out the angles rebuilt from
#: the flight path (_method_problem)
COMMON_GRID = frozenset({"fem", "ekf", "ukf"})


def _count(n: int, noun: str) -> str:
    """``"1 maneuver"``, ``"3 maneuvers"``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def scenario_methods(truth: Mapping[str, Any] | None) -> list[str]:
    """The methods that suit a flight: a statically unstable aircraft flown with a SAS
    (truth ``sas``) -> stabilised output error, equation decoupling, FEM, EKF, UKF (the
    eigenvalue transformation is exact for linear models only and the built-in
    longitudinal model is nonlinear: ``--method eigen`` stays available for a linear user
    model); turbulence -> OEM (kept to show its bias), FEM, EKF, UKF; calm air -> OEM and
    equation error."""
    truth = truth or {}
    if truth.get("sas"):
        return ["soem", "decouple", "fem", "ekf", "ukf"]
    if (truth.get("turbulence") or {}).get("model", "off") not in ("off", None, ""):
        return ["oem", "fem", "ekf", "ukf"]
    return ["oem", "ls"]


class Progress:
    """Stage-by-stage progress on stderr: '[2/7] ingest flight.bin ... 1.2 s'."""

    def __init__(self, total: int, stream=None, quiet: bool = False) -> None:
        self.total, self.n, self.stream, self.quiet = total, 0, stream or sys.stderr, quiet
        self.t0 = time.perf_counter()

    def stage(self, text: str) -> Progress:
        self.n += 1
        self._t = time.perf_counter()
        if not self.quiet:
            print(f"[{self.n}/{self.total}] {text} ...", end="", file=self.stream, flush=True)
        return self

    def substage(self, text: str) -> Progress:
        """A second part of the stage just done, on a line of its own under it (counted
        with that stage: a part that only some logs need keeps the count right)."""
        self._t = time.perf_counter()
        if not self.quiet:
            print(
                f"{' ' * (len(str(self.n)) + len(str(self.total)) + 3)} {text} ...",
                end="",
                file=self.stream,
                flush=True,
            )
        return self

    def tick(self, text: str) -> None:
        """A step within the current stage, on its line (an iteration, a refit)."""
        if not self.quiet:
            print(f" {text}", end="", file=self.stream, flush=True)

    def done(self, extra: str = "") -> None:
        if not self.quiet:
            dt = time.perf_counter() - self._t
            print(f" {dt:.1f} s{(' - ' + extra) if extra else ''}", file=self.stream, flush=True)


def measurement_noise_std(problem: Problem, logged: bool = True) -> np.ndarray:
    """Measurement-noise std per output (the filters' R): with ``logged``,
    ``problem.noise_std`` where it has the output (from the log's native samples,
    :func:`attach_logged_noise`); else from the fitted segments: sqrt(var(second
    differences) / 6), exact for white noise on a signal that is locally linear over two
    samples."""
    from estimators.statistics import difference_noise_std

    sd = difference_noise_std([s.z for s in problem.fit])
    logged = (problem.noise_std or {}) if logged else {}
    sd = np.array([logged.get(o, v) for o, v in zip(problem.model.outputs, sd)], dtype=float)
    return np.where(np.isfinite(sd) & (sd > 0), sd, 1e-6)


def attach_logged_noise(fd, problem: Problem) -> Problem:
    """Set ``problem.noise_std`` for each output that is a logged channel: its white-noise
    std from the native samples in the fitted windows, as it appears on the problem's grid
    (FlightData.noise_std with the grid rate: the anti-alias filter of the resampling
    lowers it). On the grid itself the second differences of a fast signal mistake its
    curvature for noise, and the filtered noise is no longer white: on the 50 Hz grid of
    multiaxis_multisine_turbulence they gave the gyro p 0.0018 rad/s, for a noise of
    0.0017 at 100 Hz that the resampling brings to 0.0011; with that R the lateral FEM's
    Clp/Clda moved from 5.9/5.6 to 4.8/4.9 std off the truth (seed 31), 2.5 to 2.1 at worst
    on seed 33. Returns the problem."""
    rate = problem.rate_hz or None
    wins = [(s.t0, s.t1) for s in problem.specs]
    problem.noise_std = {
        o: sd
        for o in problem.model.outputs
        if o in fd
        for sd in [fd.noise_std(o, wins, rate)]
        if np.isfinite(sd) and sd > 0
    }
    return problem


def process_noise_std(
    problem: Problem, turbulence: Mapping[str, Any] | None = None, scale: float = 1.0
) -> dict[str, float]:
    """Process-noise std F (state unit per sqrt(s)) for the filters.

    From a Dryden turbulence level (``sigma_u``, ``sigma_w`` m/s, scale lengths ``L_u``,
    ``L_w`` m, as truth.json holds them) when known: a first-order gust of std sigma and
    time constant L/V has the white-noise intensity sigma sqrt(2 V / L), so
    F_V = sigma_u sqrt(2V/L_u), F_alpha = sigma_w/V sqrt(2V/L_w), and F_q = 0.3 F_alpha
    for what the alpha noise does not carry into the pitch rate (FEM estimated 0.33 on
    the turbulence scenario). Lateral: beta, p, r likewise from sigma_v (F_p = F_r = 0.3
    F_beta). A gust model (rotary-gust states) without a known level starts from light
    turbulence at the flight's altitude (:func:`assumed_turbulence`; a real log): the data
    default below leaves its unmeasured gust states at 0, where their time constant has no
    effect on the likelihood (multiaxis_multisine_turbulence, the Dryden level withheld:
    filter error stopped at a singular information matrix on tau_pg, and on the
    longitudinal axis, started from the default's F_alpha 7x below the gusts', at one on
    CLq, CLalphadot and the initial airspeeds). Otherwise (a real log, a model without
    gust states) the FilterError default: 0.05 sqrt(var(diff z)/h) per measured state.
    Everything times ``scale``."""
    m = problem.model
    turb = turbulence or {}
    if not dryden_known(turb) and any(st in m.states for st in COLOURED_STATES):
        turb = assumed_turbulence(problem)
    if dryden_known(turb):
        V = _mean_airspeed(problem)
        su, sv, sw = (float(turb.get(k, turb["sigma_w"])) for k in ("sigma_u", "sigma_v", "sigma_w"))
        Lu, Lv, Lw = (float(turb.get(k, 300.0)) for k in ("L_u", "L_v", "L_w"))
        rot = _rotary_gust_std(m, V, sw, Lw)
        if problem.axis == "longitudinal":
            fa = sw / V * np.sqrt(2 * V / Lw)
            return {"V": scale * su * np.sqrt(2 * V / Lu), "alpha": scale * fa, "q": scale * 0.3 * fa, **rot}
        fb = sv / V * np.sqrt(2 * V / Lv)
        return {"beta": scale * fb, "p": scale * 0.3 * fb, "r": scale * 0.3 * fb, **rot}
    from estimators.filters.kalman import default_process_noise

    f = default_process_noise(m, problem.fit)
    return {st: float(scale * v) for st, v in zip(m.states, f) if st in m.outputs}


def _mean_airspeed(problem: Problem) -> float:
    """Mean measured airspeed over the fitted segments (m/s), else the model's constant V."""
    m = problem.model
    if "V" in m.outputs:
        return float(np.nanmean(np.concatenate([s.z[:, m.outputs.index("V")] for s in problem.fit])))
    return float(m.constants.get("V", 30.0))


def _rotary_gust_std(m: Any, V: float, sigma_w: float, L_w: float) -> dict[str, float]:
    """F of the rotary gust states of a gust model (first-order Markov, time constant
    4b/(pi V)): the MIL-F-8785C roll-gust level sigma_w sqrt(0.8 / (L_w b)) (pi L_w / 4b)^(1/6)
    (0.052 rad/s on multiaxis_multisine_turbulence; JSBSim flew p_g 0.049, q_g 0.041
    rad/s); q_gi, the part of the pitch gust not coherent with w_g, at half of it (FEM
    estimated F_q_gi 0.078 there, 0.48 x). Not times a scale: these states are coloured
    already (the filters' 2x is for white noise standing in for Dryden gusts)."""
    rot = {}
    for st, k in (("p_g", 1.0), ("q_gi", 0.5)):
        if st in m.states:
            b = float(m.constants["b"])
            sg = sigma_w * np.sqrt(0.8 / (L_w * b)) * (np.pi * L_w / (4 * b)) ** (1 / 6)
            rot[st] = k * sg * np.sqrt(2 * np.pi * V / (4 * b))
    return rot


def assumed_turbulence(problem: Problem) -> dict[str, float]:
    """The Dryden level of light turbulence (MIL-F-8785C: 15 kt at 20 ft, probability of
    exceedance 1e-2, as sim.turbulence tabulates it) at the flight's altitude, taken from
    the model's air density (ISA): the start of filter error's process noise for the gust
    states when no turbulence level is known (a real log); FEM then estimates it."""
    from pipeline.problems.identify import isa_altitude
    from sim.turbulence import dryden_parameters

    rho = float(problem.model.constants.get("rho", 1.225))
    return {"model": "assumed light", **dryden_parameters(isa_altitude(rho), 15 * 0.514444, 3)}


def dryden_known(turbulence: Mapping[str, Any] | None) -> bool:
    """Whether a Dryden turbulence level is given (truth.json of a simulated flight)."""
    turb = turbulence or {}
    return turb.get("model", "off") not in ("off", None, "") and bool(turb.get("sigma_w"))


#: states of the gust models that are coloured already (first-order Markov): the filters
#: take FEM's F for them as it is, not doubled (see process_noise_std)
COLOURED_STATES = ("p_g", "q_gi")


def filter_process_noise(fem: Any, scale: float = 2.0) -> dict[str, float]:
    """EKF/UKF process noise (state -> F, state unit per sqrt(s)) from a filter-error fit of
    the same model: FEM's maximum-likelihood F times ``scale`` (the filters' 2x for white
    noise standing in for coloured gusts, as with the Dryden level), gust states x1. Used
    when no turbulence level is known (a real log): with the 0.05 sqrt(var(diff z)/h)
    default, EKF CLalpha ended 5.3 std and Cmalpha 4.5 std off the truth on
    longitudinal_3211_turbulence through ``fsid estimate``."""
    out = {}
    for name, v in fem.params.items():
        if name.startswith("F_"):
            st = name[2:]
            out[st] = float(v) * (1.0 if st in COLOURED_STATES else scale)
    return out


def _filter_param_std(model: Any) -> dict[str, float]:
    """Initial parameter std of the Kalman filters: loose for derivatives, twice the start
    value and at least 0.3 (the initial covariance acts as a prior centred on the
    equation-error start: at the EKF default of half the start it held the weakly excited
    drag polar, CDalpha2, at 5 std from the truth on longitudinal_3211_turbulence), and a
    sensor-bias scale for the per-segment output biases (0.02 rad/s, 0.3 m/s^2, 0.01 rad,
    1 m/s)."""
    out = {}
    for p in model.parameters:
        if not p.free:
            continue
        if p.name.startswith("bias_"):
            o = p.name[5:]
            out[p.name] = (
                0.02 if o in ("p", "q", "r") else 0.3 if o in ("ax", "ay", "az") else 1.0 if o == "V" else 0.01
            )
        elif p.name.endswith("alphadot"):
            out[p.name] = 10.0  # CLalphadot, Cmalphadot start at 0: no prior pull
        elif p.name == "tau_pg":
            out[p.name] = 0.1 * p.value  # a time constant: UKF sigma points must stay > 0
        else:
            out[p.name] = max(2.0 * abs(p.value), 0.3)
    return out


def equation_error(problem: Problem) -> Any:
    """``ls``: ordinary least squares of the problem's coefficient regressions, returned on
    the problem's dynamic model so that validation, report and recording treat it as any
    other method: the derivatives (free, with their OLS std s^2 (X^T X)^-1) are the
    regression estimates; per-segment initial states and output biases are then fitted by
    output error with every derivative held (they are not part of the regression), and the
    predictions and residuals are that simulation's."""
    from estimators import EstimationResult, LeastSquares, OutputError

    model = problem.model
    est, var, regs, clusters = {}, {}, [], []
    for coef, names, X, y, window in problem.regressions:
        keep = [i for i, n in enumerate(names) if n is not None]
        cols = [n if n is not None else "bias" for n in names]
        res = LeastSquares(cols if names[0] is not None else cols[1:], intercept=names[0] is None, response=coef).fit(
            X if names[0] is not None else X[:, 1:], y
        )
        regs.append(res)
        for i in keep:
            n = names[i]
            est[n] = float(res.params[n])
            var[n] = float(res.std[n]) ** 2
        clusters.append(_regression_clusters(X, y, window, cols, res))
    free = [p.name for p in model.parameters if p.free and not p.per_segment and p.name in est]
    held = model.with_values({n: est[n] for n in free}).fixed(free)
    sim = OutputError(held, inputs=problem.inputs, fallback="never").fit(problem.fit, estimate_x0=problem.estimate_x0)
    names = list(sim.names)
    is_free = np.array([n in free for n in names])
    cov = np.diag([var[n] for n in names if n in free])
    # each regression's covariance block (CL0~CLalpha ...) instead of the diagonal only
    idx = {n: i for i, n in enumerate([n for n in names if n in free])}
    for res in regs:
        rn = [n for n in res.free_names if n in idx]
        sub = res.cov[np.ix_([res.free_names.index(n) for n in rn], [res.free_names.index(n) for n in rn])]
        for a, na in enumerate(rn):
            for b, nb in enumerate(rn):
                cov[idx[na], idx[nb]] = sub[a, b]
    n_samples = sum(len(r.residuals[0]) for r in regs)
    return EstimationResult(
        method="ls",
        model=model,
        names=names,
        values=np.asarray(sim.values, dtype=float),
        free=is_free,
        cov=cov,
        R=sim.R,
        converged=True,
        iterations=1,
        history=sim.history,
        predicted=sim.predicted,
        residuals=sim.residuals,
        segments=list(problem.fit),
        message=(
            f"equation error (OLS) on {', '.join(r.outputs[0] for r in regs)} from "
            f"{n_samples // max(len(regs), 1)} samples; predictions: the model with these "
            "derivatives, initial states and biases fitted"
        ),
        settings={"integrator": sim.settings.get("integrator", "rk4"), "optimizer": "ols", "inputs": problem.inputs},
        extra={
            "regressions": regs,
            "x0_and_biases": sim,
            **(
                {"cluster": _joined_clusters(clusters, [n for n in names if n in free])}
                if clusters and all(c is not None for c in clusters)
                else {}
            ),
        },
    )


def _regression_clusters(X: np.ndarray, y: np.ndarray, window: np.ndarray, cols: list[str], res):
    """The maneuver scatter of one regression (estimators.validation.cluster): each
    window's X_j^T X_j / s^2 and X_j^T e_j / s^2 at the OLS estimate; None with fewer than
    MIN_SEGMENTS windows or a singular X."""
    from estimators.validation import cluster_covariance
    from estimators.validation.cluster import MIN_SEGMENTS

    wins = np.unique(window)
    if wins.size < MIN_SEGMENTS:
        return None
    beta = np.array([float(res.params[c]) for c in cols])
    e = y - X @ beta
    s2 = float(e @ e) / max(len(y) - len(cols), 1)
    parts = [(X[window == k].T @ X[window == k] / s2, X[window == k].T @ e[window == k] / s2) for k in wins]
    try:
        return cluster_covariance([p[0] for p in parts], [p[1] for p in parts], names=cols)
    except (ValueError, np.linalg.LinAlgError):
        return None


def _joined_clusters(clusters: list, names: list[str]):
    """One ClusterResult over ``names`` from the regressions' (independent fits: block
    diagonal)."""
    from estimators.validation import ClusterResult

    p = len(names)
    cov = np.zeros((p, p))
    crb = np.full(p, np.nan)
    share = np.zeros((max(c.n_segments for c in clusters), p))
    for c in clusters:
        mine = [(names.index(n), k) for k, n in enumerate(c.names) if n in names]
        rows, cols = [a for a, _ in mine], [k for _, k in mine]
        cov[np.ix_(rows, rows)] = c.cov[np.ix_(cols, cols)]
        crb[rows] = c.crb_std[cols]
        share[: c.n_segments, rows] = c.share[:, cols]
    bad = ~np.isfinite(np.diag(cov))
    cov[bad, :] = np.nan
    cov[:, bad] = np.nan
    return ClusterResult(names=list(names), cov=cov, crb_std=crb, share=share, limit=clusters[0].limit)


def raw_starts(problem: Problem) -> dict[str, float]:
    """The equation-error estimates without the 'flyable' sign clamps of the problem's
    start values (stable Cmalpha, Cmq; positive lift slope). The clamps protect plain
    output error, whose simulation must not diverge; the stabilised methods and the
    filters keep their predictions bounded and need the unstable sign where the data
    show it (an unstable aircraft's Cmalpha > 0, which the clamp would flip)."""
    out = {}
    free = {p.name for p in problem.model.parameters if p.free}
    for _, names, X, y, _ in problem.regressions:
        sol = np.linalg.lstsq(X, y, rcond=None)[0]
        out.update({n: float(v) for n, v in zip(names, sol) if n is not None and n in free})
    return out


def _states_at_cg(model: Any):
    """Pseudo-inputs for equation decoupling: the vane's V and alpha moved to the CG with
    the measured pitch rate (u = V_v cos a_v - q z_vane, w = V_v sin a_v + q x_vane), other
    states as measured. Without it the vane's q x_vane / V in alpha enters the decoupled
    pitch equation as Cmalpha x_vane / V q and biases Cmq (by +1.3 on
    unstable_short_period: -2.6 for a truth of -3.6)."""
    c, outs = model.constants, model.outputs
    xv, zv = float(c.get("x_vane", 0.0)), float(c.get("z_vane", 0.0))
    if not ({"V", "alpha", "q"} <= set(outs)) or (xv == 0.0 and zv == 0.0):
        return None

    def pseudo(seg, states):
        V, a, q = (seg.z[:, outs.index(k)] for k in ("V", "alpha", "q"))
        V = np.interp(seg.t, seg.t[np.isfinite(V)], V[np.isfinite(V)])
        a_ok = np.isfinite(a)
        a = np.interp(seg.t, seg.t[a_ok], a[a_ok])
        q = np.interp(seg.t, seg.t[np.isfinite(q)], q[np.isfinite(q)])
        u, w = V * np.cos(a) - q * zv, V * np.sin(a) + q * xv
        cg = {"V": np.hypot(u, w), "alpha": np.arctan2(w, u)}
        return np.column_stack([cg[s] if s in cg else seg.z[:, outs.index(s)] for s in states])

    return pseudo


def fit_problem(
    problem: Problem,
    method: str,
    *,
    turbulence: Mapping[str, Any] | None = None,
    process_noise: Mapping[str, float] | None = None,
    measurement_noise: Mapping[str, float] | None = None,
    callback: Callable[[int, float, Any], None] | None = None,
    start: Mapping[str, float] | None = None,
) -> Any:
    """Run one estimation method on a problem (names in METHODS). ``turbulence``: the
    Dryden level when known (truth.json), for the filters' process noise; else
    ``process_noise`` (EKF/UKF: state -> F, e.g. :func:`filter_process_noise`), else the
    data's default. ``measurement_noise``: EKF/UKF R as output -> std (default: the grid's
    second differences). ``start``: output error's and filter error's start values by
    expanded name (initial states ``x0_V[0]`` and per-segment parameters included: a refit
    from an earlier estimate). ``callback``: called after each iteration (OEM, FEM) or pass (EKF,
    UKF) as callback(iteration, cost, params)."""
    import estimators as E

    model, inputs, x0 = problem.model, problem.inputs, problem.estimate_x0
    if method not in ("oem", "ls") and problem.regressions:
        model = model.with_values(raw_starts(problem))
    if method == "oem":
        return E.OutputError(model, inputs=inputs, priors=problem.priors or None, callback=callback).fit(
            problem.fit, estimate_x0=x0, start=start
        )
    if method == "ls":
        return equation_error(problem)
    if method == "fem":
        # nonlinear form (integrator prediction, gain of the linearisation at each
        # segment's start); process noise started from the turbulence level and
        # estimated; R started at the second-difference noise level (no output-error run
        # from equation-error starts that may diverge) and estimated by relaxation
        def fem(m, estimate_F: bool = True):
            return E.FilterError(
                m,
                form="nonlinear",
                inputs=inputs,
                process_noise=process_noise_std(problem, turbulence),
                measurement_noise=measurement_noise_std(problem),
                estimate_F=estimate_F,
                callback=callback,
            ).fit(problem.fit, estimate_x0=x0, start=start)

        res = fem(model)
        if not res.converged:
            res = _fem_restart(problem, model, res, fem)
        return res
    if method in ("ekf", "ukf"):
        cls = E.EKF if method == "ekf" else E.UKF
        # twice the gust intensity: the filters' process noise also has to carry what the
        # white-noise stand-in for coloured (Dryden) gusts misses while the parameters are
        # still uncertain; at 1x Cmalpha ended 4.5 std and Cmq 3.5 std from the truth on
        # longitudinal_3211_turbulence, at 2x all derivatives within 2.4 std (FEM, which
        # estimates F, lands at 0.8-1.2x)
        # R from the grid's own second differences, the level the 2x process noise was
        # tuned with: with the log's native-rate noise (lower on the 100 Hz IMU channels, see
        # attach_logged_noise) and the same Q, EKF/UKF CL0, CLde, CLq on
        # multiaxis_multisine_turbulence went from within 3 to 3.7-5.7 std off the truth.
        # Filter error's noise model instead (the path of a log, filters_process_noise), ad
        # hoc on that scenario, seeds 31-38 (benchmarks/multiaxis_seeds.py, the level known
        # withheld from the filters only): lateral UKF within 3 std on 2/8 seeds (0/8 here),
        # longitudinal EKF/UKF worst 5.3-11.2 std (3.7-7.4 here), the lateral EKF 3.5-79
        # either way; and with the logged noise levels as R (fsid estimate, seed 31):
        # lateral EKF Clp 34 -> 51, longitudinal CLq 4.7 -> 7.4 std
        Q = (
            process_noise_std(problem, turbulence, 2.0)
            if dryden_known(turbulence) or process_noise is None
            else {k: v for k, v in process_noise.items() if k in model.states}
        )
        return cls(
            model,
            inputs=inputs,
            process_noise=Q,
            measurement_noise=(
                dict(measurement_noise)
                if measurement_noise is not None
                else measurement_noise_std(problem, logged=False)
            ),
            param_std=_filter_param_std(model),
            callback=callback,
        ).fit(problem.fit)
    if method == "soem":
        # feed back only the short-period measurements where the model has them: with V and
        # theta fed back too, CL0/CLalpha/CLde ended 17-25 std off on unstable_short_period
        fb = ["alpha", "q"] if {"alpha", "q"} <= set(model.states) else None
        # central differences: with forward ones the line search stalls at the optimum of
        # the stabilised problem (det R settled to 7e-5, reported as not converged)
        return E.StabilizedOutputError(model, inputs=inputs, feedback=fb, jacobian="central").fit(
            problem.fit, estimate_x0=x0
        )
    if method == "eigen":
        if problem.axis == "longitudinal":
            # the transformation x~ = x e^{-sigma t} is exact for linear models only; in the
            # nonlinear longitudinal model V~ -> 0 sits in denominators (qbar, q c/2V, L/mV)
            # and the transformed simulation blows up within ~2 s
            raise E.ModelDefinitionError(
                "eigenvalue transformation needs a linear model; the longitudinal model is "
                "nonlinear (use soem, decouple or the filters for this axis)"
            )
        return E.EigenvalueTransformation(model, inputs=inputs).fit(problem.fit, estimate_x0=x0)
    if method == "decouple":
        # decouple only the destabilising coupling where the model has it (alpha in the
        # pitch equation of the longitudinal model); every measured state otherwise
        states = ["alpha"] if "alpha" in model.states else None
        return E.EquationDecoupling(model, states=states, inputs=inputs, pseudo=_states_at_cg(model)).fit(
            problem.fit, estimate_x0=x0
        )
    raise FsidError(f"unknown method {method!r}: use one of {', '.join(METHODS)}")


def _fem_restart(problem: Problem, model: Any, res: Any, fem: Callable[..., Any]) -> Any:
    """Filter error again when its fit did not converge: first the derivatives with the
    process noise (F, and the gust models' time constants) held at their starts, then
    everything from there. The result of lower cost is kept, and the problem's notes say
    which. Equation-error starts can be far off in turbulence: multiaxis_multisine_
    turbulence's ArduPilot log flown with aileron-rudder multisines only (seed 37, angles
    rebuilt) started at CYp 0.87 (truth -0.075), Clp -0.13 (-0.48); FEM wandered (F_p_g to
    0, tau_pg to its bound) and stopped after 30 iterations with CYbeta, Clbeta 200+ std
    off; from the truth it converged in 6 at a cost 4.7x lower."""
    held = {
        n: model.parameter(n).value
        for n in GUST_NOISE_PARAMETERS
        if n in model.parameter_names and model.parameter(n).free
    }
    first = fem(model.hold(held) if held else model, estimate_F=False)
    free = {n for n in model.parameter_names if model.parameter(n).free}
    again = fem(model.with_values({n: v for n, v in first.params.items() if n in free}))
    better = again.cost < res.cost
    problem.notes.append(
        f"filter error did not converge from the equation-error starts (det R {res.cost:.4g}); "
        f"refitted with the process noise held first, then free: det R {again.cost:.4g}, "
        f"{'converged' if again.converged else 'not converged'}; "
        f"{'that fit is kept' if better else 'the first fit is kept'}"
    )
    return again if better else res


#: methods whose estimate does not depend on the start values once converged (maximum
#: likelihood / least squares): a refit may start from an earlier estimate
START_FREE = ("oem", "ls", "fem", "soem", "eigen", "decouple")


#: (damping, angle-of-attack-rate) derivative pairs of the gust models
ALPHADOT_PAIRS = (("CLq", "CLalphadot"), ("Cmq", "Cmalphadot"))
#: |correlation| of a pair above which the flight does not separate them
ALPHADOT_CORR = 0.9


def _unidentifiable_alphadot(exc: Any, alphadot: Sequence[str]) -> str | None:
    """The note for holding CLalphadot, Cmalphadot at 0 when a fit with them free stopped
    on a singular information matrix that names one of them (an IdentifiabilityError),
    else None: the flight does not separate them from CLq, Cmq at all. Ad hoc, a calm 600 s
    log of the small UAV's elevator 3-2-1-1s: filter error stopped there, "CLq,
    CLalphadot cannot be identified"."""
    named = [n for n in (getattr(exc, "parameters", None) or []) if n in alphadot]
    if not named:
        return None
    return (
        "CLalphadot, Cmalphadot held at 0: this flight does not separate them from CLq, "
        f"Cmq (with them free the information matrix was singular in {', '.join(named)}), "
        "so CLq and Cmq carry their effect (Cmq estimates about Cmq + Cmalphadot)"
    )


def _inseparable_alphadot(pb: Problem, res: Any) -> str | None:
    """The note for holding CLalphadot, Cmalphadot at 0 when a fit with them free could not
    separate them from CLq, Cmq (|correlation| above :data:`ALPHADOT_CORR` for either
    pair; the report's flag of near-linear dependence), else None. The gust angle of attack
    separates alphadot from q only where the turbulence is strong against the maneuver.
    Measured with FEM (ad hoc): longitudinal_3211_turbulence (small UAV, 3-2-1-1s, truth
    CLalphadot = Cmalphadot = 0), seeds 11-15: |corr| 0.89-0.94, held on every seed (seed
    12 with them free: CLq -13.4 +- 4.3, CLalphadot 11.8 +- 4.3, Cmalphadot 3.1 std off;
    held, every derivative within 1.4 std); the light aircraft's multisines keep them
    free: 0.32 (multiaxis_multisine_turbulence, seed 31), 0.66-0.72 flown with elevator
    multisines only (flight.mcap, seed 34; 0.45-0.57 from its .bin)."""
    free = set(res.free_names)
    pairs = [(a, b) for a, b in ALPHADOT_PAIRS if a in free and b in free]
    if not pairs:
        return None
    corr = res.corr
    r = {f"{a}~{b}": float(corr.loc[a, b]) for a, b in pairs}
    if max(abs(v) for v in r.values()) <= ALPHADOT_CORR:
        return None
    return (
        "CLalphadot, Cmalphadot held at 0: this flight does not separate them from CLq, "
        f"Cmq (correlation {', '.join(f'{k} {v:+.2f}' for k, v in r.items())} with them "
        "free), so CLq and Cmq carry their effect (Cmq estimates about Cmq + Cmalphadot)"
    )


def fit_and_validate(
    pb: Problem,
    method: str,
    what: str,
    truth: Mapping[str, float] | None,
    progress: Progress,
    *,
    turbulence: Mapping[str, Any] | None = None,
    tolerances: Mapping[str, float] | None = None,
    pom: str = "auto",
    start: Mapping[str, float] | Any = None,
    process_noise: Mapping[str, float] | None = None,
    calm_air: bool = False,
    held_alphadot: str | None = None,
) -> tuple[Any, dict[str, Any] | None] | None:
    """Fit ``method`` on ``pb`` and validate the result on its held-out segments, with a
    progress stage each; ``what`` names the fit in messages ("lateral axis", "model 'x'").
    A method that fails - an EstimationError (plain OEM diverging on an unstable aircraft)
    or a singular matrix inside a method on a model it cannot handle - is reported and
    gives None: one method failing must not cost the others. Returns (result, validation).

    start : a refit (:mod:`pipeline.uncertainty.consider`): fit only, no validation
        (returns (result, None)), starting from these values (or the values of this
        earlier result) for the methods of ``START_FREE`` (the EKF/UKF estimate depends on
        its start: they start as before). Output error given its earlier result moves it
        by one Gauss-Newton step with that fit's sensitivities
        (:meth:`estimators.OutputError.step_from`) instead of refitting.
    calm_air: the held-out maneuvers are known to be flown in calm air (see
        :func:`pipeline.validation.validate.validate`).
    held_alphadot: the note of another method's fit of this axis that held CLalphadot,
        Cmalphadot (its ``extra["alphadot_held"]``): this fit holds them too, so the
        methods estimate, and are cross-checked on, the same derivatives. Otherwise a fit
        that cannot separate them from CLq, Cmq is repeated with them held
        (:func:`_inseparable_alphadot`)."""
    from estimators import EstimationError, EstimationResult, IdentifiabilityError, ModelDefinitionError, OutputError
    from pipeline.validation.validate import validate

    earlier = start if isinstance(start, EstimationResult) else None
    start = start.params if earlier is not None else start
    refit = start is not None
    alphadot = [b for _, b in ALPHADOT_PAIRS if b in pb.model.parameter_names and pb.model.parameter(b).free]
    if refit and alphadot and all(start.get(b) == 0.0 for b in alphadot):
        # the fit this one repeats held them (_inseparable_alphadot; a free estimate is
        # never exactly 0)
        pb = replace(pb, model=pb.model.hold({b: 0.0 for b in alphadot}))
    elif alphadot and held_alphadot:
        pb = replace(
            pb,
            model=pb.model.hold({b: 0.0 for b in alphadot}),
            notes=[*pb.notes, f"{held_alphadot} (found by filter error's fit)"],
        )
        alphadot = []
    if refit and method in START_FREE and len(start):  # (then fit_problem's equation-error starts off)
        free = {p.name for p in pb.model.parameters if p.free}  # held values stay the problem's
        pb = replace(
            pb,
            model=pb.model.with_values({n: v for n, v in start.items() if n in free}),
            regressions=pb.regressions if method == "ls" else [],
        )
    if not refit:
        progress.stage(
            f"estimate {what} ({method.upper()}, {pb.model.name} model, "
            f"{_count(len(pb.fit), 'maneuver')}, {len(pb.held_out)} held out, {pb.rate_hz:g} Hz)"
        )

    def fit(pb: Problem) -> Any:
        if earlier is not None and method == "oem" and earlier.sensitivities is not None:
            # the consider refits move the estimates by a fraction of their std: one
            # Gauss-Newton step with the earlier sensitivities is their first-order change
            # (ad hoc, a 600 s log with 44 lateral maneuvers: the consider stage 79 -> 15.5 s)
            try:
                return OutputError(pb.model, inputs=pb.inputs).step_from(earlier, pb.fit, estimate_x0=pb.estimate_x0)
            except ModelDefinitionError:
                pass  # other parameters or segments: refit
        # output error and filter error refit from all the free values, initial states,
        # per-segment values and filter error's F included (without them a 6-DoF lateral
        # held refit took 37 output-error iterations, now 4); the held ones stay the
        # problem's (the values a refit moves). The other START_FREE methods get the
        # model's values above.
        free = {p.name for p in pb.model.parameters if p.free}
        carry = (
            {
                n: v
                for n, v in start.items()
                if n.split("[")[0] in free or n.startswith("x0_") or (method == "fem" and n.startswith("F_"))
            }
            if refit and method in ("oem", "fem")
            else None
        )
        return fit_problem(
            pb,
            method,
            turbulence=turbulence,
            process_noise=process_noise,
            callback=None if refit else lambda it, cost, p: progress.tick(str(it + 1)),
            start=carry,
        )

    try:
        try:
            res = fit(pb)
            held = _inseparable_alphadot(pb, res) if alphadot and not refit else None
        except IdentifiabilityError as exc:
            held = _unidentifiable_alphadot(exc, alphadot) if not refit else None
            if held is None:
                raise
            res = None
        if held is not None:
            progress.done(
                ("not identifiable" if res is None else 'converged' if res.converged else 'NOT converged')
                + "; alphadot derivatives not separable: refit with them held"
            )
            pb = replace(pb, model=pb.model.hold({b: 0.0 for b in alphadot}), notes=[*pb.notes, held])
            progress.total += 1
            progress.stage(f"estimate {what} ({method.upper()}, {pb.model.name} model, CLalphadot, Cmalphadot held)")
            res = fit(pb)
            res.extra["alphadot_held"] = held
        elif held_alphadot and not [b for _, b in ALPHADOT_PAIRS if b in res.free_names]:
            res.extra["alphadot_held"] = held_alphadot
    except (EstimationError, np.linalg.LinAlgError) as exc:
        if refit:
            return None
        progress.done(f"FAILED: {exc}")
        print(f"note: {method.upper()} on the {what} failed: {exc}", file=progress.stream)
        progress.stage(f"validate {what} {method.upper()} (skipped)")
        progress.done()
        return None
    if refit:
        return res, None
    progress.done(f"{'converged' if res.converged else 'NOT converged'} in {_count(res.iterations, 'iteration')}")
    progress.stage(f"validate {what} {method.upper()} (fit, residuals, modes, proof of match)")
    v = validate(
        res,
        held_out=pb.held_out,
        truth=truth,
        tolerances=tolerances,
        proof_of_match=pom,
        calm_air=calm_air,
        step_times=pb.held_out_step_times(),
    )
    v["problem"] = {"notes": list(pb.notes)}
    progress.done()
    return res, v


def _held_refit(fd, ac: AircraftConstants, inputs: str, res, smooth_inputs: bool = True, hold_out: int = 1):
    """values -> the 6-DoF lateral output error refitted with those longitudinal values
    held, started from ``res`` (on the same maneuvers: ``hold_out`` as in the fit). The
    problem is built once, at the first call: the held values enter only its model's values
    (ad hoc, the 480 s log's 11 refits had rebuilt it in about 1 s each)."""
    from pipeline.uncertainty.consider import quiet_progress

    built: list[Problem] = []

    def refit(values: Mapping[str, float]):
        if not built:
            built.append(
                sixdof_lateral_problem(fd, ac, longitudinal=values, smooth_inputs=smooth_inputs, hold_out=hold_out)
            )
            built[0].inputs = inputs
        pb = built[0]
        held = {
            n: float(v) for n, v in values.items() if n in pb.model.parameter_names and not pb.model.parameter(n).free
        }
        done = fit_and_validate(
            replace(pb, model=pb.model.with_values(held)), "oem", "lateral axis", None, quiet_progress(), start=res
        )
        return None if done is None else done[0]

    return refit


#: prefix of the proof-of-match segments taken from a validation flight
VALIDATION_PREFIX = "validation flight: "


def hold_out_count(validation: Sequence[Any], fit_all: bool | None) -> int:
    """Maneuvers per axis held out of the fitted flight for the proof of match: none when
    there is a validation flight (``validation``: the list of them, see
    :func:`validation_flights`; or ``fit_all``: the refits of such a run), else one."""
    return 0 if (bool(validation) if fit_all is None else fit_all) else 1


def identified_axes(fd, axes: Sequence[str] = ("longitudinal", "lateral")) -> int:
    """How many of ``axes`` the log's maneuvers excite (elevator: longitudinal; aileron or
    rudder: lateral): the fits a run makes per method, for its progress count."""
    flown = {sg.axis for sg in fd.segments}
    return sum(
        1
        for name, surfaces in (("longitudinal", {"de"}), ("lateral", {"da", "dr"}))
        if name in axes and flown & surfaces
    )


def _method_problem(
    fd,
    ac: AircraftConstants,
    base: Problem,
    build,
    outs: Sequence[str],
    m: str,
    *,
    lon,
    multiaxis: bool,
    turbulent: bool = False,
    say: Callable[[str], None],
    cache: dict,
    inputs: str,
    smooth_inputs: bool,
    hold_out: int,
) -> Problem:
    """The problem method ``m`` is fitted on for the axis of ``base`` (built by ``build``
    on ``fd``; ``outs`` its outputs): ``base`` itself, or the same axis on the grid of its
    slowest output (COMMON_GRID methods; built once into ``cache``), or a richer model of
    the axis (below). ``lon``: the longitudinal output-error result, if any; ``multiaxis``:
    the flight moves all axes at once; ``turbulent``: the flight may be in turbulence (its
    level known and not off, or not known: a log); ``say`` reports a model that could not
    be set up;
    ``hold_out``: maneuvers per axis kept for the proof of match."""
    slowest = min(fd[c].rate_hz for c in outs) if m in COMMON_GRID else base.rate_hz
    rate = slowest if slowest < 0.9 * base.rate_hz else base.rate_hz

    def own() -> Problem:
        """The axis' own problem on the method's grid (the common grid built once)."""
        if rate == base.rate_hz:
            return base
        if "common" not in cache:
            cache["common"] = build(fd, ac, rate_hz=rate, smooth_inputs=smooth_inputs, hold_out=hold_out)
            cache["common"].inputs = inputs
        return cache["common"]

    pb = base
    if (
        (multiaxis or (turbulent and m in COMMON_GRID))
        and m != "ls"
        and (base.axis == "longitudinal" or m in COMMON_GRID)
    ):
        # all axes move at once: each axis' model driven by the other axis' measured
        # variables (the wings-level longitudinal model booked bank angle and yaw
        # rate on the derivatives), the filters with the Dryden gust states (the
        # rotary gusts in the damping terms; multiaxis_multisine_turbulence: FEM
        # Cmde 9.5 -> 0.6 std, Clp 49 -> 7 std from the truth).
        # Filter error's gust models measure an angle rebuilt from the flight path as
        # the rigid body's; its grid is that of the slowest other output, the rebuilt
        # angles at their own samples (FEM's per-pattern gains): on the rebuilt angles'
        # 10 Hz the 50-100 Hz channels lost their samples - ArduPilot flight.bin of
        # this scenario, seeds 31-34, worst |error|/std lateral 8.5-10.4 there, 2.9-4.7
        # on the 50 Hz of the other outputs; longitudinal 9.3-75, 7.8-14.5.
        # The filters take the gust models in turbulence also when one axis moves: the
        # aerodynamics see p - p_turb, q - q_turb whatever the maneuver
        # (multiaxis_multisine_turbulence flown with elevator multisines only, seed 34,
        # flight.mcap: FEM with the wings-level model Cmalpha, Cmde, Cm0 21-23 std off,
        # proof of match failed; with the gust model every derivative within 2.6 std;
        # with aileron-rudder multisines only: the linear lateral model Clp 46, Clda 38
        # std off, the gust model every derivative within 2.5 std). The axis' own problem
        # on the common grid is not built then (only where this one cannot be set up).
        try:
            pb = multiaxis_problem(
                fd,
                ac,
                base.axis,
                gust_states=m in COMMON_GRID,
                rate_hz=min((fd[c].rate_hz for c in outs if not rebuilt(fd, c)), default=rate) if m == "fem" else rate,
                smooth_inputs=smooth_inputs,
                hold_out=hold_out,
            )
        except FsidError as exc:
            pb = own()
            say(f"multi-axis {pb.axis} model not set up ({exc}); {pb.model.name} model used")
    elif m in COMMON_GRID:
        pb = own()
    elif pb.axis == "lateral" and m == "oem" and lon is not None:
        # output error on the lateral axis uses the nonlinear 6-DoF model with the
        # longitudinal estimates held: the linear lateral model's frozen airspeed and
        # small-angle kinematics bias the estimates by several std on a small UAV
        try:
            pb = sixdof_lateral_problem(
                fd,
                ac,
                longitudinal={n: float(v) for n, v in lon.params.items() if "[" not in n},
                smooth_inputs=smooth_inputs,
                hold_out=hold_out,
            )
        except FsidError as exc:
            say(f"6-DoF lateral model not set up ({exc}); linear model used")
    elif pb.axis == "lateral" and m in ("oem", "ls") and "q" in fd:
        # the lateral model driven by the measured V, alpha, theta, q. Output error
        # without longitudinal estimates to hold (aileron/rudder maneuvers only): the
        # linear model's frozen airspeed and small bank angles put Clda, Cnda, Cnp
        # 8-18 std off on lateral_doublets_calm; its V and alpha are the air data
        # blended with the integrated IMU above 0.1 Hz (kinematic), and it adds a
        # per-maneuver airspeed correction under an a-priori penalty for the pitot
        # noise left.
        # Equation error: the regression estimates do not depend on the dynamic
        # model, but validation simulates it: with the TRUE derivatives the linear
        # lateral model missed the held-out maneuver of scenarios/default.toml by
        # 2.05 deg/s on p and 2.01 on r (band 1.5), the driven one by 0.38, 0.33
        try:
            pb = lateral_problem(
                fd, ac, measured_longitudinal=True, kinematic=True, smooth_inputs=smooth_inputs, hold_out=hold_out
            )
            pb = with_airspeed_offsets(pb, fd) if m == "oem" else pb
        except FsidError as exc:
            say(f"lateral model with measured longitudinal inputs not set up ({exc}); linear model used")
    pb.inputs = inputs
    return pb


def validation_prefix(k: int, n: int) -> str:
    """Name prefix of the proof-of-match segments of validation flight k (0-based) of n:
    VALIDATION_PREFIX for a single flight, "validation flight <k+1>: " for several."""
    return VALIDATION_PREFIX if n == 1 else f"validation flight {k + 1}: "


def with_validation_flight(
    pb: Problem, vals: Sequence[Problem], calm: bool, numbers: Sequence[int] | None = None, n_flights: int | None = None
) -> Problem:
    """``pb`` with the maneuvers of ``vals`` (the same axis and model built on each
    validation flight, nothing held out there) as its held-out segments, named
    :func:`validation_prefix` + maneuver; ``numbers``: each problem's flight (0-based, of
    ``n_flights``; default: the order given); ``calm``: the flights are known to be in calm
    air (a simulated one)."""
    numbers = list(range(len(vals))) if numbers is None else list(numbers)
    total = len(vals) if n_flights is None else n_flights
    segs, specs, parts, times = [], [], [], []
    for k, val in zip(numbers, vals):
        pre = validation_prefix(k, total)
        mine = [replace(sg, name=pre + sg.name) for sg in val.fit + val.held_out]
        segs += mine
        times += [val.step_times] * len(mine)
        specs += list(val.specs) + list(val.held_specs)
        parts.append(("" if total == 1 else f"flight {k + 1}: ") + ", ".join(sg.name[len(pre) :] for sg in mine))
    where = "the validation flight's" if total == 1 else f"{total} validation flights'"
    note = (
        f"proof of match on {where} {_count(len(segs), 'maneuver')} "
        f"({'; '.join(parts)})" + ("; flown in calm air" if calm else "") + "; every maneuver of this flight fitted"
    )
    return replace(pb, held_out=segs, held_specs=specs, held_step_times=times, notes=list(pb.notes) + [note])


def validation_flights(validation: Any) -> list:
    """``identify``'s ``validation`` argument (or ``estimate_log``'s ``validation_log``) as
    a list: None -> none; one flight (a FlightData, a path) -> [it]; a list or tuple of
    them as it is."""
    if validation is None:
        return []
    return list(validation) if isinstance(validation, (list, tuple)) else [validation]


def identify(
    fd,
    ac: AircraftConstants,
    methods: Sequence[str],
    truth: Mapping[str, float] | None,
    progress: Progress,
    inputs: str = "linear",
    turbulence: Mapping[str, Any] | None = None,
    axes: Sequence[str] = ("longitudinal", "lateral"),
    tolerances: Mapping[str, float] | None = None,
    pom: str = "auto",
    starts: Mapping[str, Any] | None = None,
    smooth_inputs: bool = True,
    validation: Any = None,
    validation_calm: bool = False,
    fit_all: bool | None = None,
) -> tuple[dict, dict, list[Problem]]:
    """Estimate and validate every axis the log excites; ``inputs`` is how the inputs vary
    between samples (estimators.simulation.integrators.INPUT_MODES); ``tolerances``: proof-of-match
    bands per channel (SI; default those of DESIGN.md section 8); ``pom``: the proof-of-match
    mode (pipeline.validation.validate.POM_MODES: auto, simulation, air-data). Methods in COMMON_GRID get the
    axis problem on the grid of its slowest output channel (every output at every sample).
    Returns (results, validations, problems); keys are the method names
    ("<axis>-<method>" once several axes are fitted). ``starts`` (key -> parameter values):
    refit only, each fit starting there (see :func:`fit_and_validate`), no validation and
    no progress. ``smooth_inputs``: the measured surface positions low-passed where a flat
    noise floor begins (:mod:`pipeline.conditioning.input_smoothing`), else as logged.

    validation: a second flight (FlightData), or several, for the proof of match: each
    axis' model is fitted to every maneuver of ``fd`` and proved on every maneuver of each
    validation flight on that axis (built the same way; segments named by
    :func:`validation_prefix`), instead of on the last maneuver of ``fd``;
    ``validation_calm``: it is known to be flown in calm air (a simulated flight), so the
    automatic proof-of-match mode is the open-loop simulation whatever the method
    (:func:`pipeline.validation.validate.pom_mode`). ``fit_all`` (default: with a validation flight):
    hold nothing out of ``fd`` - refits of a run with a validation flight pass it."""
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise FsidError(f"unknown method(s) {bad}: use some of {', '.join(METHODS)}")
    vflights = validation_flights(validation)
    hold = hold_out_count(vflights, fit_all)
    results, validations, problems = {}, {}, []
    flown = {s.axis for s in fd.segments}
    builders = [
        ("longitudinal" in axes and "de" in flown, longitudinal_problem, LONG_OUTPUTS),
        ("lateral" in axes and bool({"da", "dr"} & flown), lateral_problem, LAT_OUTPUTS),
    ]
    skipped = []
    plans = []  # (axis problem at the default grid, builder, outputs, on validation)

    def note(msg: str) -> None:
        print(f"note: {msg}", file=progress.stream)

    def val_note(k: int):
        """The note function of validation flight k."""
        return lambda msg: note(f"{validation_prefix(k, len(vflights))}{msg}")

    for wanted, build, outs in builders:
        if not wanted:
            continue
        try:
            problem = build(fd, ac, smooth_inputs=smooth_inputs, hold_out=hold)
        except FsidError as exc:  # e.g. one maneuver only: say so, fit the other axis
            skipped.append(str(exc))
            continue
        vbases = []  # (flight number, its problem of this axis)
        for k, vfd in enumerate(vflights):
            try:
                vb = build(vfd, ac, smooth_inputs=smooth_inputs, hold_out=0)
                vb.inputs = inputs
                vbases.append((k, vb))
            except FsidError as exc:
                val_note(k)(f"the {problem.axis} axis cannot be set up there ({exc}); it proves nothing on that axis")
        problem.inputs = inputs
        problems.append(problem)
        plans.append((problem, build, outs, vbases))
    if not problems:
        raise FsidError(
            "no axis can be identified from this log: "
            + (
                "; ".join(skipped)
                or "no control-input activity found (fly doublets/3-2-1-1s on the elevator, aileron or rudder, or give segments)"
            )
        )
    for msg in skipped:
        note(msg)
    multiaxis = multi_axis(fd)
    turbulent = turbulence is None or turbulence.get("model", "off") != "off"
    filter_q: dict[str, Any] = {}  # axis -> the filter-error fit the EKF/UKF take their noise from
    for problem, build, outs, vbases in plans:
        cache: dict = {}
        vcaches: dict[int, dict] = {k: {} for k, _ in vbases}
        for m in methods:
            lon = results.get("longitudinal-oem")
            pb = _method_problem(
                fd,
                ac,
                problem,
                build,
                outs,
                m,
                lon=lon,
                multiaxis=multiaxis,
                turbulent=turbulent,
                say=note,
                cache=cache,
                inputs=inputs,
                smooth_inputs=smooth_inputs,
                hold_out=hold,
            )
            pb.step_times = step_times(fd.meta)  # the flight's: the cached problem's too
            if vflights and starts is None:
                vpbs, numbers = [], []
                for k, vbase in vbases:
                    vpb = _method_problem(
                        vflights[k],
                        ac,
                        vbase,
                        build,
                        outs,
                        m,
                        lon=lon,
                        multiaxis=multiaxis,
                        turbulent=turbulent,
                        say=val_note(k),
                        cache=vcaches[k],
                        inputs=inputs,
                        smooth_inputs=smooth_inputs,
                        hold_out=0,
                    )
                    if vpb.model.name == pb.model.name:
                        vpb.step_times = step_times(vflights[k].meta)
                        vpbs.append(vpb)
                        numbers.append(k)
                    else:
                        val_note(k)(
                            f"{pb.model.name} model not set up there; it proves nothing for {m.upper()} on the {pb.axis} axis"
                        )
                pb = (
                    with_validation_flight(pb, vpbs, validation_calm, numbers, len(vflights))
                    if vpbs
                    else replace(pb, held_out=[], held_specs=[])
                )
            key = m if len(problems) == 1 else f"{pb.axis}-{m}"
            if m == "fem":  # its R; EKF/UKF keep the grid's (fit_problem)
                attach_logged_noise(fd, pb)
            q, pb, noise = filters_process_noise(
                fd,
                pb,
                m,
                results.get(key[:-3] + "fem"),
                filter_q,
                progress,
                turbulence=turbulence,
                quiet=starts is not None,
                earlier=None if starts is None else starts.get(key),
            )
            fem = results.get(key[:-3] + "fem") if m in ("ekf", "ukf") else None
            done = fit_and_validate(
                pb,
                m,
                f"{pb.axis} axis",
                truth,
                progress,
                turbulence=turbulence,
                tolerances=tolerances,
                pom=pom,
                start=None if starts is None else starts.get(key, {}),
                process_noise=q,
                calm_air=validation_calm and bool(vbases),
                held_alphadot=fem.extra.get("alphadot_held") if fem else None,
            )
            if done is not None:
                results[key], validations[key] = done
                if noise is not None:
                    results[key].extra["filters_noise"] = noise
                if starts is None and pb.model.name.startswith("sixdof") and lon is not None:
                    # the longitudinal estimates this fit holds: their uncertainty is
                    # carried to it after the fits (carry_consider_uncertainty)
                    results[key].extra["held"] = lon
                    results[key].extra["held_refit"] = _held_refit(fd, ac, inputs, results[key], smooth_inputs, hold)
    if not results:
        raise FsidError("every estimation method failed on this log (see the notes above)")
    return results, validations, problems


#: parameters of the gust models' noise, not of the aerodynamics: the Kalman filters hold
#: them at filter error's estimates when they take its process noise (no turbulence level
#: known: a real log). fsid estimate --method fem --method ukf on
#: multiaxis_multisine_turbulence's flight.mcap, seed 31: with the roll gust's time
#: constant free the UKF ended at tau_pg 0.38 s (FEM 0.46) and Clp 3.0 std off the truth;
#: held, every lateral derivative within 2.4 std and the proof of match passes (seeds
#: 32-34: the UKF's own tau_pg was within 0.02 s of FEM's, the estimates move < 0.1 std)
GUST_NOISE_PARAMETERS = ("tau_pg",)


def filters_process_noise(
    fd,
    pb: Problem,
    method: str,
    fem: Any,
    cache: dict,
    progress: Progress,
    *,
    turbulence: Mapping[str, Any] | None = None,
    quiet: bool = False,
    earlier: Any = None,
) -> tuple[dict[str, float] | None, Problem, Any]:
    """The process noise of an EKF/UKF fit and its problem: (None, ``pb``) for other
    methods and when the Dryden level is known (fit_problem takes it from there); else
    from this run's FEM of the problem (``fem``), or a filter-error fit made for it, once
    per axis (``cache``: axis -> that fit or None), with ``pb``'s free
    GUST_NOISE_PARAMETERS held at that fit's estimates; (None, ``pb``), the filters'
    default, when that fit fails. The third element, (process noise, held values) or None,
    goes to the result's ``extra["filters_noise"]``: a refit of that result (``earlier``,
    :mod:`pipeline.uncertainty.consider`) takes the same noise model instead of another
    filter-error fit (ad hoc, fsid estimate --method ekf of a 600 s log: 50 of the
    consider stage's 66 s)."""
    if method not in ("ekf", "ukf") or dryden_known(turbulence):
        return None, pb, None
    noise = (getattr(earlier, "extra", None) or {}).get("filters_noise")
    if noise is None:
        if pb.axis not in cache:
            cache[pb.axis] = _fem_for_filters(fd, pb, fem, progress, quiet)
        src = cache[pb.axis]
        if src is None:
            return None, pb, None
        free = {p.name for p in pb.model.parameters if p.free}
        noise = (
            filter_process_noise(src),
            {n: float(src.params[n]) for n in GUST_NOISE_PARAMETERS if n in free and n in src.params},
        )
    q, held = noise
    if held:
        pb = replace(
            pb,
            model=pb.model.hold(held),
            notes=list(pb.notes)
            + [
                ", ".join(f"{n} = {v:.4g}" for n, v in held.items())
                + " held at filter error's estimate (the gust model's noise, with its process noise)"
            ],
        )
    return q, pb, noise


def _fem_for_filters(fd, pb: Problem, fem: Any, progress: Progress, quiet: bool = False) -> Any:
    """The filter-error fit the filters take their noise model from: ``fem``, else one made
    for ``pb`` (None when it fails)."""
    from estimators import EstimationError

    if fem is None:
        try:
            fem = fit_problem(attach_logged_noise(fd, replace(pb)), "fem")
        except (EstimationError, np.linalg.LinAlgError) as exc:
            if not quiet:
                print(
                    f"note: process noise for the {pb.axis} filters: the filter-error fit "
                    f"failed ({exc}); the data's default used",
                    file=progress.stream,
                )
            return None
        if not quiet:
            print(
                f"note: process noise for the {pb.axis} filters from a filter-error fit (no turbulence level known)",
                file=progress.stream,
            )
    return fem


def carry_consider_uncertainty(
    fd_raw,
    comp: dict[str, Any],
    results: dict,
    validations: dict,
    truth: Mapping[str, float] | None,
    progress: Progress,
    refit,
    *,
    flow: dict[str, Any] | None = None,
    wind_refit=None,
    dynamics: dict[str, Any] | None = None,
    dynamics_refit=None,
    steps: Sequence[Any] = (),
    inputs_data: Any = None,
    inputs_refit=None,
) -> dict[str, Any]:
    """One stage after the fits: what each fit held as exact gets its uncertainty into the
    result's ``consider_cov`` (:mod:`pipeline.uncertainty.consider`) - the other axis'
    estimates a fit held (``result.extra["held"]``, the 6-DoF lateral output error holding
    the longitudinal derivatives; the doc goes to the validation's ``held_estimates``),
    the sensor corrections applied before estimation (``comp["propagation"]``; ``refit(fd,
    starts)`` repeats the fits, results only) and, for air-data angles rebuilt from the
    flight path (``flow``, their document; ``flow["wind_uncertainty"]``), the wind they
    were rebuilt with (``wind_refit(offset)`` repeats the fits with the wind moved), and
    the control-input delays and lags applied before the fits (``dynamics``, the document
    of :func:`input_dynamics_stage`, gets ``uncertainty``; ``dynamics_refit(dynamics)``
    repeats the fits with other ones), and the times of the control-input steps logged more
    slowly than the fits' grid (``steps``: :func:`pipeline.conditioning.input_sampling.time_steps`'
    list; ``inputs_data``: the data before the input dynamics; ``inputs_refit(data)``
    repeats the fits on it; :func:`pipeline.uncertainty.consider.input_sampling`). Then
    the truth checks and verdicts are redone with the total std. Returns the step-timing
    part's document (empty when no input is slow)."""
    from pipeline.uncertainty.consider import (
        fitted_steps,
        held_estimates,
        input_dynamics,
        input_sampling,
        propagate,
        wind,
    )
    from pipeline.validation.validate import refresh_prediction_uncertainty, refresh_truth_check

    held = [k for k, r in results.items() if (r.extra or {}).get("held") is not None]
    rebuilt = (flow or {}).get("status") == "reconstructed" and wind_refit is not None
    parts = [f"{k}: held estimates" for k in held]
    parts += [f"{len(comp['applied'])} sensor corrections"] if comp.get("applied") else []
    parts += ["the wind of the rebuilt air-data angles"] if rebuilt else []
    delayed = bool(
        (dynamics or {}).get("status") == "estimated" and dynamics.get("applied") and dynamics_refit is not None
    )
    parts += [f"the delay and lag of {len(dynamics['applied'])} control inputs"] if delayed else []
    slow = inputs_refit is not None and inputs_data is not None and bool(fitted_steps(list(steps), results))
    parts += ["the times of the control-input steps between slow samples"] if slow else []
    progress.stage("uncertainty of what the fits held as exact" + (f" ({', '.join(parts)})" if parts else ""))
    for k in held:
        r = results[k]
        doc = held_estimates(r, r.extra["held_refit"], progress)
        r.extra.pop("held_refit", None)
        if k in validations:
            validations[k]["held_estimates"] = doc
    if comp.get("applied"):
        comp["propagation"] = propagate(fd_raw, comp, results, refit, progress)
    if rebuilt:
        flow["wind_uncertainty"] = wind(flow, results, wind_refit, progress)
    if delayed:
        dynamics["uncertainty"] = input_dynamics(dynamics, results, dynamics_refit, progress)
    sampling = input_sampling(inputs_data, results, inputs_refit, list(steps), progress) if slow else {}
    for key, res in results.items():
        if key in validations:
            refresh_prediction_uncertainty(validations[key], res)
            refresh_truth_check(validations[key], res, truth)
    progress.done(
        "nothing held"
        if not parts
        else f"{sum(r.consider_cov is not None for r in results.values())} of {len(results)} fits with a consider part"
    )
    return sampling


def sampling_meta(timing: Mapping[str, Any], carried: Mapping[str, Any]) -> dict[str, Any]:
    """report.json/report.md meta entries of control inputs logged more slowly than the
    gyros: their steps timed from the rates (``timing``, :func:`pipeline.conditioning.input_sampling.
    time_steps`' document) and those times' uncertainty carried to the estimates
    (``carried``, :func:`pipeline.uncertainty.consider.input_sampling`'s); none when no
    input was slow."""
    if not timing:
        return {}
    line = step_summary(timing)
    if carried:
        chans = ", ".join(
            f"{c} {v['steps']} ({v['timed']} timed, rms std {1e3 * v['time_std_s']:.1f} ms)"
            for c, v in carried["channels"].items()
        )
        line += (
            f"; the fitted windows' steps ({chans}) carried to the estimates' total std ({carried['refits']} refits)"
        )
    return {"control-input sampling": line, "input_sampling": {**timing, "uncertainty": dict(carried)}}


def flow_angle_stage(
    fd, ac: AircraftConstants | None, pr: Progress, *, airspeed_scale: float | None = None
) -> tuple[Any, Any, Any, dict]:
    """The air-data-angle stage of ``fsid estimate``: alpha/beta the log lacks (no vane), or
    holds only as an autopilot's estimate (``Channel.derived``: ArduPilot's AOA/SSA, from
    its EKF velocity and wind), rebuilt from the flight path and a fitted wind
    (:mod:`pipeline.conditioning.flow_angles`), whose document names the assumptions and the wind. Returns
    (flight data for estimation, aircraft constants, the logged data without derived
    angles - what the sensor-compatibility stage may use, also when they are kept for
    estimation -, document). Rebuilt angles are
    the CG's (the navigation filter's velocity is the body origin's), so the constants'
    air-data position becomes (0, 0, 0). ``airspeed_scale``: the pitot's scale factor held
    (a validation flight takes the fitted flight's), else estimated with the wind where the
    headings allow (:func:`pipeline.conditioning.flow_angles.airspeed_calibration`). A log that cannot give
    them (no inertial velocity, no forward flight) goes on as it is: the document says why,
    and a model that needs the angles stops later with the missing channels named."""
    from pipeline.conditioning.flow_angles import reconstruct_flow_angles, summary
    from pipeline.ingest.flightdata import FlightData

    pr.stage("air-data angles")
    derived = {k: f"{fd[k].source}: {fd[k].derived}" for k in ("alpha", "beta") if k in fd and fd[k].derived}
    base = (
        fd
        if not derived
        else FlightData(
            channels={k: c for k, c in fd.channels.items() if k not in derived},
            meta=dict(fd.meta),
            segments=list(fd.segments),
        )
    )
    try:
        out, doc = reconstruct_flow_angles(base, airspeed_scale=airspeed_scale)
    except FsidError as exc:
        kept = f"; the logged estimates kept ({', '.join(derived.values())})" if derived else ""
        pr.done(f"not rebuilt: {exc}{kept}")
        return fd, ac, base, {"status": "not possible", "reason": str(exc) + kept}
    if doc["status"] != "reconstructed":
        pr.done("logged (vanes)")
        return fd, ac, fd, doc
    if derived:
        doc["replaced"] = derived
    if ac is not None and "alpha" in doc["channels"]:
        ac = replace(ac, airdata=(0.0, 0.0, 0.0))
        doc["airdata_position_m"] = [0.0, 0.0, 0.0]
    pr.done(summary(doc) + (f" (instead of {', '.join(derived)}: autopilot estimates)" if derived else ""))
    return out, ac, base, doc


def with_flow_angles(fd, flow: Mapping[str, Any], wind_offset: Sequence[float] = (0.0, 0.0, 0.0)) -> tuple[Any, dict]:
    """(``fd`` with the air-data angles rebuilt as :func:`flow_angle_stage` rebuilt them,
    ``wind_offset`` (north, east, down [m/s], pitot scale factor [-], the last optional)
    added to their wind and scale factor, their document); ``fd`` and ``flow`` unchanged
    when that stage rebuilt nothing."""
    if flow.get("status") != "reconstructed":
        return fd, dict(flow)
    from pipeline.conditioning.flow_angles import reconstruct_flow_angles

    cal = flow.get("airspeed_scale") or {}
    return reconstruct_flow_angles(
        fd, wind_offset=wind_offset, airspeed_scale=cal["estimate"] if cal.get("status") == "held" else None
    )


def compatibility_stage(
    fd,
    ac: AircraftConstants | None,
    pr: Progress,
    *,
    enabled: bool = True,
    truth: Mapping[str, float] | None = None,
    imu_only: bool = False,
    unsteady: str | None = None,
    wind: tuple[float, float] | None = None,
    airspeed: Any = None,
    positions: tuple[Sequence[float], Sequence[float]] | None = None,
) -> tuple[Any, dict]:
    """The sensor-compatibility stage of a run (flight path reconstruction,
    :func:`pipeline.conditioning.compatibility.correct_for_estimation`): returns (flight data for
    estimation, JSON-ready document). Sensor errors distinguishable from zero (|estimate|
    >= 3 std) are removed from the data estimation sees; the others are reported and not
    applied. Sensor positions from ``ac`` (0,0,0 without one). Never ends the run: a log
    the reconstruction cannot use (no forward flight, missing channels) or a failed fit is
    reported as skipped / failed and estimation gets the data as logged. ``enabled=False``
    (``--no-compat``): skipped. ``imu_only``: estimate the IMU errors alone (a log without
    vanes: the airspeed is then the only air data, and with a free wind its bias, scale
    factor and delay are nearly one parameter - bias_V 21 m/s, delay 0.7 s "significant"
    on a windy longitudinal_3211_turbulence). ``unsteady`` and ``wind`` (the air-data-angle
    stage's, which its zero-sideslip condition fixes across the track) go to
    :func:`~pipeline.conditioning.compatibility.correct_for_estimation`. ``airspeed``: the V channel
    that wind was fitted with (calibrated by the pitot's scale factor,
    :func:`pipeline.conditioning.flow_angles.airspeed_calibration`), which the reconstruction then
    takes in place of the logged one (with the logged one and the held wind, the airspeed
    error would be booked on the IMU); the data returned keep the logged V, which the
    air-data-angle stage calibrates again. ``positions`` (IMU, boom) [m] instead of
    ``ac``'s."""
    pr.stage("sensor compatibility (flight path reconstruction)")
    if not enabled:
        doc = {
            "status": "skipped",
            "reason": "switched off (--no-compat)",
            "applied": {},
            "data_for_estimation": "as logged",
        }
        pr.done("skipped (--no-compat)")
        return fd, doc
    from pipeline.conditioning.compatibility import correct_for_estimation

    imu, boom = positions or (
        (tuple(ac.imu), tuple(ac.airdata)) if ac is not None else ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    )
    try:
        from pipeline.conditioning.compatibility import IMU_PARAMS, RUN_ESTIMATE

        seen = fd if airspeed is None else replace(fd, channels={**fd.channels, "V": airspeed})
        doc, out = correct_for_estimation(
            seen,
            imu_position=imu,
            boom_position=boom,
            truth=truth,
            estimate=IMU_PARAMS if imu_only else RUN_ESTIMATE,
            wind=wind,
            unsteady=unsteady,
        )
        if airspeed is not None:
            out = replace(out, channels={**out.channels, "V": fd["V"]})
            doc["airspeed"] = "calibrated by the air-data-angle stage's pitot scale factor"
        if imu_only:
            doc["scope"] = "IMU errors only: no air-data vanes in the log"
    except Exception as exc:  # noqa: BLE001 - the compatibility check must not cost the run
        doc, out = (
            {
                "status": "failed",
                "reason": f"{type(exc).__name__}: {exc}",
                "applied": {},
                "data_for_estimation": "as logged",
            },
            fd,
        )
    doc["positions"] = {"imu_m": list(map(float, imu)), "boom_m": list(map(float, boom))}
    st = doc.get("status")
    if st in ("skipped", "failed"):
        pr.done(f"{st}: {doc.get('reason', '')}")
    elif doc["applied"]:
        pr.done(
            f"{len(doc['applied'])} of {len(doc.get('parameters', {}))} sensor errors significant, "
            "removed from the data for estimation"
        )
    else:
        pr.done(f"{st}: {doc.get('note', 'no correction applied')}")
    return out, doc


def compatibility_after_flow_angles(
    logged, rebuilt, flow: Mapping[str, Any], ac: AircraftConstants | None, pr: Progress, **kw
) -> tuple[Any, dict]:
    """:func:`compatibility_stage` as ``fsid estimate`` and ``fsid check`` run it after the
    air-data-angle stage (:func:`flow_angle_stage`: ``logged`` its logged data without
    derived angles, ``rebuilt`` its data, ``flow`` its document): the IMU errors only when
    the log has no vane, with that stage's wind held, its verdict on the steadiness of the
    air, and the airspeed it calibrated. ``kw`` go to :func:`compatibility_stage`."""
    from pipeline.conditioning.flow_angles import calibrated, mean_wind, unsteady

    imu_only = not any(k in logged for k in ("alpha", "beta"))
    return compatibility_stage(
        logged,
        ac,
        pr,
        imu_only=imu_only,
        unsteady=unsteady(flow),
        wind=mean_wind(flow),
        airspeed=rebuilt["V"] if imu_only and calibrated(flow) else None,
        **kw,
    )


def input_dynamics_stage(fd, pr: Progress, setting: str | tuple[float, float] = "auto") -> tuple[Any, dict]:
    """The control-input dynamics stage (:mod:`pipeline.conditioning.input_dynamics`): returns (flight
    data with the dynamics applied, JSON-ready document). ``setting``: "auto" estimates each
    surface's delay and lag and applies the significant ones; "off" skips the stage;
    (delay, lag) [s] applies those to every control input without estimating. Never ends
    the run: a failed estimate is reported and the inputs stay as logged."""
    from pipeline.conditioning.input_dynamics import estimate_input_dynamics, summary, with_input_dynamics
    from pipeline.ingest.flightdata import CONTROL_INPUTS

    pr.stage("control-input delay and lag (equation error)")
    if setting == "off":
        pr.done("skipped (--input-dynamics off)")
        return fd, {"status": "skipped", "reason": "switched off (--input-dynamics off)", "applied": {}}
    if setting != "auto":
        d, tau = (float(x) for x in setting)
        doc = {"status": "given", "applied": {s: {"delay_s": d, "lag_s": tau} for s in CONTROL_INPUTS if s in fd}}
        pr.done(summary(doc))
        return with_input_dynamics(fd, doc["applied"]), doc
    try:
        doc = estimate_input_dynamics(fd)
    except Exception as exc:  # noqa: BLE001 - the estimate must not cost the run
        pr.done(f"failed: {type(exc).__name__}: {exc}; inputs as logged")
        return fd, {"status": "failed", "reason": f"{type(exc).__name__}: {exc}", "applied": {}}
    doc["status"] = "estimated"
    pr.done(summary(doc))
    return with_input_dynamics(fd, doc["applied"]), doc


def refine_input_dynamics_stage(
    fd_before, fd, doc: dict[str, Any], methods: Sequence[str], pr: Progress, fit
) -> tuple[Any, dict]:
    """The control-input dynamics stage's delays and lags refined by output error
    (:func:`pipeline.conditioning.input_dynamics.refine_by_output_error`; ``fit(dynamics, starts)`` its
    output-error fits) when that stage estimated and applied some and output error is
    among ``methods``. Returns (the data ``fd_before`` that stage had, with the refined
    dynamics applied - ``fd``, the stage's, when nothing was refined -, ``doc``). Never
    ends the run: a refinement that fails keeps the equation-error values, and says why -
    unless the output-error fits want the inputs as logged
    (:func:`pipeline.conditioning.input_dynamics.logged_inputs_fit_better`): then none is applied (each
    surface's ``withdrawn`` says why)."""
    from pipeline.conditioning.input_dynamics import (
        logged_inputs_fit_better,
        refine_by_output_error,
        with_input_dynamics,
    )

    if doc.get("status") != "estimated" or not doc.get("applied"):
        return fd, doc
    if "oem" not in methods:
        doc["refined"] = {"status": "not refined", "reason": "output error is not among the methods"}
        return fd, doc
    pr.substage(f"refined by output error ({', '.join(doc['applied'])})")
    ref = refine_by_output_error(doc, fit, pr)
    # a correction the fits do not want is not made: on a 25 Hz log throughout, its sideslip
    # rebuilt at 5 Hz, equation error put 47 ms of delay and 86 of lag on the rudder
    # (truth none), and the lateral output error did not converge with them; without them
    # it did, within 1.9 std (tests/test_input_sampling.py)
    why = logged_inputs_fit_better(doc["applied"], fit) if ref["status"] != "refined" else None
    if why:
        for srf in doc["applied"]:
            doc["surfaces"][srf]["applied"] = False
            doc["surfaces"][srf]["withdrawn"] = f"not refined ({ref['reason']}); {why}"
        doc["applied"] = {}
        ref["reason"] += f"; {why}: none applied"
        pr.done(f"not refined: {ref['reason']}")
        return fd_before, doc
    if ref["status"] != "refined":
        pr.done(f"not refined: {ref['reason']}; equation error's values kept")
        return fd, doc
    pr.done(
        ", ".join(
            f"{s} delay {v['delay_s'] * 1e3:+.1f}, lag {v['lag_s'] * 1e3:.1f} ms" for s, v in doc["applied"].items()
        )
        + f" ({ref['iterations']} iterations, {ref['fits']} fits)"
    )
    return with_input_dynamics(fd_before, doc["applied"]), doc


def with_instrument_errors_removed(fd_val, comp: Mapping[str, Any], meta: dict | None = None):
    """The validation flight with the instrument errors the compatibility stage removed
    from the fitted flight (scale factors, air-data delay:
    :func:`pipeline.conditioning.compatibility.instrument_errors`) removed too, so that the model is
    proved on data in the same corrected space it was fitted on; the names go to
    ``meta["validation flight corrections"]``."""
    from pipeline.conditioning.compatibility import instrument_errors, remove_sensor_errors

    errs = instrument_errors(comp.get("applied") or {})
    if not errs:
        return fd_val
    if meta is not None:
        meta["validation flight corrections"] = {n: float(v) for n, v in errs.items()}
    return remove_sensor_errors(fd_val, errs, keep_times=True)


def run_scenario(
    scenario_path: str | Path,
    out: Path,
    *,
    seed: int | None = None,
    methods: Sequence[str] | None = None,
    quiet: bool = False,
    compat: bool = True,
    bands: Mapping[str, float] | None = None,
    pom: str = "auto",
    smooth_inputs: bool = True,
    input_dynamics: str | tuple[float, float] = "auto",
) -> dict[str, Path]:
    """``fsid run``: everything of DESIGN.md section 5 into ``out``. ``methods`` default:
    the ones that suit the flight (:func:`scenario_methods`). ``compat``: run the
    sensor-compatibility stage on the ingested MCAP and estimate from its corrected data
    (:func:`compatibility_stage`; its document goes to checks.json under
    ``flight.mcap.compatibility`` and to the report). ``bands``: proof-of-match bands
    (``rate_deg_s``, ``accel_g``, ``angle_deg``) over the scenario's ``[validation]``;
    ``pom``: proof-of-match mode (auto, simulation, air-data); ``smooth_inputs``: see
    :func:`identify`; ``input_dynamics``: see :func:`input_dynamics_stage` (the MCAP's
    surface positions are the surfaces', so it finds none unless the scenario's surfaces
    sensor has a delay)."""
    import sim
    from pipeline.conditioning.checks import findings_to_json, run_checks, summarize
    from pipeline.ingest.readers import read_log
    from pipeline.outputs.writers import write_dataflash, write_mcap, write_truth_json

    pr = Progress(7 + 4 * len(methods or ("oem", "ls")) + 1, quiet=quiet)  # updated below
    pr.stage(f"load scenario {scenario_path}")
    try:
        scenario = sim.load_scenario(scenario_path)
    except sim.ScenarioError as exc:
        raise FsidError(str(exc)) from None
    if seed is not None:
        scenario = scenario.with_seed(seed)
    val = scenario.validation
    calm = val is not None and val.turbulence.model == "off"
    pr.done(scenario.name)
    pr.stage(f"fly {scenario.duration:.0f} s in JSBSim")
    result = sim.fly(scenario, workdir=out / ".jsbsim")
    pr.done(f"{len(result.maneuvers)} maneuvers")
    pr.stage("write flight.bin, flight.mcap, truth.json")
    write_dataflash(out / "flight.bin", result, airspeed="eas")  # ArduPilot semantics
    write_mcap(out / "flight.mcap", result)
    write_truth_json(out / "truth.json", result)
    truth_doc = json.loads((out / "truth.json").read_text())
    pr.done()
    fd_val = None
    if val is not None:  # the proof-of-match flight: its own log, read back
        pr.stage(
            f"fly the validation flight ({val.duration:.0f} s{', calm air' if calm else ''}) and write validation.mcap"
        )
        vres = sim.fly(val, workdir=out / ".jsbsim")
        write_mcap(out / "validation.mcap", vres)
        fd_val = read_log(out / "validation.mcap")
        pr.done(f"{len(vres.maneuvers)} maneuvers")
    pr.stage("ingest flight.bin and flight.mcap")
    fd_bin = read_log(out / "flight.bin")
    fd_mcap, steps, steps_doc = time_steps(read_log(out / "flight.mcap"), MAX_RATE_HZ)
    if fd_val is not None:
        fd_val = time_steps(fd_val, MAX_RATE_HZ)[0]
    pr.done(
        f"{len(fd_bin.channels)} channels, {len(fd_bin.segments)} maneuver segments"
        + (f"; {step_summary(steps_doc)}" if steps_doc else "")
    )
    pr.stage("data-quality checks")
    logs = {"flight.bin": fd_bin, "flight.mcap": fd_mcap, **({"validation.mcap": fd_val} if fd_val is not None else {})}
    findings = {name: run_checks(fd) for name, fd in logs.items()}
    checks = {name: json.loads(findings_to_json(f, logs[name])) for name, f in findings.items()}
    summary = {name: summarize(f) for name, f in findings.items()}
    pr.done(", ".join(f"{k}: {v}" for k, v in summary.items()))
    ac = AircraftConstants.from_truth(truth_doc)
    from pipeline.conditioning.compatibility import truth_errors

    fd_logged = fd_mcap
    fd_c, comp = compatibility_stage(fd_mcap, ac, pr, enabled=compat, truth=truth_errors(truth_doc))
    checks["flight.mcap"]["compatibility"] = comp
    atomic_write_text(out / "checks.json", json.dumps(checks, indent=2, default=str) + "\n")
    from pipeline.conditioning.input_dynamics import summary as dynamics_summary
    from pipeline.conditioning.input_dynamics import with_input_dynamics

    fd_mcap, dyn_doc = input_dynamics_stage(fd_c, pr, input_dynamics)
    truth = {k: float(v) for k, v in truth_doc["derivatives"].items()}
    # estimation reads the product's own MCAP (surface positions at full resolution; the
    # .bin's RCOU carries whole-microsecond PWM, ~0.075 deg steps); the simulator moves
    # inputs linearly between samples, hence linear input interpolation
    if not methods:
        methods = scenario_methods(truth_doc)
    from pipeline.uncertainty.consider import quiet_progress

    def refit(fd, starts, dynamics=None, only=None):
        """The run's fits (of ``only`` methods, default all) repeated on corrected data
        ``fd`` with the input dynamics (default: the applied ones), started from
        ``starts``."""
        return identify(
            with_input_dynamics(fd, dyn_doc["applied"] if dynamics is None else dynamics),
            ac,
            only or methods,
            truth,
            quiet_progress(),
            inputs="linear",
            turbulence=truth_doc.get("turbulence"),
            starts=starts,
            smooth_inputs=smooth_inputs,
            fit_all=fd_val is not None,
        )[0]

    fd_mcap, dyn_doc = refine_input_dynamics_stage(
        fd_c,
        fd_mcap,
        dyn_doc,
        methods,
        pr,
        lambda dyn, starts: refit(fd_c, {} if starts is None else starts, dyn, only=("oem",)),
    )
    applied = dict(dyn_doc["applied"])
    val_meta: dict = {}
    if fd_val is not None:
        fd_val = with_input_dynamics(with_instrument_errors_removed(fd_val, comp, val_meta), applied)
    pr.total = pr.n + 2 * max(identified_axes(fd_mcap), 1) * len(methods) + 2  # + correction uncertainty, outputs
    from estimators.validation import default_tolerances

    results, validations, problems = identify(
        fd_mcap,
        ac,
        methods,
        truth,
        pr,
        inputs="linear",
        turbulence=truth_doc.get("turbulence"),
        tolerances=default_tolerances(**{**scenario.pom_bands, **(bands or {})}),
        pom=pom,
        smooth_inputs=smooth_inputs,
        validation=fd_val,
        validation_calm=calm,
    )
    starts = dict(results)
    sampling = carry_consider_uncertainty(
        fd_logged,
        comp,
        results,
        validations,
        truth,
        pr,
        refit,
        dynamics=dyn_doc,
        dynamics_refit=lambda d: refit(fd_c, starts, d),
        steps=steps,
        inputs_data=fd_c,
        inputs_refit=lambda data: refit(data, starts),
    )
    meta = {
        "scenario": scenario.name,
        "log": "flight.mcap",
        "seed": result.meta["seed"],
        "aircraft": result.aircraft.name,
        "data": f"flight.mcap, {comp['data_for_estimation']}",
        "control-input delay and lag": dynamics_summary(dyn_doc),
        "input_dynamics": dyn_doc,
        **sampling_meta(steps_doc, sampling),
    }
    if val is not None:
        meta["validation flight"] = (
            f"validation.mcap (seed {vres.meta['seed']}, "
            f"{'calm air' if calm else 'turbulence as the flight'}): "
            "the proof of match; every maneuver of flight.mcap fitted"
        )
        meta.update(val_meta)
    return _write_outputs(out, results, validations, problems, truth, pr, checks=summary, meta=meta, compatibility=comp)


def estimate_log(
    log: str | Path,
    out: Path,
    *,
    aircraft: str | Path | None = None,
    map_path: str | None = None,
    methods: Sequence[str] = ("oem",),
    inputs: str = "linear",
    model: str = "auto",
    quiet: bool = False,
    compat: bool = True,
    bands: Mapping[str, float] | None = None,
    pom: str = "auto",
    smooth_inputs: bool = True,
    validation_log: str | Path | Sequence[str | Path] | None = None,
    time_base: str | None = None,
    input_dynamics: str | tuple[float, float] = "auto",
) -> dict[str, Path]:
    """``fsid estimate``: a log -> report and recording. ``model``: a built-in model
    (auto|longitudinal|lateral; needs ``aircraft``, or a truth.json next to the log) or a
    user model ``path.py:name`` (:mod:`pipeline.problems.user_model`). Aircraft and sensor positions:
    :mod:`pipeline.ingest.aircraft`. No turbulence level is known: the EKF/UKF process noise
    is the filter-error method's estimate (:func:`filters_process_noise`). ``bands``
    (``rate_deg_s``, ``accel_g``, ``angle_deg``) and ``pom`` set the proof of match
    (defaults 1.5 deg/s, 0.1 g, 1.5 deg; auto mode); ``smooth_inputs``: see :func:`identify`.
    ``validation_log``: a second flight, or a sequence of them, for the proof of match
    (each read with the same map and servo travel, its air-data angles rebuilt the same
    way; of the sensor errors removed from ``log`` the instruments' scale factors and
    air-data delay removed from it too, :func:`with_instrument_errors_removed`): every
    maneuver of ``log`` is fitted and the model proved on their maneuvers
    (:func:`identify`'s ``validation``; the air-data proof of match in auto mode for the
    filter methods, since its turbulence is not known). ``time_base``: of a .tlog or .mcap
    log and its validation flights of the same format (:func:`pipeline.ingest.readers.read_log`;
    None: the default). ``input_dynamics``: the control-input delay and lag stage
    (:func:`input_dynamics_stage`: auto, off or (delay, lag)); they go to the validation
    flights too (the same servos)."""
    from estimators.validation import default_tolerances

    tol = default_tolerances(**(bands or {}))
    from pipeline.conditioning.checks import run_checks, summarize
    from pipeline.ingest.aircraft import aircraft_for_log
    from pipeline.ingest.readers import detect_format, read_log
    from pipeline.problems.user_model import check_methods, identify_user_model, is_user_model, split_spec

    user = is_user_model(model)
    if user:  # cheap checks before the log is read
        split_spec(model)
        check_methods(methods)
    # ingest, aircraft, air-data angles, checks, compatibility, input dynamics, its
    # uncertainty, outputs (8),
    # the user model's loading, the validation flight's ingest and angles, a fit and its
    # validation per method and axis (both axes for auto: recounted once the log is read)
    vlogs = validation_flights(validation_log)
    pr = Progress(8 + user + 2 * len(vlogs) + 2 * len(methods) * (2 if model == "auto" else 1), quiet=quiet)
    pr.stage(f"ingest {log}")
    from pipeline.ingest.aircraft import servo_travel_for

    fd, steps, steps_doc = time_steps(
        read_log(log, map=map_path, servo_travel=servo_travel_for(log, aircraft), time_base=time_base), MAX_RATE_HZ
    )
    pr.done(
        f"{len(fd.channels)} channels, {len(fd.segments)} segments"
        + (f"; {step_summary(steps_doc)}" if steps_doc else "")
    )
    pr.stage("aircraft and sensor positions")
    notes: list[str] = []
    ac, ac_name, truth_doc = aircraft_for_log(log, aircraft, fd, required=not user, say=notes.append)
    pr.done(ac_name or "none (user model)")
    for n in notes if not quiet else ():
        print(n, file=pr.stream)
    truth = (
        {k: float(v) for k, v in truth_doc["derivatives"].items()}
        if truth_doc and truth_doc.get("derivatives")
        else None
    )
    ac_sensors = ac
    fd, ac, fd_logged, flow = flow_angle_stage(fd, ac, pr)
    fd_vals, val_checks = [], []
    seen = {Path(log).resolve(): "the log being fitted"}
    for vlog in vlogs:
        if Path(vlog).resolve() in seen:
            raise FsidError(
                f"--validate-with {vlog}: that is {seen[Path(vlog).resolve()]}; "
                "give another flight (or leave it out to hold out the last maneuver)"
            )
        seen[Path(vlog).resolve()] = "a validation flight already given"
    # the same pitot: a validation flight takes the fitted flight's scale factor
    cal = flow.get("airspeed_scale") or {}
    k_pitot = cal["estimate"] if cal.get("applied") else (0.0 if cal.get("carried") else None)
    for vlog in vlogs:
        pr.stage(f"ingest the validation flight {vlog}")
        fv = time_steps(
            read_log(
                vlog,
                map=map_path,
                servo_travel=servo_travel_for(vlog, aircraft),
                time_base=time_base if detect_format(vlog) == fd.meta["format"] else None,
            ),
            MAX_RATE_HZ,
        )[0]
        pr.done(f"{len(fv.channels)} channels, {len(fv.segments)} segments")
        fd_vals.append(flow_angle_stage(fv, ac_sensors, pr, airspeed_scale=k_pitot)[0])
        val_checks.append(summarize(run_checks(fd_vals[-1])))
    if user:  # before the slow stages: a bad model fails at once
        pr.stage(f"load model {model}")
        from pipeline.problems.user_model import check_channels, load_user_model

        um = load_user_model(model, ac, fd)
        check_channels(fd, um)
        pr.done(
            f"{um.name}: {len(um.states)} states, {len(um.inputs)} inputs, "
            f"{len(um.outputs)} outputs, {sum(p.free for p in um.parameters)} free parameters"
        )
    pr.stage("data-quality checks")
    summary = summarize(run_checks(fd))
    pr.done(str(summary))
    meta = {"log": str(log), "aircraft": ac_name}
    if fd_vals:
        meta["validation flight"] = "; ".join(
            f"{validation_prefix(k, len(vlogs))}{vlog}" if len(vlogs) > 1 else str(vlog) for k, vlog in enumerate(vlogs)
        ) + (
            f": the proof of match; every maneuver of {Path(log).name} fitted; data-quality "
            "checks: " + "; ".join(", ".join(f"{k} {v}" for k, v in c.items()) for c in val_checks)
        )
    if fd.meta.get("servo_travel"):
        meta["servo_travel"] = fd.meta["servo_travel"]
        assumed = [k for k, v in fd.meta["servo_travel"].items() if v["from"] == "assumed"]
        if assumed and not quiet:
            print(
                f"note: {', '.join(assumed)} from servo commands with "
                f"{fd.meta['servo_travel'][assumed[0]]['deg']:g} deg at full travel assumed; the "
                f"control derivatives scale with it: give the aircraft TOML's [servos] "
                f"({', '.join(a + '_travel_deg' for a in assumed)})",
                file=pr.stream,
            )
    n_axes = 1 if user else identified_axes(fd, ("longitudinal", "lateral") if model == "auto" else (model,))
    pr.total = pr.n + 2 + 2 * max(n_axes, 1) * len(methods) + 2  # compatibility, delays, fits, uncertainty, outputs
    from pipeline.conditioning.compatibility import truth_errors

    # the reconstruction sees the logged channels only: angles rebuilt from the GPS velocity
    # and attitude are no independent air data (with them, 4 "significant" sensor errors
    # were applied on a windy longitudinal_3211_turbulence); they are rebuilt afterwards
    # from the corrected data, and again in every refit of the correction uncertainty
    from pipeline.conditioning.flow_angles import assumptions as flow_assumptions
    from pipeline.conditioning.flow_angles import summary as flow_summary

    fd_c, comp = compatibility_after_flow_angles(
        fd_logged, fd, flow, ac_sensors, pr, enabled=compat, truth=truth_errors(truth_doc) if truth_doc else None
    )
    if flow.get("status") == "reconstructed":
        fd, flow = with_flow_angles(fd_c, flow)  # rebuilt from the corrected data
        meta["air-data angles"] = flow_summary(flow)
        meta["air-data angles assume"] = flow_assumptions(flow)
        meta["flow_angles"] = {**flow, "data": comp["data_for_estimation"]}
    else:  # derived angles not rebuilt: as logged
        fd = replace(
            fd_c, channels={**fd_c.channels, **{k: c for k, c in fd.channels.items() if k not in fd_c.channels}}
        )
    meta["data"] = f"{Path(log).name}, {comp['data_for_estimation']}"
    from pipeline.conditioning.input_dynamics import summary as dynamics_summary
    from pipeline.conditioning.input_dynamics import with_input_dynamics

    fd_before, (fd, dyn_doc) = fd, input_dynamics_stage(fd, pr, input_dynamics)
    from pipeline.uncertainty.consider import quiet_progress

    axes = ("longitudinal", "lateral") if model == "auto" else (model,)

    def fits(data, starts, only=None):
        """The fits (of ``only`` methods, default all) repeated on ``data``, started from
        ``starts``; results only."""
        if user:
            return identify_user_model(
                data,
                um,
                only or methods,
                truth,
                quiet_progress(),
                inputs=inputs,
                starts=starts,
                smooth_inputs=smooth_inputs,
                fit_all=bool(fd_vals),
            )[0]
        return identify(
            data,
            ac,
            only or methods,
            truth,
            quiet_progress(),
            inputs=inputs,
            axes=axes,
            starts=starts,
            smooth_inputs=smooth_inputs,
            fit_all=bool(fd_vals),
        )[0]

    def refit(fd_j, starts, wind_offset=(0.0, 0.0, 0.0)):
        """The fits repeated on data ``fd_j`` (the angles rebuilt with ``wind_offset``, the
        input dynamics applied as in the fits), started from ``starts``; results only."""
        return fits(with_input_dynamics(with_flow_angles(fd_j, flow, wind_offset)[0], dyn_doc["applied"]), starts)

    # the fits with other input dynamics: the data the stage had (angles as rebuilt)
    fd, dyn_doc = refine_input_dynamics_stage(
        fd_before,
        fd,
        dyn_doc,
        methods,
        pr,
        lambda dyn, starts: fits(with_input_dynamics(fd_before, dyn), {} if starts is None else starts, only=("oem",)),
    )
    applied = dict(dyn_doc["applied"])
    fd_vals = [with_input_dynamics(with_instrument_errors_removed(fv, comp, meta), applied) for fv in fd_vals]
    if user:
        results, validations, problems = identify_user_model(
            fd,
            um,
            methods,
            truth,
            pr,
            inputs=inputs,
            tolerances=tol,
            pom=pom,
            smooth_inputs=smooth_inputs,
            validation=fd_vals,
        )
        meta["model"] = model
    else:
        results, validations, problems = identify(
            fd,
            ac,
            methods,
            truth,
            pr,
            inputs=inputs,
            axes=axes,
            tolerances=tol,
            pom=pom,
            smooth_inputs=smooth_inputs,
            validation=fd_vals,
        )
    # the wind's refits (models that see an air-data angle): the corrected data the fits
    # saw, the angles rebuilt with the wind moved
    starts = dict(results)
    angles = any({"alpha", "beta"} & {*pb.model.inputs, *pb.model.outputs} for pb in problems)
    sampling = carry_consider_uncertainty(
        fd_logged,
        comp,
        results,
        validations,
        truth,
        pr,
        refit,
        flow=flow,
        wind_refit=(lambda offset: refit(fd_c, starts, offset)) if angles else None,
        dynamics=dyn_doc,
        dynamics_refit=lambda dyn: fits(with_input_dynamics(fd_before, dyn), starts),
        steps=steps,
        inputs_data=fd_before,
        inputs_refit=lambda data: fits(with_input_dynamics(data, dyn_doc["applied"]), starts),
    )
    meta["control-input delay and lag"] = dynamics_summary(dyn_doc)
    meta["input_dynamics"] = dyn_doc
    meta.update(sampling_meta(steps_doc, sampling))
    if "wind_uncertainty" in flow:
        from pipeline.uncertainty.consider import wind_summary

        meta["flow_angles"]["wind_uncertainty"] = flow["wind_uncertainty"]
        meta["air-data angles' wind"] = wind_summary(flow["wind_uncertainty"])
    if truth is not None:
        meta["truth"] = "truth.json next to the log"
    return _write_outputs(out, results, validations, problems, truth, pr, checks=summary, meta=meta, compatibility=comp)


def _write_outputs(
    out: Path,
    results,
    validations,
    problems,
    truth,
    pr: Progress,
    *,
    checks: Any,
    meta: Mapping[str, Any],
    compatibility: Mapping[str, Any] | None = None,
) -> dict[str, Path]:
    """The methods' cross-check (their std final by now), then report.md, report.json and
    run.rrd."""
    from pipeline.outputs.recording import write_recording
    from pipeline.outputs.report import write_report
    from pipeline.validation.validate import cross_check_methods

    agreement = cross_check_methods(results, validations)
    pr.stage("write report.md, report.json, run.rrd")
    md, js = write_report(
        out,
        results,
        validations,
        truth=truth,
        meta=meta,
        checks=checks,
        compatibility=compatibility,
        agreement=agreement,
    )
    rrd = write_recording(out / "run.rrd", results, validations, truth=truth)
    pr.done()
    return {"report.md": md, "report.json": js, "run.rrd": rrd}
