"""What every figure of report.md shares: size and resolution, colours, axis labels in
display units, decimation of long series, and rendering to PNG bytes without pyplot.

Figures are drawn on a :class:`matplotlib.figure.Figure` with its own Agg canvas (no pyplot,
no backend switched: a notebook importing this keeps its own) inside :func:`render`, which
applies :data:`RC` for that figure only and returns the PNG bytes; :func:`save` writes them
atomically (0644)."""

from __future__ import annotations

import io
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from matplotlib import rc_context
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from pipeline.paths import atomic_write_bytes
from pipeline.registry import method_colour
from pipeline.validation import display_unit

#: resolution of every PNG (dots per inch); with the sizes below about 1000-1400 px wide
DPI = 110
#: width of a full-width figure in inches
WIDTH = 11.0
#: most points drawn per line: longer series are thinned by a stride (the shape stays readable)
MAX_POINTS = 1500
#: matplotlib settings for the report's figures (applied per figure by :func:`render`)
RC = {
    "font.size": 8.5,
    "axes.titlesize": 9,
    "axes.labelsize": 8.5,
    "legend.fontsize": 7.5,
    "xtick.labelsize": 7.5,
    "ytick.labelsize": 7.5,
    "axes.grid": True,
    "grid.alpha": 0.35,
    "grid.linewidth": 0.5,
    "lines.linewidth": 1.1,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "legend.frameon": False,
    "path.simplify": True,
    "axes.formatter.useoffset": False,
    "axes.titlepad": 3.0,
}
#: colours of the data lines and bands (matplotlib colour specs)
MEASURED = "#282828"
TRUTH = "#c8a000"
TOLERANCE = "#bdbdbd"
APRIORI = "#7f7f7f"
MISS = "#d62728"


def method_color(method: str, order: Sequence[str] = ()) -> str:
    """The colour of an estimation method or result key ("oem", "lateral-fem", ...): the
    catalogue's, the one run.rrd uses (:func:`pipeline.registry.method_colour`)."""
    r, g, b = method_colour(method, order)
    return f"#{r:02x}{g:02x}{b:02x}"


def scale_label(channel: str) -> tuple[float, str]:
    """(factor, axis label) of a canonical channel in its display unit: ``q [deg/s]``;
    a channel without a known unit is labelled by its name alone."""
    fac, unit = display_unit(channel)
    return fac, (f"{channel} [{unit}]" if unit != "SI" else channel)


def unit_text(channel: str) -> str:
    """The display unit of a channel ("-" when it has none)."""
    label = scale_label(channel)[1]
    return label.split("[", 1)[1].rstrip("]") if "[" in label else "-"


def bode_axes(ax) -> None:
    """The shared decoration of a frequency-response grid (rows: pairs; columns:
    magnitude, phase, coherence): log frequency with plain labels at 1, 2, 5 per decade
    (minor ticks and mathtext cost most of the drawing time), the column titles and the
    frequency label under the last row."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullLocator

    for a in ax.flat:
        a.set_xscale("log")
        a.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        a.xaxis.set_minor_locator(NullLocator())
        a.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
    for c, name in enumerate(("magnitude", "phase", "coherence")):
        ax[0, c].set_title(name)
        ax[-1, c].set_xlabel("frequency [Hz]")


def stride(n: int) -> slice:
    """The slice that keeps at most about :data:`MAX_POINTS` of ``n`` samples, evenly."""
    return slice(None, None, max(1, math.ceil(n / MAX_POINTS)))


def series(t, y, factor: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(t, y * factor) for a line: the finite samples only (a slower sensor on a faster grid
    leaves NaN between its samples, which would break the line into nothing), thinned by a
    stride to at most about :data:`MAX_POINTS`."""
    t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
    ok = np.isfinite(t) & np.isfinite(y)
    t, y = t[ok], y[ok]
    s = stride(t.size)
    return t[s], y[s] * factor


def file_part(name: str) -> str:
    """A file-name part from a method key or segment name: characters outside
    [A-Za-z0-9_.-] become '_'."""
    return re.sub(r"[^A-Za-z0-9_.\-]", "_", str(name)) or "_"


def grid_size(n_rows: int, row_height: float, extra: float = 0.9) -> tuple[float, float]:
    """(width, height) in inches of a full-width figure of ``n_rows`` panel rows."""
    return WIDTH, n_rows * row_height + extra


def render(size: tuple[float, float], draw: Callable[[Figure], None]) -> bytes:
    """PNG bytes of a new ``size`` (inches) figure drawn by ``draw(fig)`` under :data:`RC`."""
    with rc_context(RC):
        fig = Figure(figsize=size, dpi=DPI)
        FigureCanvasAgg(fig)
        draw(fig)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None}, pil_kwargs={"compress_level": 3})
    return buf.getvalue()


def save(path: Path, png: bytes) -> Path:
    """Write the PNG bytes atomically (readable by others)."""
    return atomic_write_bytes(path, png)


#: most maneuvers laid side by side in one figure; more go to further figures
MAX_MANEUVERS = 4


def chunks(n: int, size: int = MAX_MANEUVERS) -> list[range]:
    """Index ranges of at most ``size`` covering ``range(n)`` in order."""
    return [range(i, min(i + size, n)) for i in range(0, n, size)]


