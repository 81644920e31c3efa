"""Why an output-error simulation failed or a fit does not follow the data.

An unstable model integrated open loop runs away from the measurements long before it
overflows (:func:`runaway`); a model that cannot track the flight leaves residuals that
are coloured and large (:func:`follow_note`). Both point to the methods that keep the
simulation bounded (:data:`UNSTABLE_METHODS`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from estimators.defaults import FOLLOW_LAG1, FOLLOW_SHARE, RUNAWAY_FACTOR
from estimators.errors import DIVERGE_HINT, SimulationDivergedError
from estimators.filters.linearize import linearize_batch
from estimators.model import Model, Segment


def runaway(seg: Segment, Y: np.ndarray) -> tuple[int, int] | None:
    """(sample, output) where the simulated outputs Y (N, n_out) first run away from the
    measured ones (see RUNAWAY_FACTOR), or None."""
    with np.errstate(all="ignore"):
        med = np.nanmedian(seg.z, axis=0) if np.any(np.isfinite(seg.z)) else np.zeros(Y.shape[1])
        scale = np.nanmax(np.abs(seg.z - med), axis=0)
    ok = np.isfinite(scale) & (scale > 0)
    if not np.any(ok):
        return None
    bad = np.abs(Y[:, ok] - med[ok]) > RUNAWAY_FACTOR * scale[ok]
    if not np.any(bad):
        return None
    i = int(np.argmax(bad.any(axis=1)))
    return i, int(np.flatnonzero(ok)[np.argmax(bad[i])])


def runaway_error(model: Model, seg: Segment, k: int, where: tuple[int, int], what: str) -> SimulationDivergedError:
    """The error for segment k's simulated output that ran away at ``where`` (sample,
    output) (:func:`runaway`); ``what`` says at which parameter values."""
    i, o = where
    return SimulationDivergedError(
        f"the simulation of segment {seg.name or k} diverged at t={seg.t[i]:.4g} s (output "
        f"{model.outputs[o]!r} ran away to more than {RUNAWAY_FACTOR:g} times the measured "
        f"range; the model is unstable or far off) {what}. {DIVERGE_HINT}",
        segment=k,
        time=float(seg.t[i]),
        state=model.outputs[o],
    )


#: the methods that keep the simulation of an unstable aircraft bounded, named in messages
UNSTABLE_METHODS = "StabilizedOutputError, EigenvalueTransformation, EquationDecoupling or FilterError"


def lag1_autocorrelation(E: Sequence[np.ndarray]) -> np.ndarray:
    """(n_out,) lag-1 autocorrelation of residuals ``E`` (per segment (N_k, n_out)), each
    output over its measured (finite) samples, demeaned per segment and pooled over the
    segments as :func:`estimators.validation.whiteness` pools them; NaN without data."""
    n_out = np.shape(E[0])[1]
    rho = np.full(n_out, np.nan)
    for j in range(n_out):
        cols = [np.asarray(e, float)[:, j] for e in E]
        cols = [c[np.isfinite(c)] for c in cols]
        cols = [c - c.mean() for c in cols if c.size > 2]
        if cols:
            c0 = sum(float(c @ c) for c in cols)
            c1 = sum(float(c[:-1] @ c[1:]) for c in cols)
            if c0 > 0:
                rho[j] = c1 / c0
    return rho


def _pooled_variance(X: Sequence[np.ndarray]) -> np.ndarray:
    """(n,) variance of each column about its per-segment mean, finite samples only."""
    ss = sum(np.nansum((x - np.nanmean(x, axis=0)) ** 2, axis=0) for x in X)
    return ss / np.maximum(sum(np.isfinite(x).sum(axis=0) for x in X), 1)


def slowest_mode(model: Model, segments: Sequence[Segment], params: np.ndarray) -> float:
    """The largest real eigenvalue (1/s) of df/dx at the first segment's initial state and
    input for the model parameters ``params`` (n_p,) (:func:`linearize_batch`): the
    aperiodic mode an output-error fit moves to the stability boundary when the aircraft
    is unstable (an oscillatory mode, a lightly damped phugoid, is not that). NaN when f is
    not finite there or every eigenvalue is complex."""
    seg = segments[0]
    x0 = np.asarray(seg.initial_state(model), float)
    A = linearize_batch(
        model, np.asarray(params, float)[:, None], x0[:, None], np.asarray(seg.u[0], float), model.constants_for(seg)
    )[0][0]
    if not np.all(np.isfinite(A)):
        return float("nan")
    lam = np.linalg.eigvals(A)
    real = lam.real[np.abs(lam.imag) <= 1e-9 * np.maximum(np.abs(lam), 1e-300)]
    return float(np.max(real)) if real.size else float("nan")


def follow_note(
    outputs: Sequence[str],
    segments: Sequence[Segment],
    E: Sequence[np.ndarray],
    runaways: int = 0,
    sigma_max: float = float("nan"),
) -> tuple[str, dict[str, Any]]:
    """A message, and its numbers, when an output-error fit did not follow the data: at
    least half the outputs with residuals coloured and large (see FOLLOW_LAG1), or trial
    parameter values whose simulation ran away (``runaways`` of them). Both mark a model
    simulated open loop that cannot track the flight: an unstable aircraft, or strong
    process noise (turbulence). Half the outputs are needed because one poorly modelled
    channel is not the aircraft. Also when the estimate leaves the model at the stability
    boundary (its slowest mode's real part ``sigma_max`` (1/s) slower than the record) with
    residuals far from white: the fit moved the model there instead of following an
    unstable flight. Returns (message, numbers); ``numbers["std_withdrawn"]``: after
    run-away trials the bounds mean nothing and are withdrawn; otherwise the message says
    they understate the error. ("", {}) otherwise."""
    with np.errstate(all="ignore"):
        rho = lag1_autocorrelation(E)
        share = _pooled_variance(E) / _pooled_variance([s.z for s in segments])
    half = max(1, int(np.ceil(len(outputs) / 2)))
    bad = [j for j in range(len(outputs)) if rho[j] > FOLLOW_LAG1 and share[j] > FOLLOW_SHARE]
    coloured = len(bad) >= half
    # an estimate that left the model just stable: a mode slower than the record, with
    # residuals far from white (however small): the fit moved the model to the boundary
    # rather than follow an unstable flight
    record = max(float(s.t[-1] - s.t[0]) for s in segments)
    white_off = [j for j in range(len(outputs)) if rho[j] > FOLLOW_LAG1]
    boundary = bool(np.isfinite(sigma_max) and abs(sigma_max) * record < 1.0 and len(white_off) >= half)
    if not coloured and not runaways and not boundary:
        return "", {}
    why = []
    if boundary and not coloured:
        bad = white_off
        why.append(
            f"the estimate leaves the model at the stability boundary (slowest mode's real part "
            f"{sigma_max:.3g} 1/s, a time constant longer than the {record:.3g} s record) with the "
            f"residuals of {', '.join(outputs[j] for j in bad)} far from white (lag-1 autocorrelation "
            f"{', '.join(f'{rho[j]:.2f}' for j in bad)})"
        )
    if coloured:
        why.append(
            f"the residuals of {', '.join(outputs[j] for j in bad)} are far from white "
            f"(lag-1 autocorrelation {', '.join(f'{rho[j]:.2f}' for j in bad)}) and "
            f"leave {', '.join(f'{100 * min(share[j], 9.99):.0f}' for j in bad)} % of "
            "their measured variance unexplained"
        )
    if runaways:
        why.append(f"the simulation ran away for {runaways} trial parameter set{'s' if runaways > 1 else ''}")
    withdrawn = bool(runaways)
    msg = (
        f"the model does not follow the data: {' and '.join(why)}. An unstable aircraft "
        "(or strong turbulence) cannot be fitted by simulating it open loop: use "
        f"{UNSTABLE_METHODS}. "
        + (
            "The Cramér-Rao std, which assume a model that follows the flight, are withdrawn (NaN; "
            "extra['not_followed']['crb_std'] keeps them)"
            if withdrawn
            else "The Cramér-Rao std assume white residuals and understate the error (see the "
            "coloured-residual bounds, Morelli-Klein)"
        )
    )
    info = {
        "outputs": [outputs[j] for j in bad],
        "runaways": int(runaways),
        "lag1": dict(zip(outputs, rho.tolist())),
        "unexplained": dict(zip(outputs, share.tolist())),
        "slowest_mode": sigma_max,
        "std_withdrawn": withdrawn,
    }
    return msg, info
