"""A log as its reader decoded it, before channel mapping: the raw message tables, the
damage found, and the one error a reader raises.

Every reader (:mod:`pipeline.ingest.readers`) turns a file into ``dict[str, Table]`` (one
table per message type / topic / instance) plus metadata; :mod:`pipeline.ingest.maps` then
turns tables into canonical channels.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline.errors import FsidError

#: the time bases a format's reader offers (its ``time_base``; the first is its default)
TIME_BASES = {"tlog": ("auto", "boot", "log"), "mcap": ("auto", "header", "log")}


class LogReadError(FsidError):
    """The only error a reader raises for a bad input file.

    Attributes
    ----------
    path : str
        The file being read.
    offset : int | None
        Byte offset where the damage starts (None when not byte-addressable).
    where : str
        Human-readable location ("byte 65480, inside an IMU record", "line 12").
    partial : object | None
        What was decoded before the damage (a ``FlightData`` or raw tables) when any.
    """

    def __init__(
        self, message: str, *, path: str = "", offset: int | None = None, where: str = "", partial: Any = None
    ) -> None:
        super().__init__(message)
        self.path = path
        self.offset = offset
        self.where = where
        self.partial = partial
        self.internal = False  # True when raised by the safety net (a reader bug)

    @classmethod
    def cannot_open(cls, path, exc: OSError) -> LogReadError:
        """The error for a file the operating system will not open or read."""
        return cls(
            f"cannot read {path}: {exc.strerror}; check the path and permissions",
            path=str(path),
            offset=0,
            where="open",
        )


@dataclass
class Damage:
    """Where a file stops being readable; stored in ``FlightData.meta['damage']``.

    ``offset`` is the byte offset of the first undecodable byte, ``kept`` the number of
    records decoded before it (all of which are kept), ``skipped_bytes`` how many bytes
    the reader had to skip in total while resynchronising.
    """

    offset: int
    where: str
    message: str
    kept: int = 0
    skipped_bytes: int = 0

    def as_dict(self) -> dict:
        return {
            "offset": int(self.offset),
            "where": self.where,
            "message": self.message,
            "kept_records": int(self.kept),
            "skipped_bytes": int(self.skipped_bytes),
        }


@dataclass
class Table:
    """All samples of one message type (or topic, or instance) of a log.

    ``t`` is the time of each sample in seconds on the reader's chosen time base, shape (n,).
    Columns are 1-D numpy arrays of length n, in the log's own units (scaled by the log's
    own multipliers, e.g. DataFlash ``c`` fields divided by 100). Columns may be provided
    lazily through ``loader`` so large logs do not convert fields nobody asked for.
    """

    name: str
    t: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    loader: Callable[[str], np.ndarray] | None = None
    field_names: list[str] | None = None

    @property
    def fields(self) -> list[str]:
        if self.field_names is not None:
            return list(self.field_names)
        return list(self.columns)

    def __contains__(self, name: str) -> bool:
        return name in self.columns or (self.field_names is not None and name in self.field_names)

    def __getitem__(self, name: str) -> np.ndarray:
        if name in self.columns:
            return self.columns[name]
        if self.loader is not None and self.field_names is not None and name in self.field_names:
            col = self.loader(name)
            self.columns[name] = col
            return col
        raise KeyError(name)

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass
class RawLog:
    """What a format reader returns before channel mapping."""

    tables: dict[str, Table]
    format: str
    params: dict[str, float] = field(default_factory=dict)
    modes: list[tuple[float, str]] = field(default_factory=list)  # (t_start [s], mode name)
    time_base: str = ""
    damage: Damage | None = None
    info: dict = field(default_factory=dict)
