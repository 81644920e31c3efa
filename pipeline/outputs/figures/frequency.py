"""Frequency responses of one fit: for each output/input pair the magnitude (dB) and
phase (deg) of the data's spectral estimate, of the model's simulated outputs through the
same estimator, and of the linearised model G(jw), with the coherence that says where the
data's estimate can be trusted (the points the check used are marked)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from pipeline.outputs.figures.refs import FigureRef, NotDrawn, make
from pipeline.outputs.figures.style import (
    MEASURED,
    bode_axes,
    file_part,
    grid_size,
    method_color,
    panel_grid,
    scale_label,
    top_legend,
    unit_text,
)

#: the frequency axis ends at this multiple of the highest frequency the check used
_F_MARGIN = 3.0
#: an output/input pair is drawn when the check judged it at this many frequencies or more
MIN_POINTS = 2


def frequency_figures(folder: Path, key: str, v: Mapping[str, Any]) -> list[FigureRef]:
    """The frequency-response figure of method ``key`` from its validation ``v``
    (``arrays["freq"]``, ``frequency["bounds"]``): one row per output/input pair the check
    could judge at :data:`MIN_POINTS` frequencies or more; none without a frequency check."""
    fr = (v.get("arrays") or {}).get("freq")
    if not fr:
        return []
    min_coh = ((v.get("frequency") or {}).get("bounds") or {}).get("min_coherence")
    used = np.asarray(fr["used"], dtype=bool)
    pairs = [
        (a, b) for b in range(len(fr["inputs"])) for a in range(len(fr["outputs"])) if used[:, a, b].sum() >= MIN_POINTS
    ]
    left = [f"{o}/{i}" for b, i in enumerate(fr["inputs"]) for a, o in enumerate(fr["outputs"]) if (a, b) not in pairs]
    return [
        make(
            folder,
            f"{file_part(key)}_freq",
            "frequency",
            f"{key}: frequency responses (data, model, linearised model) and coherence"
            + (f"; not shown (fewer than {MIN_POINTS} coherent points): {', '.join(left)}" if left else ""),
            grid_size(max(len(pairs), 1), 1.15),
            lambda fig: _draw(fig, key, fr, pairs, min_coh),
        )
    ]


def _db(h: np.ndarray) -> np.ndarray:
    """20 log10 |h| (NaN where zero)."""
    m = np.abs(h)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(m > 0, 20.0 * np.log10(m), np.nan)


def _draw(fig: Figure, key: str, fr: Mapping[str, Any], pairs: list[tuple[int, int]], min_coh: float | None) -> None:
    """Rows: output/input pairs; columns: magnitude, phase, coherence; x: frequency (Hz, log)."""
    if not pairs:
        raise NotDrawn(f"no output/input pair has {MIN_POINTS} coherent frequencies")
    f = np.asarray(fr["f"], dtype=float)
    used = np.asarray(fr["used"], dtype=bool)
    keep = (f > 0) & (f <= _F_MARGIN * f[used.any(axis=(1, 2))].max())
    ax = panel_grid(fig, len(pairs), 3)
    color = method_color(key)
    for row, (a_, b) in enumerate(pairs):
        o, i = fr["outputs"][a_], fr["inputs"][b]
        gain = scale_label(o)[0] / scale_label(i)[0]  # display units per display unit (deg/s per deg)
        curves = (
            ("data", fr["H_data"], MEASURED, "-", 0.9),
            (f"model ({key})", fr["H_model"], color, "-", 1.3),
            ("linearised model G(jw)", fr["H_analytic"], color, "--", 1.0),
        )
        ref = np.asarray(fr["H_model"])[keep, a_, b]
        ref_phase = np.unwrap(np.angle(ref))
        for name, H, c, ls, lw in curves:
            h = np.asarray(H)[keep, a_, b] * gain
            ax[row, 0].plot(f[keep], _db(h), color=c, ls=ls, lw=lw, label=name)
            # each phase as the model's unwrapped phase plus its wrapped difference from it: a
            # difference reads as the check judges it, never as a 360 deg jump of one unwrap
            ph = ref_phase + np.angle(np.asarray(H)[keep, a_, b] * np.conj(ref))
            ax[row, 1].plot(f[keep], np.degrees(ph), color=c, ls=ls, lw=lw, label=name)
        u = used[keep, a_, b]
        h = np.asarray(fr["H_data"])[keep, a_, b] * gain
        ax[row, 0].plot(f[keep][u], _db(h)[u], ".", color=MEASURED, ms=5, label="points checked")
        ax[row, 2].plot(f[keep], np.asarray(fr["coherence"])[keep, a_, b], color=MEASURED, lw=1.0, label="coherence")
        if min_coh is not None:
            ax[row, 2].axhline(min_coh, color="0.5", lw=0.8, ls=":", label="least coherence checked")
        ax[row, 2].set_ylim(0.0, 1.05)
        ax[row, 0].set_ylabel(f"{o}/{i} [dB]\n({unit_text(o)} per {unit_text(i)})")
        # the pair is named once, on the magnitude; the other columns' titles say what they
        # hold, so their labels stay short and clear of the panel to their left
        ax[row, 1].set_ylabel("deg")
        ax[row, 2].set_ylabel("")
    bode_axes(ax)
    h0, l0 = ax[0, 0].get_legend_handles_labels()
    h2, l2 = ax[0, 2].get_legend_handles_labels()
    top_legend(fig, h0 + h2, l0 + l2, f"{key}: frequency responses")
