"""A job's failure written where its outputs go: error.txt (what failed, the files left) or
INTERRUPTED.txt (Ctrl-C, SIGTERM), so that an output folder never stays unexplained. Used by
every command and by the batch's tasks, which run the same jobs in worker processes."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pipeline.errors import Terminated, describe
from pipeline.jobs.progress import where_stopped
from pipeline.paths import atomic_write_text, run_id

#: the files :func:`failure_recorded` writes
MARKERS = ("error.txt", "INTERRUPTED.txt")


@contextmanager
def failure_recorded(out: Path, command: str) -> Iterator[None]:
    """Run a job writing into ``out``; when it fails, ``out/error.txt`` says what failed
    (the same message the command line prints: what, where, what to do) and which files
    the job left there, so a folder never stays empty or unexplained; an interruption
    leaves ``INTERRUPTED.txt`` naming the stage and the partial files. The error goes on."""
    try:
        yield
    except KeyboardInterrupt as exc:
        where = where_stopped()
        how = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted (Ctrl-C)"
        atomic_write_text(
            out / "INTERRUPTED.txt",
            f"fsid {command} was {how}{' ' + where if where else ''}; "
            + _partial(out, "these files are partial, not a result", "nothing else was written"),
        )
        raise
    except Exception as exc:
        try:
            atomic_write_text(
                out / "error.txt",
                f"fsid {command} failed: {describe(exc)}\n"
                + _partial(out, "files left here (partial, not a result)", "no other output was written"),
            )
        except OSError:  # the disk that failed the run fails this too: the terminal says it
            pass
        raise


def _partial(out: Path, some: str, none: str) -> str:
    """The line naming the files a stopped job left in ``out`` (its markers and
    temporary files left out)."""
    left = sorted(p.name for p in out.iterdir() if not p.name.startswith(".") and p.name not in MARKERS)
    rid = run_id(out)
    return (f"{some}: {', '.join(left)}\n" if left else f"{none}\n") + (f"run_id: {rid}\n" if rid else "")
