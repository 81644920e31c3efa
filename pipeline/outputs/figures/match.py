"""The proof of match: the identified model's prediction of each held-out maneuver against
the measurement and its band, with the prediction's own uncertainty.

Per channel a row (display units), the held-out maneuvers end to end along the time axis. The model line is the
prediction plus the bias the judgement allows; the grey band around it is -/+ (tolerance +
noise allowance), so a measured sample inside it passes; the coloured band is -/+ PREDICTION_K std of the prediction from the estimates'
covariance; red dots are the samples outside the band."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from estimators.validation import PREDICTION_K
from pipeline.outputs.figures.refs import FigureRef, NotDrawn, make
from pipeline.outputs.figures.style import (
    MEASURED,
    MISS,
    TOLERANCE,
    Strip,
    chunks,
    file_part,
    grid_size,
    method_color,
    panel_grid,
    scale_label,
    series,
    stride,
    top_legend,
)


def match_figures(folder: Path, key: str, v: Mapping[str, Any]) -> list[FigureRef]:
    """The proof-of-match figures of method ``key`` from its validation ``v`` (its
    ``proof_of_match`` and ``arrays["match"]``); none when nothing was held out."""
    arr = list((v.get("arrays") or {}).get("match") or [])
    pm = v.get("proof_of_match") or {}
    if not arr or not pm:
        return []
    segs = list(pm.get("segments") or [])
    groups = chunks(len(arr))
    refs = []
    for n, idx in enumerate(groups):
        part = f"_{n + 1}" if len(groups) > 1 else ""
        rows = max(a["measured"].shape[1] for a in arr)
        refs.append(
            make(
                folder,
                f"{file_part(key)}_match{part}",
                "proof_of_match",
                f"{key}: proof of match on the held-out maneuver(s) {', '.join(arr[k]['name'] for k in idx)}",
                grid_size(rows, 1.0),
                lambda fig, idx=idx: _draw(fig, key, [arr[k] for k in idx], [_at(segs, k) for k in idx], pm),
            )
        )
    return refs


def _at(items: list, k: int) -> Mapping[str, Any]:
    """Item ``k`` of a list, or an empty mapping past its end."""
    return items[k] if k < len(items) else {}


def _draw(fig: Figure, key: str, arr: list[Mapping[str, Any]], segs: list[Mapping[str, Any]], pm) -> None:
    """The held-out segments end to end (``arr``: their arrays, ``segs``: their report entries)."""
    channels = list(arr[0]["measured"].columns)
    if not channels:
        raise NotDrawn("the held-out prediction has no channels")
    ax = panel_grid(fig, len(channels))[:, 0]
    strip = Strip(
        [np.asarray(a["t"], dtype=float) for a in arr],
        [f"{a['name']}: {'PASS' if s.get('all_pass') else 'FAIL'}" for a, s in zip(arr, segs)],
    )
    color = method_color(key)
    for c, (a, s) in enumerate(zip(arr, segs)):
        t = strip.x(c, a["t"])
        for j, o in enumerate(channels):
            if o in a["measured"]:
                _panel(
                    ax[j], a, list(a["measured"].columns).index(o), o, (s.get("channels") or {}).get(o) or {}, t, color
                )
    for j, o in enumerate(channels):
        results = {_result((s.get("channels") or {}).get(o) or {}) for s in segs}
        ax[j].set_ylabel(f"{scale_label(o)[1]}\n{' / '.join(sorted(results))}")
    strip.decorate(ax)
    handles: dict[str, Any] = {}
    for a in ax:
        for h, lab in zip(*a.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    top_legend(
        fig,
        list(handles.values()),
        list(handles),
        f"{key}: proof of match ({pm.get('mode', 'simulation')} mode, every derivative held)",
    )


def _result(d: Mapping[str, Any]) -> str:
    """A channel's outcome for its y label: pass / FAIL / driving / not judged."""
    if d.get("role") == "drives the filter":
        return "driving"
    p = d.get("pass")
    return "not judged" if p is None else ("pass" if p else "FAIL")


def _panel(ax, a: Mapping[str, Any], j: int, o: str, d: Mapping[str, Any], t: np.ndarray, color: str) -> None:
    """Channel ``o`` (column ``j``) of one held-out segment: band, measured, prediction
    (+ allowed bias), its -/+ PREDICTION_K std, the steps' timing range and the misses."""
    fac = scale_label(o)[0]
    z = a["measured"][o].to_numpy(float)
    bias = d.get("bias_removed") or 0.0
    y = a["predicted"][o].to_numpy(float) + bias
    band = float(np.asarray(a["tolerance"], dtype=float)[j]) + (d.get("noise_allowance") or 0.0)
    k = stride(t.size)  # the bands thinned like the lines
    if np.isfinite(band):
        ax.fill_between(
            t[k],
            (y[k] - band) * fac,
            (y[k] + band) * fac,
            color=TOLERANCE,
            alpha=0.6,
            lw=0,
            label="model -/+ (tolerance + noise allowance)",
        )
    ax.plot(*series(t, z, fac), color=MEASURED, lw=0.8, label="measured (held out)")
    ps = a.get("prediction_std")
    if ps is not None and o in ps:
        sd = PREDICTION_K * ps[o].to_numpy(float)
        if np.isfinite(sd).any():
            ax.fill_between(
                t[k],
                (y[k] - sd[k]) * fac,
                (y[k] + sd[k]) * fac,
                color=color,
                alpha=0.3,
                lw=0,
                label=f"model -/+ {PREDICTION_K:g} std (estimates' covariance)",
            )
    env = a.get("envelope")
    if env is not None:
        for e in env:
            ax.plot(
                *series(t, e[o].to_numpy(float) + bias, fac),
                color=color,
                lw=0.7,
                ls="--",
                label="prediction, steps moved in time",
            )
    ax.plot(*series(t, y, fac), color=color, lw=1.3, label="model prediction")
    excess = np.asarray(a.get("excess"), dtype=float)
    if excess.ndim == 2 and excess.shape[0] == t.size:
        miss = np.isfinite(excess[:, j]) & (excess[:, j] > 0)
        if miss.any():
            ax.plot(t[miss], z[miss] * fac, ".", color=MISS, ms=3, label="outside the band")
