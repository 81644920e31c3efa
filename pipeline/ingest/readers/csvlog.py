"""CSV / ASCII column files.

The whole file becomes one table named ``csv``. Its time column is the map's
``[map] time_column`` (default ``t``; else the first of ``time``, ``timestamp``,
``time_s``) times ``[map] time_scale`` (default 1, i.e. seconds). Delimiter is sniffed
(comma, semicolon, tab, whitespace); lines starting with ``#`` are comments.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from pipeline.ingest.rawlog import Damage, LogReadError, RawLog, Table

TIME_NAMES = ("t", "time", "timestamp", "time_s", "Time", "TIME")


def read_csv(
    path: str | os.PathLike, *, strict: bool = False, time_column: str | None = None, time_scale: float = 1.0
) -> RawLog:
    """Read a column file into the table ``csv`` (see module docstring)."""
    path = Path(path)
    try:
        text = path.read_bytes()
    except OSError as exc:
        raise LogReadError.cannot_open(path, exc) from None
    try:
        s = text.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise LogReadError(
            f"{path}: not a text file (byte {exc.start} is not UTF-8); is it a binary log with a wrong extension?",
            path=str(path),
            offset=exc.start,
            where=f"byte {exc.start}",
        ) from None
    lines = [ln for ln in s.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if len(lines) < 2:
        raise LogReadError(
            f"{path}: needs a header line and at least one data line", path=str(path), offset=0, where="line 1"
        )
    head = lines[0]
    sep = "," if "," in head else ";" if ";" in head else "\t" if "\t" in head else r"\s+"
    names = [c.strip() for c in (head.split() if sep == r"\s+" else head.split(sep))]
    ncol = len(names)
    good: list[list[float]] = []
    damage = None
    for k, ln in enumerate(lines[1:], start=2):
        parts = ln.split() if sep == r"\s+" else ln.split(sep)
        try:
            if len(parts) != ncol:
                raise ValueError(f"{len(parts)} fields, header has {ncol}")
            good.append([float(p) if p.strip() else np.nan for p in parts])
        except ValueError as exc:
            off = s.find(ln)
            damage = Damage(
                off,
                f"data line {k}",
                f"line {k} unreadable ({exc}); kept the lines before it",
                len(good),
                len(s) - max(off, 0),
            )
            if strict:
                raise LogReadError(
                    f"{path}: {damage.message}", path=str(path), offset=off, where=damage.where
                ) from None
            break
    if not good:
        raise LogReadError(f"{path}: no numeric data lines under the header", path=str(path), offset=0, where="line 2")
    arr = np.asarray(good, dtype=np.float64)
    cols = {n: arr[:, j] for j, n in enumerate(names)}
    tcol = time_column or next((n for n in TIME_NAMES if n in cols), None)
    if tcol is None or tcol not in cols:
        raise LogReadError(
            f"{path}: no time column (looked for {time_column or ', '.join(TIME_NAMES)}); name it in the map's [map] time_column",
            path=str(path),
            offset=0,
            where="header line",
        )
    t = cols[tcol] * float(time_scale)
    return RawLog(
        {"csv": Table("csv", t, cols)},
        "csv",
        {},
        [],
        f"column '{tcol}' x {time_scale:g}, in s",
        damage,
        {"columns": names},
    )
