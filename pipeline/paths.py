"""Output folders and atomic writes shared by every command that writes."""

from __future__ import annotations

import atexit
import os
import secrets
import shutil
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from pipeline.errors import FsidError

#: what fsid's commands write into an output folder besides logs: an earlier run's are
#: removed when a new run takes the folder, so it never holds two runs' files side by side
RUN_OUTPUTS = (
    "report.json",
    "report.md",
    "report.html",
    "run.rrd",
    "check.rrd",
    "checks.json",
    "canonical.csv",
    "figures",
    "error.txt",
    "INTERRUPTED.txt",
)
#: the flight logs ``fsid simulate`` writes: never written over without ``--force``
LOG_OUTPUTS = ("flight.mcap", "flight.bin", "validation.mcap", "validation.bin", "truth.json")
#: the file that marks an output folder as taken by a running fsid (its process id, command
#: and run id)
LOCK = ".fsid.lock"

#: output folder (resolved) -> the id of the run this process is writing into it
_RUN_IDS: dict[Path, str] = {}


def run_id(out: str | os.PathLike) -> str | None:
    """The id of this process's run into the output folder ``out`` (None: no run took it):
    stamped on every file of the run so that files of two runs are never taken for one set."""
    return _RUN_IDS.get(Path(out).resolve())


def new_run_dir(
    kind: str,
    out: str | os.PathLike | None = None,
    *,
    inputs: Sequence[str | os.PathLike | None] = (),
    logs: bool = False,
    force: bool = False,
) -> Path:
    """The output folder, ready before any work: ``out`` when given, else a new
    ``./runs/<kind>-<stamp>``; created and checked writable, locked for this process (a
    second fsid is refused naming the one holding it; a lock whose process is gone is
    taken over), and cleared of an earlier run's files (RUN_OUTPUTS, hidden temporary
    files) other than this run's ``inputs`` (paths; None and paths that do not exist, such
    as a built-in map's name, are skipped). ``logs``: the run writes LOG_OUTPUTS, refused
    where they exist unless ``force``. The run gets a new id (:func:`run_id`). Every refusal
    is an FsidError saying what to do."""
    if out is not None:
        path = Path(out)
    else:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = Path("runs") / f"{kind}-{stamp}"
        n = 1
        while path.exists():
            n += 1
            path = Path("runs") / f"{kind}-{stamp}-{n}"
    if path.exists() and not path.is_dir():
        raise FsidError(f"--out {path} is a file, not a folder: give a folder for the results")
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=path, prefix=".fsid-probe.")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise FsidError(
            f"cannot write into the output folder {path} ({exc.strerror or exc}): give a writable folder with --out"
        ) from None
    mine = {Path(p).resolve() for p in inputs if p and Path(p).exists()}
    written = RUN_OUTPUTS + (LOG_OUTPUTS if logs else ())
    clash = [n for n in written if (path / n).resolve() in mine]
    if clash:
        raise FsidError(f"--out {path} would write over this run's input {path / clash[0]}: give another output folder")
    if logs and not force:
        there = [n for n in LOG_OUTPUTS if (path / n).exists()]
        if there:
            raise FsidError(f"{path} already holds {', '.join(there)}: give another --out, or --force to replace them")
    rid = _RUN_IDS.get(path.resolve())  # a stage of this process's run (fsid run's simulate)
    if rid is None:
        rid = f"{kind}-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}-{secrets.token_hex(4)}"
        _lock(path, f"{kind} {rid}")
        _clear(path, mine)
        _RUN_IDS[path.resolve()] = rid
    return path


def release_run_dirs() -> None:
    """Unlock the output folders this process took and forget their run ids: the end of a
    command (a process that exits is released anyway)."""
    for path in list(_RUN_IDS):
        _unlock(path / LOCK, os.getpid())
    _RUN_IDS.clear()


