"""Markdown building blocks of report.md: table cells and tables."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def cell(x: Any, fmt: str = ".4g") -> str:
    """A number for a table cell; '-' for missing/NaN."""
    if x is None or isinstance(x, str):
        return x or "-"
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    x = float(x)
    return format(x, fmt) if math.isfinite(x) else "-"


def table(head: list[str], rows: list[list[str]]) -> list[str]:
    """The lines of a Markdown table with header ``head`` and one line per row, then a blank."""
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out + [""]
