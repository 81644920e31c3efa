"""The estimates of the methods fitted to one axis side by side: each system parameter in
its own panel, every method's estimate with -/+ 2 std (the total std: Cramér-Rao plus what
the fit held as exact), the truth where known and the a-priori value with its own 2 std."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from estimators import EstimationResult
from pipeline.outputs.figures.refs import FigureRef, NotDrawn, make
from pipeline.outputs.figures.style import APRIORI, TRUTH, WIDTH, file_part, method_color, top_legend
from pipeline.registry import FitKey
from pipeline.validation import is_segment_parameter

#: half-width of the error bars in std
K_BAR = 2.0
#: panels per row
_COLUMNS = 6


def system_parameters(r: EstimationResult) -> list[str]:
    """The free parameters of a result that describe the aircraft: no initial states, no
    per-segment biases."""
    return [n for n in r.free_names if not n.startswith("x0_") and not is_segment_parameter(n)]


def estimates_figure(
    folder: Path,
    group: str,
    results: Mapping[str, EstimationResult],
    validations: Mapping[str, Mapping[str, Any]],
    truth: Mapping[str, float] | None,
) -> FigureRef:
    """The estimates figure of the methods ``results`` (key -> result) of axis ``group``."""
    names: list[str] = []
    for r in results.values():
        names += [n for n in system_parameters(r) if n not in names]
    rows = max(1, math.ceil(len(names) / _COLUMNS))
    title = f"estimates{f' ({group})' if group else ''}"
    against = [w for w, has in (("the truth", truth), ("the a-priori values", _apriori(validations))) if has]
    return make(
        folder,
        f"{file_part(group) + '_' if group else ''}estimates",
        "parameters",
        f"{title}: {', '.join(results)}, each -/+ {K_BAR:g} std (total)"
        + (f", against {' and '.join(against)}" if against else ""),
        (WIDTH, 1.55 * rows + 0.9),
        lambda fig: _draw(fig, names, results, validations, truth or {}, title),
    )


def _apriori(validations: Mapping[str, Mapping[str, Any]]) -> dict[str, tuple[float, float]]:
    """A-priori (value, std) per parameter from the methods' plausibility checks."""
    out: dict[str, tuple[float, float]] = {}
    for v in validations.values():
        for n, d in ((v or {}).get("plausibility") or {}).get("apriori", {}).items():
            if d.get("apriori") is not None:
                out.setdefault(n, (float(d["apriori"]), float(d.get("apriori_std") or np.nan)))
    return out


def _draw(
    fig: Figure,
    names: list[str],
    results: Mapping[str, EstimationResult],
    validations: Mapping[str, Mapping[str, Any]],
    truth: Mapping[str, float],
    title: str,
) -> None:
    """One panel per parameter: methods on x, estimate -/+ K_BAR std, truth line, a priori."""
    if not names:
        raise NotDrawn("no system parameter was estimated")
    ap = _apriori(validations)
    keys = list(results)
    rows = math.ceil(len(names) / _COLUMNS)
    w, h = fig.get_size_inches()
    ax = fig.subplots(
        rows,
        _COLUMNS,
        squeeze=False,
        gridspec_kw={
            "left": 0.6 / w,
            "right": 1 - 0.15 / w,
            "top": 1 - 0.75 / h,
            "bottom": 0.3 / h,
            "hspace": 0.55,
            "wspace": 0.5,
        },
    )
    ax = ax.ravel()
    slots = keys + (["a priori"] if ap else [])
    for a, n in zip(ax, names):
        for x, k in enumerate(keys):
            r = results[k]
            if n in r.names:
                est, sd = float(r.params[n]), float(r.total_std[n])
                a.errorbar(
                    x,
                    est,
                    yerr=K_BAR * sd if np.isfinite(sd) else None,
                    fmt="o",
                    ms=4,
                    capsize=3,
                    color=method_color(k, keys),
                )
        if n in ap:
            val, sd = ap[n]
            a.errorbar(
                len(keys),
                val,
                yerr=K_BAR * sd if np.isfinite(sd) else None,
                fmt="s",
                ms=4,
                capsize=3,
                color=APRIORI,
                mfc="white",
            )
        if n in truth and truth[n] is not None:
            a.axhline(float(truth[n]), color=TRUTH, lw=1.4, ls="--")
        a.set_title(n)
        a.set_xlim(-0.6, len(slots) - 0.4)
        a.set_xticks(range(len(slots)), [FitKey.parse(s).method for s in slots])
        a.yaxis.get_major_formatter().set_powerlimits((-3, 4))
        a.locator_params(axis="y", nbins=4)
    for a in ax[len(names) :]:
        a.set_visible(False)
    handles = [Line2D([], [], color=method_color(k, keys), marker="o", ls="", label=k) for k in keys]
    if ap:
        handles.append(Line2D([], [], color=APRIORI, marker="s", mfc="white", ls="", label="a priori"))
    if truth:
        handles.append(Line2D([], [], color=TRUTH, ls="--", label="truth"))
    top_legend(fig, handles, [hd.get_label() for hd in handles], f"{title}: -/+ {K_BAR:g} std bars (total std)")
