"""The rows batch and campaign tasks return and the parquet files they are gathered in: one
row per method and parameter of a report.json, and the table written whole, atomically, in a
fixed order each time a task finishes (a reader, or an interruption, never meets half a
file)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from pipeline.paths import atomic_path

#: the columns read as numbers (a missing value is NaN)
NUMERIC = ("estimate", "std", "total_std", "truth", "seconds")


def report_rows(rep: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One row per method and parameter of a report.json document: estimate, std, total
    std, truth (None on a real log), the fit's verdict and its proof of match."""
    rows = []
    for key, m in rep.get("methods", {}).items():
        pom = (m.get("validation") or {}).get("proof_of_match") or {}
        verdict = (m.get("verdict") or {}).get("level")
        for name, p in (m.get("parameters") or {}).items():
            rows.append(
                {
                    "method": key,
                    "parameter": name,
                    "estimate": p.get("estimate"),
                    "std": p.get("std"),
                    "total_std": p.get("total_std", p.get("std")),
                    "truth": p.get("truth"),
                    "verdict": verdict,
                    "proof_of_match": {True: "pass", False: "fail"}.get(pom.get("all_pass"), "none"),
                }
            )
    return rows


def write_rows(path: Path, rows: list[dict[str, Any]], columns: Sequence[str], order: Sequence[str]) -> pd.DataFrame:
    """``rows`` as a frame of ``columns`` (NUMERIC ones as numbers), sorted by ``order``
    (stable, missing values first), written atomically to the parquet file ``path``."""
    df = pd.DataFrame(rows, columns=list(columns))
    for c in NUMERIC:
        if c in df:
            df[c] = pd.to_numeric(df[c], errors="coerce")
    df = df.sort_values(list(order), na_position="first", kind="stable").reset_index(drop=True)
    with atomic_path(path) as tmp:
        df.to_parquet(tmp, index=False)
    return df
