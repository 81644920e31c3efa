"""The frequency-domain methods of the pipeline, on the band from the maneuvers' input
spectra: output error ("fdoe": the built-in or user model linearised at each maneuver's
start, :class:`estimators.FrequencyOutputError`) and equation error ("fdls": the built-in
models' coefficient regressions transformed maneuver by maneuver,
:meth:`estimators.FourierRegression.fit_records`); each with a time-domain view of the fit
for the validation (the same checks and proof of match as every method)."""

from __future__ import annotations

from dataclasses import replace
from functools import partial
from typing import Any

import numpy as np

from estimators import EstimationResult, FourierRegression, FrequencyOutputError, OutputError, Segment
from estimators.validation import ClusterResult
from pipeline.methods.equation_error import equation_error
from pipeline.problems import Problem
from pipeline.problems.regressions import Regression

#: the band: where the inputs' summed spectrum (each input scaled to its own peak) reaches
#: this share of its peak (every frequency weighs alike in the frequency domain, so where
#: the inputs carry little power what the model leaves out - sensor lags, actuators -
#: weighs as much as the dynamics)
BAND_POWER = 0.1
#: the transforms' detrending: a least-squares line (the line through the first and last
#: samples, the reference's convention, carries their noise into every frequency)
DETREND = "linear"
#: the band's upper end: at most this (Hz) and a fifth of the grid's rate
BAND_MAX_HZ = 10.0
#: the built-in models' trim terms: they set the operating point, which the band does not
#: see (the model is linearised at each maneuver's measured start), so they are held at
#: the problem's start values (equation error's)
TRIM_TERMS = ("CL0", "CD0", "Cm0", "CY0", "Cl0", "Cn0")
#: the name of the reported covariance: per parameter the larger of the Cramér-Rao and
#: the sandwich std
REPORTED = "crb|sandwich"
#: at most this many frequencies (spaced by the longest maneuver's resolution 1/T otherwise)
MAX_FREQUENCIES = 200


def input_band(segments: list[Segment]) -> tuple[float, float, float]:
    """(f_low, f_high, df) in Hz: where the maneuvers' inputs carry power (module constants)
    and the spacing 1/T of the shortest maneuver: closer frequencies share that maneuver's
    resolution, their residuals correlated, and the bounds that count each frequency as
    independent would be too small."""
    dt = float(np.median(np.diff(segments[0].t)))
    T = max(s.t[-1] - s.t[0] + dt for s in segments)
    n = int(2 ** np.ceil(np.log2(T / dt)))
    f = np.fft.rfftfreq(n, dt)
    power = np.zeros(f.size)
    for s in segments:
        u = s.u - s.u.mean(axis=0)
        P = np.abs(np.fft.rfft(u, n=n, axis=0)) ** 2
        peak = P[1:].max(axis=0)
        power += (P / np.where(peak > 0, peak, 1.0)).sum(axis=1)
    power[0] = 0.0
    lo_res = 1.0 / T
    on = np.flatnonzero((power >= BAND_POWER * power.max()) & (f >= lo_res))
    f_hi = min(float(f[on[-1]]) if on.size else BAND_MAX_HZ, BAND_MAX_HZ, 0.2 / dt)
    f_lo = max(float(f[on[0]]) if on.size else lo_res, lo_res)
    df = 1.0 / min(s.t[-1] - s.t[0] + dt for s in segments)
    return f_lo, max(f_hi, f_lo + 2 * df), df


def band_frequencies(segments: list[Segment]) -> tuple[np.ndarray, float, float]:
    """(f, f_low, f_high): the frequencies (Hz) of a fit on ``segments``, spaced by the
    shortest maneuver's 1/T over :func:`input_band` (at least 8, at most MAX_FREQUENCIES)."""
    f_lo, f_hi, df = input_band(segments)
    n = int(min(MAX_FREQUENCIES, np.floor((f_hi - f_lo) / df) + 1))
    return np.linspace(f_lo, f_hi, max(n, 8)), f_lo, f_hi


def larger_std(covs: dict[str, np.ndarray]) -> np.ndarray:
    """The reported covariance: per parameter the larger of the "crb" and "sandwich" std
    (the reference's bound, or the sandwich where the residuals' level across the band makes
    that larger), correlations those of the Cramér-Rao bound."""
    with np.errstate(invalid="ignore", divide="ignore"):
        D = np.sqrt(np.diag(covs["sandwich"]) / np.diag(covs["crb"]))
    D = np.where(np.isfinite(D), np.maximum(D, 1.0), 1.0)
    return D[:, None] * covs["crb"] * D[None, :]


def _complete(seg: Segment) -> Segment:
    """The segment with outputs slower than its grid read linearly between their samples
    (the frequency domain needs complete records)."""
    z = seg.z.copy()
    for j in range(z.shape[1]):
        ok = np.isfinite(z[:, j])
        if not ok.all() and ok.sum() >= 2:
            z[:, j] = np.interp(seg.t, seg.t[ok], z[ok, j])
    return replace(seg, z=z)


