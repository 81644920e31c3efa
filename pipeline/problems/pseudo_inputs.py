"""Measured variables of one axis that drive the other axis' model as inputs ("pseudo-inputs").

Output error takes its inputs as exact, so the measured airspeed, angles and rates that drive
a model are low-passed forwards and backwards first; the airspeed's remaining pitot noise is
quantified per window for the a-priori airspeed corrections of the lateral problem.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from estimators import Segment
from pipeline.conditioning.input_smoothing import smooth_columns
from pipeline.ingest.flightdata import FlightData

#: zero-phase low-pass corner (Hz) of the measured longitudinal variables that drive the
#: lateral model as inputs: noise on an input is not in the output-error likelihood
PSEUDO_INPUT_CORNER_HZ = {"V": 1.0, "alpha": 5.0, "theta": 5.0, "q": 5.0}
#: likewise for the measured lateral variables that drive the longitudinal model
LONG_PSEUDO_CORNER_HZ = {"beta": 5.0, "p": 5.0, "r": 5.0, "phi": 5.0, "ay": 2.0}


def smooth_pseudo_inputs(w: pd.DataFrame, rate_hz: float, corners: Mapping[str, float] | None = None) -> pd.DataFrame:
    """V, alpha, theta, q of a window (or the channels of ``corners``) low-pass filtered
    forwards and backwards (second-order Butterworth at PSEUDO_INPUT_CORNER_HZ) before
    they drive the lateral model."""
    return smooth_columns(w, rate_hz, corners or PSEUDO_INPUT_CORNER_HZ)


def airspeed_window_std(fd: FlightData, segments: Sequence[Segment]) -> tuple[float, list[float]]:
    """(sigma_V, [std of the mean pitot-noise error over each segment]) in m/s.

    sigma_V, the pitot's white-noise level, from its own samples: the second difference
    V[j+1] - 2 V[j] + V[j-1] of white noise has variance 6 sigma^2, and the airspeed's own
    curvature over two pitot samples is negligible. The pseudo-input V is that noise
    interpolated to the grid and low-passed (PSEUDO_INPUT_CORNER_HZ, zero phase); both have
    unit gain at zero frequency, so they leave the window MEAN of the noise as it was: the
    mean of n independent samples, std sigma_V / sqrt(n), n = f_s T the pitot samples in
    the window (the noise in the band 0..f_s/2 has 2 B T = f_s T degrees of freedom over
    T; the low-pass only removes the fluctuation about the mean). Pitot noise coloured
    below the window's bandwidth (drift, pressure-sensor 1/f) is not in this figure."""
    ch = fd["V"]
    t, v = np.asarray(ch.t, dtype=float), np.asarray(ch.values, dtype=float)
    ok = np.isfinite(t) & np.isfinite(v)
    t, v = t[ok], v[ok]
    sigma = float(np.sqrt(np.var(np.diff(v, 2)) / 6.0)) if v.size > 3 else 0.0
    sds = []
    for s in segments:
        n = int(np.count_nonzero((t >= s.t[0]) & (t <= s.t[-1])))
        sds.append(sigma / np.sqrt(max(n, 1)))
    return sigma, sds
