"""``fsid batch LOGS... | --manifest M.csv [--aircraft A.toml] [--method ...] --out DIR
[--scheduler ADDR | --workers N]``: every log through ``fsid estimate`` as one Dask task,
results.parquet and a report across the flights. The work is :func:`pipeline.jobs.batch.batch`.

The manifest is a CSV with a ``log`` column and optional ``name`` (the log's folder under
DIR), ``aircraft``, ``map``, ``segments``, ``method`` (space-separated) and ``options`` (more
``fsid estimate`` options, as on its command line); relative paths are from the manifest's
folder. A row's values replace the command line's for that log."""

from __future__ import annotations

import argparse
import csv
import shlex
from importlib import metadata
from pathlib import Path

from pipeline.commands import estimate as estimate_command
from pipeline.commands.arguments import add_cluster_arguments, log_file, print_outputs
from pipeline.errors import FsidError
from pipeline.jobs.failures import failure_recorded
from pipeline.paths import new_run_dir
from pipeline.registry import METHODS

HELP = "estimate every log of a campaign as Dask tasks (a local cluster, or --scheduler): results.parquet, trends"

#: manifest columns and the estimate option each gives
MANIFEST_OPTIONS = {"aircraft": "--aircraft", "map": "--map", "segments": "--segments"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("logs", nargs="*", help="flight logs (or --manifest)")
    parser.add_argument("--manifest", default=None, help="CSV: log[,name,aircraft,map,segments,method,options]")
    parser.add_argument(
        "--aircraft", default=None, help="aircraft TOML for every log (a manifest row may give its own)"
    )
    parser.add_argument(
        "--method", action="append", choices=METHODS, help="estimation method (repeatable; default oem)"
    )
    parser.add_argument("--map", default=None, help="channel map for every log")
    parser.add_argument("--segments", default=None, metavar="T0:T1,...", help="windows for every log")
    parser.add_argument("--no-figures", action="store_true", help="the logs' reports without figures (faster)")
    add_cluster_arguments(parser)
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--out", default=None, help="output folder (default: a new folder under ./runs/)")


class _Parser(argparse.ArgumentParser):
    """fsid estimate's parser, whose errors name the log they are for."""

    def error(self, message: str):  # noqa: D102 - argparse's hook
        raise FsidError(f"fsid batch: {self.prog}: {message}")


def _estimate_parser(where: str) -> _Parser:
    p = _Parser(prog=where, add_help=False)
    estimate_command.add_arguments(p)
    return p


def _rows(args: argparse.Namespace) -> list[dict[str, str]]:
    """The logs and their per-log values: the command line's logs, or the manifest's rows
    (paths made relative to its folder)."""
    if args.manifest and args.logs:
        raise FsidError("fsid batch: give logs or --manifest, not both")
    if not args.manifest:
        if not args.logs:
            raise FsidError("fsid batch: give the logs (fsid batch a.bin b.bin ...) or --manifest M.csv")
        return [{"log": str(log_file(x))} for x in args.logs]
    m = Path(args.manifest)
    if not m.is_file():
        raise FsidError(f"--manifest {m} not found; give a CSV with a 'log' column")
    with open(m, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    if not rows or "log" not in rows[0]:
        raise FsidError(
            f"--manifest {m}: no 'log' column (columns: log, name, aircraft, map, segments, method, options)"
        )
    out = []
    for k, r in enumerate(rows, start=2):
        r = {c: (v or "").strip() for c, v in r.items() if c}
        for c in ("log", "aircraft", "map"):
            if r.get(c) and not Path(r[c]).is_absolute() and (m.parent / r[c]).exists():
                r[c] = str(m.parent / r[c])
        if not r.get("log"):
            raise FsidError(f"--manifest {m} line {k}: no log")
        log_file(r["log"])
        out.append(r)
    return out


def entries(args: argparse.Namespace) -> list:
    """The batch's entries: each log's estimate options, parsed by fsid estimate's own
    command line (so a batch estimates exactly as fsid estimate does)."""
    from pipeline.jobs.batch import BatchEntry

    common = []
    for opt, v in (("--aircraft", args.aircraft), ("--map", args.map), ("--segments", args.segments)):
        if v:
            common += [opt, v]
    rows = _rows(args)
    stems = [Path(r["log"]).stem for r in rows]
    out, names = [], set()
    for r in rows:
        argv = dict(zip(common[::2], common[1::2]))
        for c, opt in MANIFEST_OPTIONS.items():
            if r.get(c):
                argv[opt] = r[c]
        flat = [x for kv in argv.items() for x in kv]
        for m in r.get("method", "").split() or args.method or ["oem"]:
            flat += ["--method", m]
        flat += shlex.split(r.get("options", "")) + (["--no-figures"] if args.no_figures else []) + ["--quiet"]
        log = Path(r["log"])
        # a folder per log: its stem, with its folder's name where stems repeat (s1/flight.mcap)
        name = r.get("name") or (f"{log.parent.name}-{log.stem}" if stems.count(log.stem) > 1 else log.stem)
        base, n = name, 1
        while name in names:
            n += 1
            name = f"{base}-{n}"
        names.add(name)
        parsed = _estimate_parser(f"log {r['log']}").parse_args([r["log"], *flat])
        inputs = tuple(x for x in (parsed.aircraft, parsed.map) if x and Path(x).is_file())
        out.append(BatchEntry(r["log"], name, estimate_command.options(parsed), shlex.join(flat), inputs))
    return out


def _version() -> str:
    try:
        return metadata.version("fsid")
    except metadata.PackageNotFoundError:
        return "unknown"


def run(args: argparse.Namespace) -> int:
    from pipeline.jobs.batch import BatchOptions, batch  # dask, numerics: on use only

    items = entries(args)
    out = new_run_dir("batch", args.out, inputs=[e.log for e in items])
    opts = BatchOptions(
        scheduler=args.scheduler,
        workers=int(args.workers) if args.workers else None,
        quiet=args.quiet,
        version=_version(),
    )
    with failure_recorded(out, "batch"):
        paths = batch(out, items, opts)
    print_outputs(out, paths)
    return 0
