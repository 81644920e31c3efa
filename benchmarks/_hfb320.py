"""The HFB-320 longitudinal case of the reference software's test case 4, replicated by
simulation, for :mod:`benchmarks.first_fit`.

The model is :func:`estimators.replicas.hfb320_model` (states V m/s, alpha rad, theta rad,
q rad/s; inputs elevator de rad and thrust N; outputs V, alpha, theta, q, qdot rad/s^2, ax
and az m/s^2; 11 free derivatives), written as users write it: f and g share a helper.
The data: 601 samples at 10 Hz from the reference's initial state, simulated at the
reference's estimates (HFB320_TRUTH) with an elevator multistep, plus white noise of the
reference's estimated R (HFB320_R). The recorded flight is not redistributable, so this replica stands in for it:
the same model, size and noise level, hence the same work for the fit.

This module imports numpy only: the timed process (:func:`timed_fit`) imports estimators
(and the replica's model and start values) itself, and the import's time is part of what
is measured.
"""

from __future__ import annotations

import numpy as np

DT, N = 0.1, 601


def model(values):
    """The replica's model (:func:`estimators.replicas.hfb320_model`) with every parameter
    free at ``values``."""
    from estimators.replicas import hfb320_model

    return hfb320_model(values)


def _pulses(t, t0, unit, pattern, amplitude):
    out = np.zeros_like(t)
    for w in pattern:
        end = t0 + abs(w) * unit
        out[(t >= t0) & (t < end)] = amplitude * np.sign(w)
        t0 = end
    return out


def inputs() -> tuple[np.ndarray, np.ndarray]:
    """t (601,) s at 10 Hz and U (601, 2): elevator (rad) a 3-2-1-1 of 1 s pulses at 2 s,
    a reversed one at 20 s and a 2 s doublet at 40 s about -0.026 rad; thrust 9700 N
    held (the reference flight's is nearly constant)."""
    t = np.arange(N) * DT
    de = (
        -0.026
        + _pulses(t, 2.0, 1.0, (3, -2, 1, -1), 0.03)
        + _pulses(t, 20.0, 1.0, (3, -2, 1, -1), -0.03)
        + _pulses(t, 40.0, 2.0, (1, -1), 0.02)
    )
    return t, np.c_[de, np.full(N, 9700.0)]


def make_data(path: str, seed: int = 0) -> None:
    """Simulate the replica at HFB320_TRUTH (the package's RK4, default input convention), add the
    noise and save t, u, z, x0 to ``path`` (.npz)."""
    from estimators import Segment, simulate_outputs
    from estimators.replicas import HFB320_R, HFB320_TRUTH, HFB320_X0

    t, U = inputs()
    seg = Segment(t=t, u=U, z=np.zeros((N, len(HFB320_R))), x0=HFB320_X0)
    y = simulate_outputs(model(HFB320_TRUTH), seg).to_numpy()
    z = y + np.random.default_rng(seed).standard_normal(y.shape) * np.sqrt(HFB320_R)
    np.savez(path, t=t, u=U, z=z, x0=HFB320_X0)


def timed_fit(path: str, t_start: float) -> dict:
    """What the timed process does after start-up: import estimators, load the data, build
    the model and fit with OutputError's defaults. Returns the phase times (s, from
    ``t_start``, a ``time.perf_counter()`` taken first thing) and the estimates."""
    import time

    t0 = time.perf_counter()
    from estimators import OutputError, Segment
    from estimators.replicas import HFB320_START

    t1 = time.perf_counter()
    d = np.load(path)
    seg = Segment(t=d["t"], u=d["u"], z=d["z"], x0=d["x0"])
    res = OutputError(model(HFB320_START)).fit([seg])
    t2 = time.perf_counter()
    return {
        "before_import": t0 - t_start,
        "import": t1 - t0,
        "fit": t2 - t1,
        "total": t2 - t_start,
        "converged": bool(res.converged),
        "iterations": int(res.iterations),
        "params": {k: float(v) for k, v in res.params.items()},
        "std": {k: float(v) for k, v in res.std.items()},
    }
