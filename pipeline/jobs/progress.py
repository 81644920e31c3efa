"""Stage-by-stage progress of a job on stderr: '[2/7] ingest flight.bin ... 1.2 s'.

A job counts its stages once, before the first one, from its plan (what it will run on
which axes and methods); a stage that only some logs need is a substage of another, so the
count holds whatever the data."""

from __future__ import annotations

import io
import sys
import time
from dataclasses import dataclass
from typing import TextIO

from pipeline.errors import Terminated, visible


@dataclass
class _Place:
    """Where this process's job stands: the last stage it started ("[n/N] text"),
    whether that stage finished, and the stream whose progress line is still open."""

    label: str = ""
    done: bool = False
    open_on: TextIO | None = None


_PLACE = _Place()


def where_stopped() -> str:
    """Where a job stopped, for an interruption or an error: "during [3/12] fly 60 s in
    JSBSim" (or "after ..." when that stage had finished); "" before any stage."""
    if not _PLACE.label:
        return ""
    return f"{'after' if _PLACE.done else 'during'} {_PLACE.label}"


def end_open_line() -> None:
    """End a progress line a failing stage left open, so that the error printed next
    stands on its own line."""
    if _PLACE.open_on is not None:
        try:
            print(file=_PLACE.open_on, flush=True)
        except (ValueError, OSError):  # that stream is closed or gone
            pass
        _PLACE.open_on = None


def _raise_if_terminated() -> None:
    """Raise the termination a callback may have swallowed (:class:`Terminated`)."""
    if Terminated.requested:
        raise Terminated()


def new_job() -> None:
    """Forget where an earlier job of this process stood (a command's start)."""
    global _PLACE
    _PLACE = _Place()
    Terminated.requested = False


class Progress:
    """Progress lines on ``stream`` (stderr): ``total`` stages, each started by
    :meth:`stage` and ended by :meth:`done` with its duration; nothing printed when
    ``quiet`` (notes written to ``stream`` by the stages still go there). ``nested``: a
    Progress run inside another's stage (a refit), which leaves :func:`where_stopped`
    to the job's own."""

    def __init__(self, total: int, stream: TextIO | None = None, quiet: bool = False, nested: bool = False) -> None:
        self.total, self.n, self.stream, self.quiet = total, 0, stream or sys.stderr, quiet
        self.nested = nested
        self.t0 = time.perf_counter()
        self._t = self.t0

    def plan(self, remaining: int) -> Progress:
        """Continue this count with a job of ``remaining`` more stages (``fsid run``: the
        flight's stages, then the estimate job's). The total was planned from the flight
        plan before the first stage; it changes only when the job counts differently."""
        self.total = self.n + remaining
        return self

    def stage(self, text: str, since: float | None = None) -> Progress:
        """Start the next stage (``since``: its start time, perf_counter, when its work ran
        before the count was known)."""
        _raise_if_terminated()
        self.n += 1
        self._t = time.perf_counter() if since is None else since
        if not self.quiet:
            print(f"[{self.n}/{self.total}] {visible(text)} ...", end="", file=self.stream, flush=True)
            _PLACE.open_on = self.stream
        if not self.nested:
            _PLACE.label, _PLACE.done = f"[{self.n}/{self.total}] {text}", False
        return self

    def substage(self, text: str) -> Progress:
        """A second part of the stage just done, on a line of its own under it (counted
        with that stage: a part that only some logs need keeps the count right)."""
        _raise_if_terminated()
        self._t = time.perf_counter()
        if not self.quiet:
            print(
                f"{' ' * (len(str(self.n)) + len(str(self.total)) + 3)} {visible(text)} ...",
                end="",
                file=self.stream,
                flush=True,
            )
            _PLACE.open_on = self.stream
        return self

    def tick(self, text: str) -> None:
        """A step within the current stage, on its line (an iteration, a refit)."""
        _raise_if_terminated()
        if not self.quiet:
            print(f" {visible(text)}", end="", file=self.stream, flush=True)

    def done(self, extra: str = "") -> None:
        """End the current stage or substage: its duration and ``extra``."""
        _raise_if_terminated()
        if not self.quiet:
            dt = time.perf_counter() - self._t
            print(f" {dt:.1f} s{(' - ' + visible(extra)) if extra else ''}", file=self.stream, flush=True)
            _PLACE.open_on = None
        if not self.nested:
            _PLACE.done = True


def quiet_progress() -> Progress:
    """A Progress that prints nothing (notes of the refits included)."""
    return Progress(1, stream=io.StringIO(), quiet=True, nested=True)


def counted(n: int, noun: str) -> str:
    """``"1 maneuver"``, ``"3 maneuvers"``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"