def frequency_output_error(problem: Problem, model: Any, s: Any) -> EstimationResult:
    """Frequency-domain output error on the problem's maneuvers (module docstring); the
    band and what was held go to the problem's notes. The result carries the shared
    derivatives with the frequency-domain bounds, and the time-domain fit of each
    maneuver's own parameters (initial states, biases) with those derivatives held, whose
    predictions and residuals the validation judges."""
    segs = [_complete(sg) for sg in problem.fit]
    f, f_lo, f_hi = band_frequencies(segs)
    trim = {p.name: p.value for p in model.parameters if p.free and p.name in TRIM_TERMS}
    fd_model = model.hold(trim) if trim else model
    fdoe = FrequencyOutputError(fd_model, 2 * np.pi * f, detrend=DETREND, x_ref="initial").fit(segs, start=s.start)
    problem.notes.append(
        f"frequency-domain output error on {f_lo:.3g}-{f_hi:.3g} Hz ({f.size} frequencies, where the inputs carry "
        f">= {BAND_POWER:.0%} of their peak power), the model linearised at each maneuver's start"
        + "; transforms detrended by a least-squares line"
        + (f"; trim terms held at their start values (the band does not see them): {', '.join(trim)}" if trim else "")
        + (f"; {fdoe.message}" if fdoe.message else "")
    )
    shared = {n: v for n, v in zip(fdoe.names, fdoe.values) if "[" not in n}
    td = OutputError(fd_model.hold(shared), inputs=problem.inputs).fit(problem.fit, estimate_x0=problem.estimate_x0)
    values = np.array([shared.get(n, v) for n, v in zip(td.names, td.values)])
    free = np.array([n in fdoe.free_names for n in td.names])
    order = [fdoe.free_names.index(n) for n in np.array(td.names)[free]]
    covs = {k: c[np.ix_(order, order)] for k, c in fdoe.covariances.items()}
    covs[REPORTED] = larger_std(covs)
    return EstimationResult(
        method="fdoe",
        model=model,
        names=list(td.names),
        values=values,
        free=free,
        cov=covs[REPORTED],
        cov_type=REPORTED,
        covariances=covs,
        R=td.R,
        converged=fdoe.converged,
        iterations=fdoe.iterations,
        history=fdoe.history,
        predicted=td.predicted,
        residuals=td.residuals,
        segments=problem.fit,
        at_bounds=fdoe.at_bounds,
        message=fdoe.message,
        settings={**td.settings, **fdoe.settings, "band_hz": [f_lo, f_hi]},
        extra={
            # the maneuvers' scatter against the bounds (the validation widens by it)
            **({"cluster": fdoe.extra["cluster"]} if "cluster" in fdoe.extra else {}),
            "frequency_residuals": fdoe.residuals,
            "S": fdoe.extra["S"],
            "w": fdoe.extra["w"],
            "time_domain_fit": "initial states and per-maneuver parameters with the derivatives held",
        },
    )


def frequency_equation_error(problem: Problem, model: Any, s: Any) -> EstimationResult:
    """``fdls``: the problem's coefficient regressions in the frequency domain (module
    docstring) on the fdoe band; the intercepts (trim terms, biases) drop out of it and are
    held. Per derivative the reported std is the larger of the regression's Cramér-Rao and
    sandwich std."""
    f, f_lo, f_hi = band_frequencies([_complete(sg) for sg in problem.fit])
    res = equation_error(problem, partial(_fourier_regression, f=f))
    problem.notes.append(
        f"frequency-domain equation error on {f_lo:.3g}-{f_hi:.3g} Hz ({f.size} frequencies per maneuver); "
        "the intercepts (trim terms) drop out of the band and are held"
    )
    coefs = ", ".join(r.outputs[0] for r in res.extra["regressions"])
    return res.replace(
        method="fdls",
        cov_type=REPORTED,
        covariances={REPORTED: res.cov},
        message=f"frequency-domain equation error on {coefs}; predictions: the model with these derivatives, "
        "initial states and biases fitted",
        settings={**res.settings, "optimizer": "fourier regression", "band_hz": [f_lo, f_hi], "domain": "frequency"},
    )


def _fourier_regression(reg: Regression, f: np.ndarray) -> tuple[EstimationResult, ClusterResult | None]:
    """One coefficient regression in the frequency domain: each maneuver's rows (resampled
    onto a uniform grid where rows were dropped) transformed on their own, the intercept
    column left out; the covariance reported is :func:`larger_std`'s."""
    cols = list(reg.names[1:])
    records = []
    for k in np.unique(reg.window):
        rows = reg.window == k
        t, X, y = reg.t[rows], reg.X[rows][:, 1:], reg.y[rows]
        if t.size < 2 * len(cols) + 2:
            continue
        dt = float(np.median(np.diff(t)))
        if np.max(np.abs(np.diff(t) - dt)) > 1e-6 * dt:
            grid = np.arange(t[0], t[-1] + 0.5 * dt, dt)
            X = np.column_stack([np.interp(grid, t, x) for x in X.T])
            y, t = np.interp(grid, t, y), grid
        records.append((t, X, y))
    res = FourierRegression(cols, frequencies=f, detrend=DETREND, response=reg.coef).fit_records(records)
    return res.with_cov(larger_std(dict(res.covariances)), REPORTED), None
