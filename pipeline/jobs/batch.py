"""``fsid batch``: every log of a campaign through ``fsid estimate``, one Dask task each.

Each task runs the estimate job exactly as ``fsid estimate`` does (the same options, parsed
by its command line) into DIR/<name>/, and returns that report's rows: one per method and
parameter (estimate, std, total std, verdict, proof of match) with the log's hash, the
options and the tool version. The driver writes DIR/results.parquet again (atomically) as
each task finishes, so an interruption leaves it consistent; a log that fails (a refusal, a
damaged file, a crashed worker) gets its reason and the others go on. A rerun skips the logs
whose rows exist for the same input hash, options and version. At the end batch.md and
batch.html show each log's status and, per derivative, its estimates across the flights.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from pipeline.errors import USER_ERRORS, describe
from pipeline.jobs.dask_cluster import as_finished, dask_client
from pipeline.jobs.failures import failure_recorded
from pipeline.jobs.options import EstimateOptions
from pipeline.jobs.task_rows import report_rows, write_rows
from pipeline.paths import new_run_dir, release_run_dirs, run_id

#: the results' columns, in order
COLUMNS = (
    "name",
    "log",
    "status",
    "reason",
    "method",
    "parameter",
    "estimate",
    "std",
    "total_std",
    "verdict",
    "proof_of_match",
    "log_sha256",
    "options",
    "version",
    "seconds",
)


@dataclass(frozen=True)
class BatchEntry:
    """One log of the batch: its path, its folder name under DIR, the estimate's options
    and the command line that gave them (the record's ``options``)."""

    log: str
    name: str
    options: EstimateOptions
    argv: str
    inputs: tuple[str, ...] = ()  #: the files besides the log whose contents the result depends on


@dataclass(frozen=True)
class BatchOptions:
    """Where the tasks run: ``scheduler`` (an address) or a local cluster of ``workers``;
    ``quiet``; ``version`` (the tool's, in every row)."""

    scheduler: str | None = None
    workers: int | None = None
    quiet: bool = False
    version: str = "unknown"


def file_hash(paths: Sequence[str | Path]) -> str:
    """sha256 over the files' contents, in order (a missing one counts as its name)."""
    h = hashlib.sha256()
    for p in paths:
        try:
            with open(p, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    h.update(block)
        except OSError:
            h.update(str(p).encode())
    return h.hexdigest()


def estimate_task(entry: BatchEntry, out_root: str, version: str) -> list[dict[str, Any]]:
    """Run ``fsid estimate`` on one entry into out_root/<name>/ (in a worker process); its
    rows (module docstring), one row with the reason when it fails."""
    from pipeline.jobs.estimate import estimate_log  # the numerics: in the worker

    t0 = time.perf_counter()
    out = Path(out_root) / entry.name
    base = {
        "name": entry.name,
        "log": entry.log,
        "log_sha256": file_hash([entry.log, *entry.inputs]),
        "options": entry.argv,
        "version": version,
    }
    try:
        new_run_dir("estimate", out, inputs=[entry.log, *entry.inputs])
        with failure_recorded(out, "estimate"):
            estimate_log(entry.log, out, entry.options)
        rows = report_rows(json.loads((out / "report.json").read_text()))
        status, reason = "ok", ""
    except Exception as exc:  # noqa: BLE001 - every failure of one log is that log's record
        rows, status = [], "refused" if isinstance(exc, USER_ERRORS) else "crashed"
        reason = describe(exc)
    finally:
        release_run_dirs()
    seconds = time.perf_counter() - t0
    if not rows:
        return [{**base, "status": status if status != "ok" else "no estimate", "reason": reason, "seconds": seconds}]
    return [{**base, **r, "status": status, "reason": reason, "seconds": seconds} for r in rows]


def write_results(path: Path, rows: list[dict[str, Any]]) -> pd.DataFrame:
    """results.parquet of ``rows``, by log and row (:func:`pipeline.jobs.task_rows.write_rows`)."""
    return write_rows(path, rows, COLUMNS, ("name", "method", "parameter"))


def _earlier(path: Path, entries: Sequence[BatchEntry], version: str, out: Path) -> dict[str, list[dict]]:
    """The rows of the logs a rerun skips: done ("ok") in results.parquet with the same
    input hash, options and version, their report still there."""
    if not path.exists():
        return {}
    try:
        old = pd.read_parquet(path)
    except (OSError, ValueError):
        return {}
    keep = {}
    for e in entries:
        rows = old[old["name"] == e.name]
        if rows.empty or not (rows["status"] == "ok").all() or not (out / e.name / "report.json").exists():
            continue
        r = rows.iloc[0]
        if r["options"] == e.argv and r["version"] == version and r["log_sha256"] == file_hash([e.log, *e.inputs]):
            keep[e.name] = rows.to_dict("records")
    return keep


def batch(out: str | Path, entries: Sequence[BatchEntry], opts: BatchOptions) -> dict[str, Path]:
    """Run the batch into ``out`` (module docstring); returns name -> path."""
    from pipeline.outputs.batch import write_batch_report  # matplotlib: at the end only

    out = new_run_dir("batch", out, inputs=[e.log for e in entries])
    results = out / "results.parquet"
    done = _earlier(results, entries, opts.version, out)
    rows = [r for rs in done.values() for r in rs]
    todo = [e for e in entries if e.name not in done]
    say = (lambda s: None) if opts.quiet else (lambda s: print(s, flush=True))
    if done:
        say(f"{len(done)} of {len(entries)} logs have results for the same input, options and version: skipped")
    t0, n_done, failed = time.monotonic(), 0, 0
    stopped = ""
    try:
        if todo:
            with dask_client(opts.scheduler, opts.workers) as client:
                where = opts.scheduler or f"a local cluster of {len(client.scheduler_info()['workers'])} workers"
                say(f"{len(todo)} logs on {where}")
                for entry, got, exc in as_finished(
                    client, estimate_task, todo, str(out), opts.version, key=lambda e: e.name
                ):
                    if exc is not None:
                        got = [_lost(entry, exc, opts.version)]
                    rows += got
                    write_results(results, rows)
                    n_done += 1
                    status = got[0]["status"]
                    failed += status != "ok"
                    say(_progress(n_done, len(todo), failed, time.monotonic() - t0, entry.name, status))
    except KeyboardInterrupt:
        stopped = f"interrupted (Ctrl-C) after {n_done} of {len(todo)} logs"
    df = write_results(results, rows)
    paths = write_batch_report(out, df, {"run_id": run_id(out), "entries": len(entries), "stopped": stopped})
    if stopped:
        raise KeyboardInterrupt
    return {"results.parquet": results, **{n: out / p for n, p in paths.items()}}


def _lost(entry: BatchEntry, exc: BaseException, version: str) -> dict[str, Any]:
    """The record of a task that never returned (its worker died, more than once)."""
    return {
        "name": entry.name,
        "log": entry.log,
        "status": "crashed",
        "reason": f"the task did not finish: {type(exc).__name__}: {exc}",
        "log_sha256": file_hash([entry.log, *entry.inputs]),
        "options": entry.argv,
        "version": version,
    }


def _progress(k: int, n: int, failed: int, elapsed: float, name: str, status: str) -> str:
    """``[k/n] name: status (f failed) ETA m:ss``: counts and the time left at the pace so far."""
    left = elapsed / k * (n - k) if k else 0.0
    bar = "#" * int(20 * k / n) + "." * (20 - int(20 * k / n))
    fails = f", {failed} failed" if failed else ""
    return f"[{bar}] {k}/{n}{fails}  {name}: {status}  left {int(left // 60)}:{int(left % 60):02d}"
