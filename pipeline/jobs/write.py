"""The last stage of the fitting jobs: the methods' cross-check (their std final by now),
then report.md with its figures, report.html beside it, report.json and run.rrd."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pipeline.jobs.progress import Progress
from pipeline.outputs.html import write_html
from pipeline.outputs.recording import write_recording
from pipeline.outputs.recording_flight import FlightRecord
from pipeline.outputs.report import write_report
from pipeline.validation import cross_check_methods


def write_outputs(
    out: Path,
    results: dict,
    validations: dict,
    truth: Mapping[str, float] | None,
    pr: Progress,
    *,
    checks: Any,
    meta: Mapping[str, Any],
    compatibility: Mapping[str, Any] | None = None,
    flight: FlightRecord | None = None,
    figures: bool = True,
) -> dict[str, Path]:
    """Write report.md (its figures in ``out/figures``), report.html, report.json and run.rrd
    of ``results`` (key -> result) and their ``validations`` into ``out``, compared with
    ``truth`` where known (``flight``: the whole flight they were fitted on, for run.rrd);
    returns name -> path (report.html and the figures are beside report.md). ``figures``
    False: report.md without them."""
    agreement = cross_check_methods(results, validations)
    pr.stage(f"write report.md{' with its figures' if figures else ''}, report.html, report.json, run.rrd")
    md, js = write_report(
        out,
        results,
        validations,
        truth=truth,
        meta=meta,
        checks=checks,
        compatibility=compatibility,
        agreement=agreement,
        figures=figures,
    )
    write_html(out / "report.html", md)
    rrd = write_recording(out / "run.rrd", results, validations, truth=truth, flight=flight)
    pr.done()
    return {"report.md": md, "report.json": js, "run.rrd": rrd}