def _lock(path: Path, kind: str) -> None:
    """Take ``path``'s LOCK for this process (released at exit), or FsidError naming the
    live fsid that holds it."""
    lock = path / LOCK
    for _ in range(3):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                pid_text, _, what = lock.read_text().partition(" ")
                pid = int(pid_text)
            except (OSError, ValueError):
                pid, what = -1, ""
            if pid == os.getpid():  # this process's own earlier run into the folder
                lock.write_text(f"{pid} fsid {kind}\n")
                return
            if pid > 0 and _alive(pid):
                raise FsidError(
                    f"{path} is in use by another fsid ({what.strip() or 'a run'}, process {pid}): wait for it "
                    "to finish, or give another --out"
                ) from None
            try:
                lock.unlink()  # its process is gone (killed): the lock is stale
            except FileNotFoundError:
                pass
            continue
        with os.fdopen(fd, "w") as fh:
            fh.write(f"{os.getpid()} fsid {kind}\n")
        atexit.register(_unlock, lock, os.getpid())
        return
    raise FsidError(f"could not take the output folder {path}: another fsid keeps taking it; give another --out")


def _alive(pid: int) -> bool:
    """Whether process ``pid`` still runs: a zombie (killed, not yet reaped by its parent:
    a Dask worker killed under its nanny) holds no folder."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as fh:
            return fh.read().rsplit(")", 1)[-1].split()[0] != "Z"
    except OSError:  # no /proc (macOS, Windows): kill(pid, 0) is all there is
        return True


def _unlock(lock: Path, pid: int) -> None:
    try:
        if lock.read_text().split(" ")[0] == str(pid):
            lock.unlink()
    except (OSError, ValueError):
        pass


def _clear(path: Path, keep: set[Path]) -> None:
    """Remove an earlier run's outputs (RUN_OUTPUTS) and hidden temporary files from
    ``path``, except the paths in ``keep`` (this run's inputs)."""
    for p in [path / n for n in RUN_OUTPUTS] + list(path.glob(".*.tmp")) + list(path.glob(STAGE + "*")):
        if p.resolve() in keep or not (p.exists() or p.is_symlink()):
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)


#: prefix of the hidden folder a run's files are written into before they are published
STAGE = ".fsid-stage."


@contextmanager
def staged(out: str | os.PathLike, last: str) -> Iterator[Path]:
    """A hidden folder inside ``out`` to write a set of files into; on leaving, every file
    and folder written there is moved into ``out``, ``last`` (the file that says the set is
    complete, e.g. report.json) after all the others. A reader of ``out`` never meets a
    complete-looking partial set: a run killed while writing leaves only the hidden folder
    (cleared by the next run); one stopped by an exception publishes what it wrote without
    ``last`` unless ``last`` was written, and says so in error.txt."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(dir=out, prefix=STAGE))
    try:
        yield stage
    finally:
        names = sorted((p.name for p in stage.iterdir() if not p.name.startswith(".")), key=lambda n: n == last)
        for n in names:
            if (out / n).is_dir() and not (out / n).is_symlink():
                shutil.rmtree(out / n)
            os.replace(stage / n, out / n)
        shutil.rmtree(stage, ignore_errors=True)


def _umask() -> int:
    """The process's file-creation mask (read by setting it and putting it back)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _publish(tmp: str | os.PathLike, path: Path) -> None:
    """Give the temporary file the mode a plain ``open`` would (0666 less the umask, so
    0644 by default: a team folder can read it; mkstemp makes 0600) and rename it onto
    ``path``."""
    os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename,
    so a reader never sees a half-written file. The file is readable by others (0644 under
    the usual umask)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        _publish(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


class atomic_path:
    """Context manager yielding a temporary path next to ``path``; renamed onto ``path``
    on success (with :func:`atomic_write_bytes`' mode), removed on failure. For writers that
    need a file name (mcap, rerun)."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=f".{self.path.name}.", suffix=".tmp")
        os.close(fd)
        self.tmp = Path(tmp)

    def __enter__(self) -> Path:
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            _publish(self.tmp, self.path)
        elif self.tmp.exists():
            self.tmp.unlink()
