"""A figure of report.md as the report sees it: the section it belongs to, its caption and
its PNG file, or the one line saying why it was not drawn."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from matplotlib.figure import Figure

from pipeline.outputs.figures.style import render, save

#: the sections of a method's part of report.md that carry figures, in report order
SECTIONS = ("parameters", "fit", "modes", "proof_of_match", "frequency")

log = logging.getLogger(__name__)


class NotDrawn(Exception):
    """The data a figure needs are missing (the message says which)."""


@dataclass(frozen=True)
class FigureRef:
    """One figure: ``section`` (one of :data:`SECTIONS`), ``caption``, ``path`` of the PNG
    relative to report.md (POSIX), or ``note``: why it was not drawn (``path`` None)."""

    section: str
    caption: str
    path: str | None = None
    note: str = ""

    def markdown(self) -> list[str]:
        """The report.md lines: the image with its caption, or the skip note."""
        if self.path:
            return [f"![{self.caption}]({self.path})", ""]
        return [f"Figure not drawn ({self.caption}): {self.note}.", ""]


def make(
    folder: Path, name: str, section: str, caption: str, size: tuple[float, float], draw: Callable[[Figure], None]
) -> FigureRef:
    """Render ``draw`` to ``folder/name.png`` and return its reference; a figure whose data
    are missing (:class:`NotDrawn`) or whose drawing fails is skipped with a note, so a
    figure never costs the report."""
    try:
        png = render(size, draw)
    except NotDrawn as exc:
        return FigureRef(section, caption, note=str(exc))
    except Exception as exc:  # noqa: BLE001 - a figure is never worth the report
        log.warning("figure %s not drawn", name, exc_info=True)
        return FigureRef(section, caption, note=f"{type(exc).__name__}: {exc}")
    save(folder / f"{name}.png", png)
    return FigureRef(section, caption, path=f"{folder.name}/{name}.png")
