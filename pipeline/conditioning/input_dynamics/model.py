"""The model of a control surface behind its logged input, and applying it to a log.

Surface s moves as delta_s(t) = L_tau_s[u_s](t - d_s): the logged value u_s through the
first-order lag L_tau = 1 / (tau s + 1) (tau = 0: none), read d_s later (d > 0: the
surface acts after the logged value). Between samples the estimate reads the surfaces by
cubic convolution (:func:`cubic_at`, smooth in the delay).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.signal import lfilter

from pipeline.ingest.flightdata import Channel, FlightData


def lagged(u: np.ndarray, tau: float, h: float) -> np.ndarray:
    """u (..., n) on a uniform grid of step h [s] through the first-order lag 1/(tau s + 1),
    exact for u linear between samples, started in steady state at u[..., 0]; tau [s] may
    be an array (K,) with u (n,) or (K, n): one lag per row."""
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
