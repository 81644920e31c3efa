"""How well the fit follows its data: fit metrics per output and the residual analysis."""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from estimators import EstimationResult
from estimators import statistics as st
from estimators import validation as V
from pipeline.validation.json_values import frame_dict, num

#: TIC below which a channel's fit counts as good (DESIGN.md section 8)
TIC_LIMIT = 0.1
#: a channel whose residual rms is within this factor of its white measurement noise is fitted
#: as well as its noise allows (the model's own error at most 0.66 of the noise): a TIC at or
#: above TIC_LIMIT there is the noise's, and the verdict notes it instead of failing on it
NOISE_FLOOR_RATIO = 1.2


def measured(result: EstimationResult) -> list[pd.DataFrame]:
    """Measured outputs per fitted segment, DataFrames on t (z = predicted + residual)."""
    return [p + r for p, r in zip(result.predicted, result.residuals)]


def fit_summary(result: EstimationResult, tic_limit: float) -> dict[str, Any]:
    """The fit metrics per output (``per_output``), ``det_R``, ``max_TIC``, ``tic_ok``, and
    the outputs whose TIC reaches ``tic_limit`` only through their measurement noise
    (``tic_noise_floor``: residual rms within NOISE_FLOOR_RATIO of the white-noise level of
    their own samples' second differences, robust to the kinks at control steps;
    ``noise_std`` per output). An output a maneuver hardly moves is fitted as well as its
    noise allows and still has a TIC at the limit."""
    z = measured(result)
    df = V.fit_metrics(z, result.predicted, names=result.outputs)
    out = frame_dict(df)
    tic = df["TIC"].to_numpy()
    noise = st.difference_noise_std([f.to_numpy(float) for f in z], robust=True)
    floor = []
    for o, sd, t in zip(result.outputs, noise, tic):
        out[o]["noise_std"] = num(sd)
        if t >= tic_limit and np.isfinite(sd) and sd > 0 and out[o]["RMS"] <= NOISE_FLOOR_RATIO * sd:
            floor.append(o)
    return {
        "per_output": out,
        "det_R": num(df.attrs["det_R"]),
        "max_TIC": num(np.nanmax(tic)) if np.isfinite(tic).any() else None,
        "tic_limit": tic_limit,
        "tic_ok": bool(np.all(tic < tic_limit)),
        "tic_noise_floor": floor,
    }


def residual_analysis(result: EstimationResult) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """(section, arrays): residual statistics and whiteness per output (``stats``,
    ``whiteness``, ``max_lag``, ``all_white``, ``fs_hz``), and the residual power spectrum
    of the longest segment (``f`` (n_f,) Hz, ``Pxx`` (n_f, n_out) units^2/Hz)."""
    res = [r.to_numpy() for r in result.residuals]
    stats = V.residual_stats(res, names=result.outputs)
    w = V.whiteness(res, names=result.outputs)
    t0 = result.residuals[0].index.to_numpy()
    fs = 1.0 / float(np.median(np.diff(t0)))
    f, P = V.psd(res[int(np.argmax([len(r) for r in res]))], fs)
    return (
        {
            "stats": frame_dict(stats),
            "whiteness": frame_dict(w.to_frame()),
            "max_lag": w.max_lag,
            "all_white": bool(np.all(w.white)),
            "fs_hz": fs,
        },
        {"f": f, "Pxx": P},
    )
