"""Dryden turbulence parameters as JSBSim computes them (MIL-F-8785C, FGWinds.cpp).

JSBSim's turb-type 3 ('milspec', MIL-STD-1797A discretisation) and 4 ('tustin') shape
white noise into Dryden spectra; intensity and scale lengths follow MIL-F-8785C from the
altitude above sea level, the wind at 20 ft (low altitude) and the probability-of-
exceedance table (high altitude). The gusts are along the mean-wind axes: with no mean
wind, u -> north, v -> east, w -> down.
"""

from __future__ import annotations

import numpy as np

FT = 0.3048
#: MIL-F-8785C Fig. 7 as tabulated in JSBSim: POE index rows, altitude (ft) columns, sigma in ft/s
_POE_ALT_FT = np.array([500.0, 1750, 3750, 7500, 15000, 25000, 35000, 45000, 55000, 65000, 75000, 80000])
_POE = {
    1: [3.2, 2.2, 1.5, 0, 0, 0, 0, 0, 0, 0, 0, 0],
    2: [4.2, 3.6, 3.3, 1.6, 0, 0, 0, 0, 0, 0, 0, 0],
    3: [6.6, 6.9, 7.4, 6.7, 4.6, 2.7, 0.4, 0, 0, 0, 0, 0],
    4: [8.6, 9.6, 10.6, 10.1, 8.0, 6.6, 5.0, 4.2, 2.7, 0, 0, 0],
    5: [11.8, 13.0, 16.0, 15.1, 11.6, 9.7, 8.1, 8.2, 7.9, 4.9, 3.2, 2.1],
    6: [15.6, 17.6, 23.0, 23.6, 22.1, 20.0, 16.0, 15.1, 12.1, 7.9, 6.2, 5.1],
    7: [18.7, 21.5, 28.4, 30.2, 30.7, 31.0, 25.2, 23.1, 17.5, 10.7, 8.4, 7.2],
}


def dryden_parameters(altitude_m: float, windspeed_20ft_mps: float, poe_index: int) -> dict[str, float]:
    """Intensities sigma_u/v/w (m/s) and scale lengths L_u/v/w (m) JSBSim uses at this
    altitude (ASL, m). v shares u's intensity and scale length (as in JSBSim)."""
    h = max(altitude_m / FT, 10.0)
    w20 = windspeed_20ft_mps / FT
    poe = float(np.interp(h, _POE_ALT_FT, _POE[poe_index])) if poe_index else 0.0
    if h <= 1000:
        L_u, L_w = h / (0.177 + 0.000823 * h) ** 1.2, h
        sig_w = 0.1 * w20
        sig_u = sig_w / (0.177 + 0.000823 * h) ** 0.4
    elif h <= 2000:
        L_u = L_w = 1000 + (h - 1000.0) / 1000.0 * 750.0
        sig_u = sig_w = 0.1 * w20 + (h - 1000.0) / 1000.0 * (poe - 0.1 * w20)
    else:
        L_u = L_w = 1750.0
        sig_u = sig_w = poe
    return {
        "sigma_u": sig_u * FT,
        "sigma_v": sig_u * FT,
        "sigma_w": sig_w * FT,
        "L_u": L_u * FT,
        "L_v": L_u * FT,
        "L_w": L_w * FT,
    }


def dryden_psd(f_hz: np.ndarray, V: float, sigma: float, L: float, component: str) -> np.ndarray:
    """One-sided Dryden power spectral density ((m/s)^2/Hz) of a gust component ('u', 'v'
    or 'w') seen at airspeed V (m/s), MIL-F-8785C form, at frequencies f_hz (Hz)."""
    w = 2 * np.pi * np.asarray(f_hz, dtype=float)
    tau = L / V
    if component == "u":
        phi = sigma**2 * 2 * tau / np.pi / (1 + (tau * w) ** 2)
    else:
        phi = sigma**2 * tau / np.pi * (1 + 3 * (tau * w) ** 2) / (1 + (tau * w) ** 2) ** 2
    return phi * 2 * np.pi  # per rad/s -> per Hz (two-sided in w folded to one-sided in f)
