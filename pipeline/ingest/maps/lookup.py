"""Finding a map source (``MESSAGE.field``) among a log's raw tables."""

from __future__ import annotations

import numpy as np

from pipeline.ingest.rawlog import RawLog, Table


def split_source(source: str) -> tuple[str, str]:
    if "." not in source:
        return source, ""
    msg, fld = source.split(".", 1)
    return msg, fld


def find_table(raw: RawLog, msg: str) -> Table | None:
    if msg in raw.tables:
        return raw.tables[msg]
    if msg.startswith("@"):  # by schema name (MCAP)
        schema = msg[1:]
        for tab in raw.tables.values():
            if tab.units.get("__schema__") == schema:
                return tab
        return None
    if msg.endswith("[0]"):  # instance 0 of a log that does not split instances
        return raw.tables.get(msg[:-3])
    if msg.endswith("]"):
        return None
    inst0 = f"{msg}[0]"
    return raw.tables.get(inst0)


def lookup(raw: RawLog, source: str) -> tuple[Table, np.ndarray] | str:
    msg, fld = split_source(source)
    tab = find_table(raw, msg)
    if tab is None:
        return f"no {msg} messages"
    if len(tab) == 0:
        return f"{msg} has no samples"
    if fld not in tab:
        return f"{msg} has no field {fld}"
    return tab, np.asarray(tab[fld], dtype=np.float64)


def onto(t: np.ndarray, got: tuple[Table, np.ndarray], source: str) -> np.ndarray | str:
    """The values of a looked-up source ``got`` (its table, values) interpolated onto the
    times ``t`` (non-finite samples left out), or why not."""
    tb, vb = got
    tb_t = np.asarray(tb.t, dtype=float)
    ok = np.isfinite(tb_t) & np.isfinite(vb)
    if not ok.any():
        return f"{source} has no finite samples"
    order = np.argsort(tb_t[ok], kind="stable")
    return np.interp(t, tb_t[ok][order], np.asarray(vb, dtype=float)[ok][order])
