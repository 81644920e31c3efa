"""Time histories of a fit: measured and model outputs on the fitted maneuvers (with the
control surfaces that drove them), and the residuals against the data's noise level.

One row per output in display units (deg, deg/s, g); the maneuvers laid end to end along
the time axis (:class:`~pipeline.outputs.figures.style.Strip`), at most
:data:`~pipeline.outputs.figures.style.MAX_MANEUVERS` per figure (more go to further figures)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from estimators import EstimationResult
from pipeline.outputs.figures.refs import FigureRef, NotDrawn, make
from pipeline.outputs.figures.style import (
    MEASURED,
    TOLERANCE,
    Strip,
    chunks,
    file_part,
    grid_size,
    method_color,
    panel_grid,
    scale_label,
    series,
    top_legend,
)
from pipeline.outputs.recording_layout import segment_names

#: inputs shown under the outputs: the control surfaces (deg)
CONTROLS = ("de", "da", "dr")
#: line style and legend name of each control surface: grey, told apart by the dash, so
#: that no surface shares a colour with a method's model line
CONTROL_COLOR = "#555555"
CONTROL_STYLES = {"de": ("-", "de elevator"), "da": ("--", "da aileron"), "dr": ("-.", "dr rudder")}


def time_history_figures(folder: Path, key: str, r: EstimationResult, fit: Mapping[str, Any]) -> list[FigureRef]:
    """The time-history and residual figures of result ``r`` (method key ``key``);
    ``fit``: the validation's per-output fit metrics (their ``noise_std``, SI)."""
    names = segment_names(r)
    groups = chunks(len(r.predicted)) or [range(0)]
    refs = []
    for n, idx in enumerate(groups):
        part = f"_{n + 1}" if len(groups) > 1 else ""
        which = "" if len(groups) == 1 else f", maneuvers {idx.start + 1}-{idx.stop} of {len(r.predicted)}"
        rows = len(r.outputs) + (1 if _controls(r) else 0)
        refs.append(
            make(
                folder,
                f"{file_part(key)}_timehist{part}",
                "fit",
                f"{key}: measured and model outputs on the fitted maneuvers{which}",
                grid_size(rows, 1.05),
                lambda fig, idx=idx: _draw_outputs(fig, key, r, list(idx), names),
            )
        )
        refs.append(
            make(
                folder,
                f"{file_part(key)}_residuals{part}",
                "fit",
                f"{key}: residuals (measured - model) with the data's noise level{which}",
                grid_size(len(r.outputs), 0.95),
                lambda fig, idx=idx: _draw_residuals(fig, key, r, list(idx), names, fit),
            )
        )
    return refs


def _controls(r: EstimationResult) -> list[str]:
    """The model's control-surface inputs, in CONTROLS order."""
    return [i for i in CONTROLS if i in list(r.model.inputs)]


def _draw_outputs(fig: Figure, key: str, r: EstimationResult, idx: list[int], names: list[str]) -> None:
    """Measured (dark) and model (method colour) outputs, and the control surfaces below."""
    if not idx or not r.outputs:
        raise NotDrawn("the result keeps no fitted time histories")
    controls = _controls(r)
    ax = panel_grid(fig, len(r.outputs) + (1 if controls else 0))[:, 0]
    strip = Strip([r.predicted[k].index.to_numpy(float) for k in idx], [names[k] for k in idx])
    color = method_color(key)
    for c, k in enumerate(idx):
        pred, res = r.predicted[k], r.residuals[k]
        t = strip.x(c, pred.index)
        for j, o in enumerate(r.outputs):
            fac = scale_label(o)[0]
            ax[j].plot(*series(t, pred[o] + res[o], fac), color=MEASURED, lw=0.8, label="measured" if c == 0 else None)
            ax[j].plot(
                *series(t, pred[o], fac), color=color, lw=1.3, alpha=0.9, label=f"model ({key})" if c == 0 else None
            )
        if controls and k < len(r.segments):
            seg = r.segments[k]
            for i in controls:
                dash, name = CONTROL_STYLES[i]
                u = seg.u[:, list(r.model.inputs).index(i)]
                ax[-1].plot(
                    *series(strip.x(c, seg.t), u, 180.0 / np.pi),
                    color=CONTROL_COLOR,
                    ls=dash,
                    lw=1.0,
                    label=name if c == 0 else None,
                )
    for j, o in enumerate(r.outputs):
        ax[j].set_ylabel(scale_label(o)[1])
    if controls:
        ax[-1].set_ylabel("surface [deg]")
    strip.decorate(ax)
    handles, labels = ax[0].get_legend_handles_labels()
    if controls:
        h2, l2 = ax[-1].get_legend_handles_labels()
        handles, labels = handles + h2, labels + l2
    top_legend(fig, handles, labels, f"{key}: measured and model outputs")


def _draw_residuals(
    fig: Figure, key: str, r: EstimationResult, idx: list[int], names: list[str], fit: Mapping[str, Any]
) -> None:
    """Residuals (method colour) with a band of -/+ the output's white-noise std (grey)."""
    if not idx or not r.outputs:
        raise NotDrawn("the result keeps no residuals")
    ax = panel_grid(fig, len(r.outputs))[:, 0]
    strip = Strip([r.residuals[k].index.to_numpy(float) for k in idx], [names[k] for k in idx])
    color = method_color(key)
    for j, o in enumerate(r.outputs):
        fac, label = scale_label(o)
        noise = (fit.get(o) or {}).get("noise_std")
        if noise is not None and np.isfinite(noise):
            ax[j].axhspan(-noise * fac, noise * fac, color=TOLERANCE, alpha=0.5, lw=0, label="-/+ noise std")
        ax[j].axhline(0.0, color=MEASURED, lw=0.6)
        for c, k in enumerate(idx):
            res = r.residuals[k]
            ax[j].plot(
                *series(strip.x(c, res.index), res[o], fac),
                color=color,
                lw=0.8,
                label=f"residual ({key})" if c == 0 else None,
            )
        ax[j].set_ylabel(label)
    strip.decorate(ax)
    handles, labels = ax[0].get_legend_handles_labels()
    top_legend(fig, handles, labels, f"{key}: residuals and the measurement noise level (white part of the data)")
