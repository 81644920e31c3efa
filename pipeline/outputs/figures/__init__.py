"""The figures of report.md (PNG, matplotlib's Agg canvas, no pyplot): per fit the
measured and model time histories and the residuals, the proof of match, the frequency
responses; per axis the estimates of its methods side by side and their modes.

:func:`render_figures` draws them into a folder next to report.md and returns, per method
key, the :class:`FigureRef` of each figure for the method's section of report.md; a figure
whose data are missing is a one-line note there instead."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from estimators import EstimationResult
from pipeline.outputs.figures.estimates import estimates_figure
from pipeline.outputs.figures.frequency import frequency_figures
from pipeline.outputs.figures.match import match_figures
from pipeline.outputs.figures.modes import modes_figure
from pipeline.outputs.figures.refs import SECTIONS, FigureRef
from pipeline.outputs.figures.time_histories import time_history_figures
from pipeline.validation.names import method_group

__all__ = ["SECTIONS", "FigureRef", "render_figures", "section_markdown"]


def render_figures(
    folder: str | Path,
    results: Mapping[str, EstimationResult],
    validations: Mapping[str, Mapping[str, Any]],
    truth: Mapping[str, float] | None = None,
) -> dict[str, list[FigureRef]]:
    """Draw every figure of the run into ``folder`` (created; the report links them as
    ``<folder name>/<file>.png``) and return method key -> its figures in report order.

    results: method key -> result; validations: method key -> validation with its
    ``arrays`` (:func:`pipeline.validation.validate`); truth: true parameter values, shown
    in the estimates figure where known."""
    folder = Path(folder)
    groups: dict[str, list[str]] = {}
    for key in results:
        groups.setdefault(method_group(key), []).append(key)
    out: dict[str, list[FigureRef]] = {key: [] for key in results}
    for group, keys in groups.items():
        vals = {k: validations.get(k) or {} for k in keys}
        estimates = estimates_figure(folder, group, {k: results[k] for k in keys}, vals, truth)
        with_modes = [k for k in keys if (vals[k].get("modes") or {}).get("table")]
        modes = [modes_figure(folder, group, {k: vals[k] for k in with_modes})] if with_modes else []
        for k in keys:
            v = vals[k]
            fit = (v.get("fit") or {}).get("per_output") or {}
            refs = [estimates] + (modes if k in with_modes else []) + time_history_figures(folder, k, results[k], fit)
            refs += match_figures(folder, k, v) + frequency_figures(folder, k, v)
            out[k] = sorted(refs, key=lambda f: SECTIONS.index(f.section))
    return out


def section_markdown(refs: list[FigureRef]) -> dict[str, list[str]]:
    """report.md lines per section of one method's figures (images or skip notes)."""
    lines: dict[str, list[str]] = {}
    for f in refs:
        lines.setdefault(f.section, []).extend(f.markdown())
    return lines
