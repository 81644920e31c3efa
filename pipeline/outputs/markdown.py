"""Markdown building blocks of report.md: text from data, table cells and tables."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from pipeline.errors import visible

#: the characters that would make text from a log or a file into Markdown or HTML syntax
#: (links, images, tags, table cells), written as character references: renderers show the
#: characters, and no link, image or tag comes of them
_MD_SPECIAL = {"&": "&amp;", "<": "&lt;", ">": "&gt;", "[": "&#91;", "]": "&#93;", "|": "&#124;", "`": "&#96;"}


def md_text(x: Any) -> str:
    """``x`` as text safe to put into report.md: Markdown and HTML syntax characters as
    character references, control characters as escapes
    (:func:`pipeline.errors.visible`). For everything that comes from data or
    configuration: log paths, aircraft, flight-mode, channel and parameter names."""
    text = visible(str(x)).replace("\n", " ")
    return "".join(_MD_SPECIAL.get(c, c) for c in text)


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


def one_line(text: Any) -> str:
    """A reason for a table cell: one line, no table bars, at most 200 characters."""
    s = " ".join(str(text or "").split()).replace("|", "/")
    return s if len(s) <= 200 else s[:199] + "..."
