"""The modes of the linearised models of one axis in the complex plane: every method's
eigenvalues (1/s) with the mode names, lines of constant damping ratio, and a second panel
around the origin for the slow modes (phugoid, spiral) that the fast ones squeeze there."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from pipeline.outputs.figures.refs import FigureRef, NotDrawn, make
from pipeline.outputs.figures.style import MEASURED, WIDTH, file_part, method_color, top_legend

#: damping ratios drawn as rays from the origin
ZETAS = (0.1, 0.3, 0.7)
#: a mode slower than this fraction of the fastest one is shown in the zoomed panel
SLOW = 0.12
_MARKERS = "oxs^vD"
_RAY_STYLES = (":", "--", "-.")


def modes_figure(folder: Path, group: str, validations: Mapping[str, Mapping[str, Any]]) -> FigureRef:
    """The modes figure of the methods ``validations`` (key -> validation) of axis ``group``."""
    title = f"modes{f' ({group})' if group else ''}"
    return make(
        folder,
        f"{file_part(group) + '_' if group else ''}modes",
        "modes",
        f"{title} of the linearised models: {', '.join(validations)}",
        (WIDTH, 4.4),
        lambda fig: _draw(fig, validations, title),
    )


def _points(validations: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, complex]]:
    """Per method key its modes' eigenvalues (upper half plane) by mode name."""
    out: dict[str, dict[str, complex]] = {}
    for k, v in validations.items():
        table = ((v or {}).get("modes") or {}).get("table") or {}
        pts = {n: complex(d["real"], abs(d.get("imag") or 0.0)) for n, d in table.items() if d.get("real") is not None}
        if pts:
            out[k] = pts
    return out


def _draw(fig: Figure, validations: Mapping[str, Mapping[str, Any]], title: str) -> None:
    """Left: all modes; right: the slow ones (when the fast ones hide them)."""
    pts = _points(validations)
    if not pts:
        raise NotDrawn("no method has modes (a regression, or the linearisation failed)")
    every = np.array([p for d in pts.values() for p in d.values()])
    big = float(np.max(np.abs(every))) or 1.0
    slow = {k: {n: p for n, p in d.items() if abs(p) < SLOW * big} for k, d in pts.items()}
    zoom = any(slow.values())
    w, h = fig.get_size_inches()
    ax = fig.subplots(
        1,
        2 if zoom else 1,
        squeeze=False,
        gridspec_kw={"left": 0.75 / w, "right": 1 - 0.2 / w, "top": 1 - 0.75 / h, "bottom": 0.5 / h, "wspace": 0.22},
    )[0]
    keys = list(validations)
    _plane(ax[0], pts, keys, labelled=lambda p: not zoom or abs(p) >= SLOW * big)
    ax[0].set_title("all modes")
    if zoom:
        _plane(ax[1], slow, keys, labelled=lambda p: True)
        ax[1].set_title(f"slow modes (|eigenvalue| < {SLOW * big:.2g} 1/s)")
    handles = [
        ax[0].plot([], [], _MARKERS[i % len(_MARKERS)], color=method_color(k, keys), label=k)[0]
        for i, k in enumerate(keys)
    ]
    handles += [h for h in ax[0].get_lines() if str(h.get_label()).startswith("damping ratio")]
    top_legend(
        fig, handles, [hd.get_label() for hd in handles], f"{title}: eigenvalues (upper half; each has its conjugate)"
    )


def _plane(ax, pts: Mapping[str, Mapping[str, complex]], keys: list[str], labelled) -> None:
    """Eigenvalues per method (marker and colour), each mode's name once, damping rays."""
    allp = np.array([p for d in pts.values() for p in d.values()])
    if allp.size == 0:
        return
    span = max(float(np.max(np.abs(allp))), 1e-6)
    x0, x1 = min(float(allp.real.min()), -0.3 * span) - 0.1 * span, max(float(allp.real.max()), 0.0) + 0.15 * span
    y0, y1 = -0.1 * span, max(float(allp.imag.max()), 0.3 * span) + 0.15 * span
    named: set[str] = set()
    for i, k in enumerate(keys):
        for n, p in (pts.get(k) or {}).items():
            ax.plot(p.real, p.imag, _MARKERS[i % len(_MARKERS)], color=method_color(k, keys), ms=6, mew=1.3)
            if n not in named and labelled(p):
                named.add(n)
                ax.annotate(n, (p.real, p.imag), xytext=(6, 6), textcoords="offset points", fontsize=8)
    for z, ls in zip(ZETAS, _RAY_STYLES):  # rays of constant damping ratio (named in the legend)
        c, s_ = z, np.sqrt(1.0 - z * z)
        t = min(-x0 / c, y1 / s_)
        ax.plot([0, -t * c], [0, t * s_], color="0.55", lw=0.8, ls=ls, label=f"damping ratio {z:g}")
    ax.axvline(0.0, color=MEASURED, lw=0.8)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_xlabel("real part [1/s]")
    ax.set_ylabel("imaginary part [rad/s]")
