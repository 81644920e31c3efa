"""``fsid fields``: what a log holds and what a channel map makes of it.

The first thing to run on a log the built-in map does not fully understand: every message
table with its sample count, rate and fields, each field that fills a canonical channel
marked with that channel, then the canonical channels the map could not fill and why. A
user map (``--map my.toml``, ``[map] extends = "<built-in>"``) then names the missing
sources; docs/channel-maps.md describes the format.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.conditioning.checks import CORE
from pipeline.ingest.flightdata import CANONICAL_UNITS
from pipeline.ingest.maps import apply_map, load_map
from pipeline.ingest.maps.loading import builtin_names
from pipeline.ingest.rawlog import RawLog, Table
from pipeline.ingest.readers import detect_format, read_raw
from pipeline.ingest.sampling import sample_rate

#: why a channel identification needs is missing when the map has no rule for it
NOT_MAPPED = "not in the channel map (fill it from a field with a map of your own, below)"


@dataclass
class TableFields:
    """One message table of a log: ``samples``, ``rate_hz`` of its stamps (the rule of every
    rate fsid states, :func:`pipeline.ingest.sampling.sample_rate`), and its
    ``fields`` with the canonical channel each one fills ("" when none)."""

    name: str
    samples: int
    rate_hz: float
    fields: dict[str, str] = field(default_factory=dict)


@dataclass
class LogFields:
    """A log's tables and what the channel map ``map_name`` makes of them: ``filled``
    canonical channel -> (source field, unit, notes), ``unfilled`` channel -> reason."""

    path: str
    format: str
    map_name: str
    tables: list[TableFields]
    filled: dict[str, tuple[str, str, str]]
    unfilled: dict[str, str]

    def as_dict(self) -> dict:
        """The JSON form (``fsid fields --json``)."""
        return {
            "path": self.path,
            "format": self.format,
            "map": self.map_name,
            "tables": [
                {"name": t.name, "samples": t.samples, "rate_hz": t.rate_hz, "fields": t.fields} for t in self.tables
            ],
            "channels": {k: {"source": s, "unit": u, "notes": n} for k, (s, u, n) in self.filled.items()},
            "unfilled": self.unfilled,
        }


#: a ``TABLE.field`` reference inside a channel's source text (``IMU[0].GyrX``,
#: ``quat_wxyz(vehicle_attitude.q[0], ...)``, ``RCOU.C2 (SERVO2: ...)``)
_FIELD_REF = re.compile(r"([A-Za-z_/][\w/\[\]]*)\.([A-Za-z_][\w\[\]]*)")


def _field_refs(source: str) -> list[tuple[str, str]]:
    """The (table, field) pairs a channel's source text names."""
    return _FIELD_REF.findall(source)


def _match_table(raw: RawLog, source_table: str) -> str | None:
    """The raw table a channel's source names (exact, or the one instance ``IMU`` of ``IMU[0]``)."""
    if source_table in raw.tables:
        return source_table
    base = source_table.split("[")[0]
    for name in raw.tables:
        if name.split("[")[0] == base:
            return name
    return None


def list_fields(log: str | Path, map_spec: str | None = None, **read_opts) -> LogFields:
    """Read ``log`` with its reader (``read_opts``: e.g. ``time_base``) and map it with
    ``map_spec`` (None: the built-in map for its format) into a :class:`LogFields`."""
    fmt = detect_format(log)
    raw = read_raw(log, fmt, **read_opts)
    hint = raw.info.get("map_hint", raw.format)
    cmap = (
        load_map(map_spec, raw.format) if map_spec else load_map(hint if hint in builtin_names() else None, raw.format)
    )
    chans, why, _ = apply_map(raw, cmap)
    tables = {name: _table_fields(name, tab) for name, tab in raw.tables.items()}
    filled: dict[str, tuple[str, str, str]] = {}
    for name, ch in chans.items():
        filled[name] = (ch.source, ch.unit, ch.notes)
        for tname, fname in _field_refs(ch.source):
            hit = _match_table(raw, tname)
            if hit is not None and fname in tables[hit].fields:
                tables[hit].fields[fname] = "+".join(filter(None, [tables[hit].fields[fname], name]))
    unfilled = {n: NOT_MAPPED for n in CORE if n not in filled} | dict(why)
    return LogFields(str(log), raw.format, cmap.name, list(tables.values()), filled, unfilled)


def _table_fields(name: str, tab: Table) -> TableFields:
    return TableFields(name, len(tab), round(sample_rate(tab.t), 3), {f: "" for f in tab.fields})


def format_fields(lf: LogFields, *, all_fields: bool = True) -> str:
    """The text ``fsid fields`` prints: one block per table (fields filling a canonical
    channel shown as ``field -> channel``), then the canonical channels filled and those
    the map could not fill with the reason. ``all_fields`` False lists only the tables
    that fill a channel."""
    lines = [f"{lf.path}: {lf.format} log, {len(lf.tables)} tables; map {lf.map_name}", ""]
    for t in sorted(lf.tables, key=lambda t: t.name):
        used = {f: c for f, c in t.fields.items() if c}
        if not all_fields and not used:
            continue
        lines.append(f"{t.name}  ({t.samples} samples, {t.rate_hz:g} Hz)")
        shown = [f"{f} -> {c}" if c else f for f, c in t.fields.items()]
        lines.extend(_wrap(shown, indent="  "))
    lines += ["", f"canonical channels filled ({len(lf.filled)}):"]
    for name in sorted(lf.filled, key=_canonical_order):
        src, unit, notes = lf.filled[name]
        lines.append(f"  {name:<9} {unit:<7} <- {src}" + (f"  ({notes})" if notes else ""))
    if lf.unfilled:
        lines += ["", f"not filled by the map ({len(lf.unfilled)}):"]
        for name in sorted(lf.unfilled, key=_canonical_order):
            lines.append(f"  {name:<9} {lf.unfilled[name]}")
    lines += [
        "",
        "to fill a channel from another field: a map TOML with [map] extends = "
        f'"{lf.map_name.split("+")[0]}" and [channels.NAME] source = "TABLE.field", unit = "..." '
        "(docs/channel-maps.md), then --map it in check and estimate",
    ]
    return "\n".join(lines)


def _canonical_order(name: str) -> tuple[int, str]:
    order = list(CANONICAL_UNITS)
    return (order.index(name) if name in order else len(order), name)


def _wrap(items: list[str], indent: str, width: int = 100) -> list[str]:
    out, line = [], indent
    for it in items:
        if len(line) + len(it) + 2 > width and line.strip():
            out.append(line.rstrip(", "))
            line = indent
        line += it + ", "
    if line.strip():
        out.append(line.rstrip(", "))
    return out


def fields_json(lf: LogFields) -> str:
    return json.dumps(lf.as_dict(), indent=1)
