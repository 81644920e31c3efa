"""The uncertainty of the wind that angles rebuilt from the flight path
(:mod:`pipeline.conditioning.flow_angles`) were computed with: the fitted horizontal wind's
std, the pitot scale factor's, and the mean vertical wind the reconstruction assumes zero,
for the estimates' consider covariance."""

from __future__ import annotations

from typing import Any

import numpy as np


def markov_mean_std(sigma: float, tau: float, spans: Any) -> float:
    """Std of the time average, over the union of ``spans`` [(t0, t1), ...] [s], of a
    stationary first-order Markov process of std ``sigma`` and time constant ``tau`` [s]
    (autocovariance sigma^2 exp(-|dt| / tau)). Exact: with the merged spans [a_i, b_i]
    of lengths L_i and total T, the variance is sigma^2 / T^2 sum_ij I_ij with
    I_ii = 2 tau^2 (L_i / tau - 1 + exp(-L_i / tau)) and, for a_i < b_i <= a_j < b_j,
    I_ij = tau^2 (exp((b_i - a_j)/tau) - exp((b_i - b_j)/tau) - exp((a_i - a_j)/tau)
    + exp((a_i - b_j)/tau)). One span much longer than tau: sigma sqrt(2 tau / T);
    much shorter: sigma."""
    iv = sorted((float(a), float(b)) for a, b in spans if b > a)
    merged: list[list[float]] = []
    for a, b in iv:
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    if not merged or sigma <= 0.0 or tau <= 0.0:
        return 0.0
    a, b = np.array(merged).T
    L = b - a
    T = float(L.sum())
    total = float(np.sum(2.0 * tau**2 * (L / tau - 1.0 + np.exp(-L / tau))))
    i, j = np.triu_indices(a.size, k=1)
    total += 2.0 * float(
        np.sum(
            tau**2
            * (
                np.exp((b[i] - a[j]) / tau)
                - np.exp((b[i] - b[j]) / tau)
                - np.exp((a[i] - a[j]) / tau)
                + np.exp((a[i] - b[j]) / tau)
            )
        )
    )
    return float(sigma * np.sqrt(max(total, 0.0)) / T)


#: names of the parts whose uncertainty :func:`wind_uncertainty` returns (the order of
#: :func:`pipeline.conditioning.flow_angles.reconstruct_flow_angles`' ``wind_offset``)
WIND_PARTS = ("wind north", "wind east", "vertical wind", "airspeed scale")
#: the largest scale length of the vertical gust [m] (MIL-F-8785C: 1750 ft above 2000 ft,
#: the altitude below): its time constant is at most this over the airspeed
L_W_MAX = 533.4


def wind_uncertainty(doc: dict[str, Any], spans: Any) -> dict[str, float]:
    """The std [m/s] of the wind the rebuilt angles were computed with, over the fitted
    ``spans`` [(t0, t1), ...] [s], by :data:`WIND_PARTS`: the horizontal wind's from its fit
    (the mean over the knots of the std of each component, taken as one shift of all
    knots; given the pitot's scale factor), the pitot's scale factor's [-] where it was
    estimated (:func:`airspeed_calibration` ``carried``), and the mean vertical wind's,
    which the reconstruction assumes zero. In turbulence the vertical gust averaged over
    the fitted spans is not zero: it shifts alpha by W_d / V and trades with CL0, Cm0,
    CD0. Its std is :func:`markov_mean_std` of the vertical gust, taken as isotropic
    with the horizontal one the airspeed residual shows: level sqrt(residual^2 -
    pitot noise^2), time constant the residual's correlation time (MIL-F-8785C: below
    2000 ft the vertical gust is weaker and shorter, so this errs on the large side), at
    most :data:`L_W_MAX` over the mean airspeed (a slower residual is the horizontal wind
    changing, not vertical turbulence). Not covered: vertical air motion that is no
    turbulence (thermals, ridge lift, waves). Nothing rebuilt: {}."""
    if doc.get("status") != "reconstructed":
        return {}
    w = doc["wind"]
    res, noise = doc["airspeed_residual_rms_mps"], doc.get("airspeed_noise_mps") or 0.0
    sigma = float(np.sqrt(max(res**2 - (noise if np.isfinite(noise) else 0.0) ** 2, 0.0)))
    tau = float(doc.get("airspeed_residual_tau_s", 0.0))
    if doc.get("airspeed_mean_mps"):
        tau = min(tau, L_W_MAX / float(doc["airspeed_mean_mps"]))
    cal = doc.get("airspeed_scale") or {}
    return {
        "wind north": float(np.mean(w["std_north_mps"])),
        "wind east": float(np.mean(w["std_east_mps"])),
        "vertical wind": markov_mean_std(sigma, tau, spans),
        "airspeed scale": float(cal["std"]) if cal.get("carried") else 0.0,
    }
