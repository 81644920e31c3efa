"""The ``fsid`` command line, one sub-command per module of :mod:`pipeline.commands` (demo,
simulate, check, fields, estimate, run, response, design, live, batch, campaign, view,
aircraft).

Every failure the user can act on arrives as :class:`pipeline.errors.FsidError` (or one of
the estimators' typed errors) and ends in one line on stderr and a non-zero exit, never a
traceback. Set ``FSID_DEBUG=1`` to see the traceback anyway.
"""

from __future__ import annotations

import argparse
import importlib
import io
import os
import signal
import sys
import warnings
from importlib import metadata

from pipeline.commands import COMMANDS
from pipeline.errors import USER_ERRORS, Terminated, VisibleStream, describe, is_write_failure
from pipeline.jobs.progress import end_open_line, new_job, where_stopped
from pipeline.paths import release_run_dirs


def _load(name: str):
    try:
        return importlib.import_module(f"pipeline.commands.{COMMANDS[name]}")
    except ModuleNotFoundError as exc:  # a command whose stage has not landed yet
        if exc.name and exc.name.startswith("pipeline.commands"):
            return None
        raise


def _version() -> str:
    """The installed distribution's version (the source tree's pyproject when not installed)."""
    try:
        return metadata.version("fsid")
    except metadata.PackageNotFoundError:
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fsid",
        description="Flight-vehicle system identification: flight logs in, aerodynamic derivatives with Cramér-Rao bounds out.",
    )
    parser.add_argument("--version", action="version", version=f"fsid {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        mod = _load(name)
        if mod is None:
            continue
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    previous = _on_sigterm()
    new_job()
    streams = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = VisibleStream(sys.stdout), VisibleStream(sys.stderr)
    try:
        with warnings.catch_warnings():
            # numpy's floating-point RuntimeWarnings (a NaN sample, an empty window) are
            # handled where they matter; on the command line they are noise
            warnings.simplefilter("ignore", RuntimeWarning)
            return int(args._run(args) or 0)
    except BrokenPipeError:  # the reader of our output went away (fsid fields ... | head)
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # nothing left to flush at exit
        except (OSError, ValueError, io.UnsupportedOperation):
            pass
        return 0
    except KeyboardInterrupt as exc:
        end_open_line()
        where = where_stopped()
        how = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
        print(f"fsid: {how}{' ' + where if where else ''}", file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    except Exception as exc:  # one clear line, never a traceback
        end_open_line()
        if os.environ.get("FSID_DEBUG"):
            raise
        print(f"fsid: error: {describe(exc)}", file=sys.stderr)
        if isinstance(exc, USER_ERRORS):
            return getattr(exc, "exit_code", 2)
        return 2 if is_write_failure(exc) else 1
    finally:
        sys.stdout, sys.stderr = streams
        release_run_dirs()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _terminate(signum, frame) -> None:
    Terminated.requested = True
    raise Terminated()


def _on_sigterm():
    """SIGTERM taken as an interruption (:class:`pipeline.errors.Terminated`) while a
    command runs; the handler before, or None where signals cannot be set (a thread)."""
    try:
        return signal.signal(signal.SIGTERM, _terminate)
    except ValueError:
        return None


if __name__ == "__main__":
    sys.exit(main())