def panel_grid(fig: Figure, n_rows: int, n_cols: int = 1, *, top: float = 0.85, bottom: float = 0.45):
    """A (n_rows, n_cols) array of axes sharing x per column, placed with fixed margins in
    inches (``top`` above the first row for the titles and the figure legend, ``bottom``
    for the x label; a y label and tick labels at the left of every column): no overlap
    and no layout engine to pay for."""
    w, h = fig.get_size_inches()
    left, right, gap_x, gap_y = 0.85, 0.15, 0.75, 0.22
    ax = fig.subplots(
        n_rows,
        n_cols,
        sharex="col",
        squeeze=False,
        gridspec_kw={
            "left": left / w,
            "right": 1 - right / w,
            "top": 1 - top / h,
            "bottom": bottom / h,
            "wspace": gap_x * n_cols / max(w - left - right - gap_x * (n_cols - 1), 1.0),
            "hspace": gap_y * n_rows / max(h - top - bottom - gap_y * (n_rows - 1), 1.0),
        },
    )
    for a in ax.flat:  # few ticks: readable in a small panel, and ticks are most of the drawing time
        a.yaxis.set_major_locator(MaxNLocator(4))
    return ax


#: width of one character of a maneuver's name over the panels, inches (8.5 pt, generous)
_NAME_INCH = 0.075


class Strip:
    """Maneuvers laid end to end on one x axis, a small gap between them, so that one row of
    panels shows them all: :meth:`x` places a maneuver's own times (s from the log's start),
    :meth:`decorate` draws the separators, names and tick labels in those own times."""

    def __init__(self, times: Sequence[np.ndarray], names: Sequence[str]) -> None:
        spans = [(float(t[0]), float(t[-1])) if len(t) else (0.0, 0.0) for t in times]
        self.gap = gap = 0.04 * max(sum(b - a for a, b in spans), 1e-9)
        self.names, self.spans, self.offsets = list(names), spans, []
        start = 0.0
        for a, b in spans:
            self.offsets.append(start - a)
            start += (b - a) + gap

    def x(self, k: int, t) -> np.ndarray:
        """Maneuver ``k``'s times (s) on the strip."""
        return np.asarray(t, dtype=float) + self.offsets[k]

    def decorate(self, column) -> None:
        """Separators on every panel of ``column`` (axes top to bottom), the maneuvers' names
        over the first (on two staggered lines where they would not fit side by side), ticks
        in each maneuver's own time under the last (fewer, or none, on a narrow maneuver)."""
        fig = column[0].get_figure()
        lo, hi = self.spans[0][0] + self.offsets[0], self.spans[-1][1] + self.offsets[-1]
        inch = column[0].get_position().width * fig.get_size_inches()[0] / max(hi - lo, 1e-9)  # in per s
        crowded = any(_NAME_INCH * len(n) > inch * (b - a + self.gap) for n, (a, b) in zip(self.names, self.spans))
        ticks, labels = [], []
        for k, ((a, b), off) in enumerate(zip(self.spans, self.offsets)):
            n_ticks = min(3, int(inch * (b - a) / 0.6))
            for v in MaxNLocator(max(n_ticks, 1)).tick_values(a, b) if n_ticks else []:
                if a <= v <= b:
                    ticks.append(v + off)
                    labels.append(f"{v:g}")
            if k:
                for ax in column:
                    ax.axvline(a + off - self.gap / 2, color="0.3", lw=0.8)
            x, half = (a + b) / 2 + off, _NAME_INCH * len(self.names[k]) / 2 / inch
            x, ha = (hi, "right") if x + half > hi else (lo, "left") if x - half < lo else (x, "center")
            column[0].text(
                x,
                1.03 + (0.16 if crowded and k % 2 else 0.0),
                self.names[k],
                transform=column[0].get_xaxis_transform(),
                ha=ha,
                va="bottom",
                fontsize=8.5,
            )
        column[-1].set_xticks(ticks, labels)
        column[-1].set_xlim(lo, hi)
        column[-1].set_xlabel("time from the log's start [s] (maneuvers laid end to end)")


def top_legend(fig: Figure, handles: list, labels: list, title: str) -> None:
    """The figure's title and, under it, the legend for all panels: one row when it fits the
    width, else as many rows as it needs, the panels moved down to make room."""
    w, h = fig.get_size_inches()
    widths = [_LEGEND_ENTRY + _LEGEND_CHAR * len(str(lab)) for lab in labels]
    ncol = max(len(labels), 1)
    while ncol > 1 and _legend_width(widths, ncol) > w - 0.4:
        ncol -= 1
    rows = math.ceil(len(labels) / ncol) if labels else 1
    fig.suptitle(title, y=1 - 0.08 / h, va="top", fontsize=10)
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 1 - 0.3 / h), ncol=ncol)
    if rows > 1:
        for gs in {id(a.get_gridspec()): a.get_gridspec() for a in fig.axes}.values():
            gs.update(top=gs.top - _LEGEND_ROW * (rows - 1) / h)


#: legend entry width in inches: handle and padding, and per character of its label (7.5 pt)
_LEGEND_ENTRY, _LEGEND_CHAR = 0.6, 0.058
#: height of one more legend row, inches
_LEGEND_ROW = 0.19


def _legend_width(widths: list[float], ncol: int) -> float:
    """Width in inches of a legend of entries ``widths`` in ``ncol`` columns (filled column by
    column, as matplotlib does)."""
    rows = math.ceil(len(widths) / ncol)
    return sum(max(widths[c * rows : (c + 1) * rows], default=0.0) for c in range(ncol))
