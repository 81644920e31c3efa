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
from pipeline.paths import atomic_write_text, run_id, staged
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
    files: Mapping[str, str] | None = None,
) -> dict[str, Path]:
    """Write report.md (its figures in ``out/figures``), report.html, report.json and run.rrd
    of ``results`` (key -> result) and their ``validations`` into ``out``, compared with
    ``truth`` where known (``flight``: the whole flight they were fitted on, for run.rrd);
    returns name -> path (the figures are beside report.md, in ``figures/``). ``figures``
    False: report.md without them; ``files``: more files of the set, name -> text. Every
    file carries the run's id (``meta["run_id"]``, the recording's id) and the set appears
    in ``out`` at once, report.json last: a folder holding report.json holds the whole set
    of one run."""
    agreement = cross_check_methods(results, validations)
    pr.stage(f"write report.md{' with its figures' if figures else ''}, report.html, run.rrd, report.json")
    rid = run_id(out)
    meta = {"run_id": rid, **meta} if rid else meta
    with staged(out, "report.json") as stage:
        for name, text in (files or {}).items():
            atomic_write_text(stage / name, text)
        md, _ = write_report(
            stage,
            results,
            validations,
            truth=truth,
            meta=meta,
            checks=checks,
            compatibility=compatibility,
            agreement=agreement,
            figures=figures,
        )
        write_html(stage / "report.html", md)
        write_recording(stage / "run.rrd", results, validations, truth=truth, flight=flight, recording_id=rid)
    pr.done()
    return {name: out / name for name in ("report.md", "report.html", "report.json", "run.rrd")}
