"""Output folders and atomic writes shared by every command that writes."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path


def new_run_dir(kind: str, out: str | os.PathLike | None = None) -> Path:
    """Return the output folder: ``out`` when given, else a new ``./runs/<kind>-<stamp>``."""
    if out is not None:
        path = Path(out)
    else:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = Path("runs") / f"{kind}-{stamp}"
        n = 1
        while path.exists():
            n += 1
            path = Path("runs") / f"{kind}-{stamp}-{n}"
    path.mkdir(parents=True, exist_ok=True)
    return path


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
