"""What ``fsid live`` shows and writes: the estimates each second on the terminal (and the
moment a derivative's std falls below the target: "Cmq: enough"), the same as scalar series
in a rerun recording (a live viewer, and live.rrd), and at the end live.json (the final
estimates, each derivative's history, the run's facts), live.csv (the history) and
report.md / report.html."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pipeline.outputs.html import write_html
from pipeline.outputs.markdown import cell, table
from pipeline.paths import atomic_write_text
from pipeline.validation.json_values import num

Estimates = Mapping[str, Mapping[str, Mapping[str, float]]]


def status_lines(t: float, est: Estimates) -> list[str]:
    """One line per equation: ``t  Cm  Cmalpha -0.380 +- 0.010 ...`` (derivatives, not the
    trim terms; "ok" after a derivative that is enough)."""
    lines = []
    for eq, d in est.items():
        parts = [
            f"{p} {v['value']:+.4g} +- {v['std']:.2g}{' ok' if np.isfinite(v['enough']) else ''}"
            for p, v in d.items()
            if not p.endswith("0")
        ]
        lines.append(f"{t:8.1f} s  {eq:3s} " + "   ".join(parts))
    return lines


def enough_events(est: Estimates, said: set[str], target: float) -> list[str]:
    """Lines for the derivatives that became enough since the last call (``said`` updated)."""
    out = []
    for d in est.values():
        for p, v in d.items():
            if np.isfinite(v["enough"]) and p not in said:
                said.add(p)
                out.append(f"{v['enough']:8.1f} s  {p}: enough (std {100 * v['rel_std']:.1f} % < {100 * target:g} %)")
    return out


class LiveRecording:
    """The estimates as rerun scalar series (value, value +- 2 std) on the flight's time, in
    ``path`` and optionally a viewer spawned now."""

    def __init__(self, path: Path, spawn: bool = False, recording_id: str | None = None) -> None:
        import rerun as rr

        self.rr = rr
        self.path = path
        self.rec = rr.RecordingStream("fsid", recording_id=recording_id)
        self.rec.save(str(path))
        if spawn:
            self.rec.spawn(connect=True)
        self.rec.send_recording_name("fsid live")

    def log(self, t: float, est: Estimates) -> None:
        rr = self.rr
        self.rec.set_time("flight_time", duration=float(t))
        for eq, d in est.items():
            for p, v in d.items():
                lo, hi = v["value"] - 2 * v["std"], v["value"] + 2 * v["std"]
                self.rec.log(f"live/{eq}/{p}", rr.Scalars([v["value"], lo, hi]))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()


def history_frame(history: list[tuple[float, Estimates]]) -> pd.DataFrame:
    """The estimates over time, one row per time, equation and parameter."""
    rows = [
        {"t": t, "equation": eq, "parameter": p, "value": v["value"], "std": v["std"]}
        for t, est in history
        for eq, d in est.items()
        for p, v in d.items()
    ]
    return pd.DataFrame(rows, columns=["t", "equation", "parameter", "value", "std"])


def write_live(out: Path, doc: dict[str, Any], history: list[tuple[float, Estimates]]) -> dict[str, str]:
    """live.csv, report.md, report.html and live.json (last) into ``out``; returns name ->
    path relative to it."""
    hist = history_frame(history)
    atomic_write_text(out / "live.csv", hist.to_csv(index=False, float_format="%.9g"))
    atomic_write_text(out / "report.md", _markdown(doc))
    write_html(out / "report.html", out / "report.md")
    atomic_write_text(out / "live.json", json.dumps(_jsonable(doc), indent=1, allow_nan=False))
    return {"live.csv": "live.csv", "report.md": "report.md", "report.html": "report.html", "live.json": "live.json"}


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return num(float(x))
    return x


def _markdown(doc: Mapping[str, Any]) -> str:
    L = [
        "# Identification while flying",
        "",
        f"Run {doc['run_id']}. Source {doc['source']}; {doc['duration_s']:.1f} s of flight, "
        f"{doc['rows']} equation rows; frequency-domain equation error on {doc['band_hz'][0]:g}-"
        f"{doc['band_hz'][1]:g} Hz ({doc['n_frequencies']} frequencies), updated on the samples' own times. "
        f"Stopped: {doc['stopped']}.",
        "",
    ]
    if doc.get("received"):
        L += [
            f"Everything received is in `{doc['received']}` ({doc['packets']} packets): `fsid estimate` reads it.",
            "",
        ]
    if not doc["final"]:
        L += ["No equation had enough data for an estimate: fly maneuvers (designed inputs: `fsid design`).", ""]
    for eq, d in doc["final"].items():
        rows = [
            [p, f"{v['value']:.5g}", cell(v["std"], ".3g"), cell(100 * v["rel_std"], ".1f"), cell(v["enough"], ".1f")]
            for p, v in d.items()
        ]
        L += [f"## {eq}", ""]
        L += table(
            ["parameter", "estimate", "std", "rel. std %", f"enough at (s; std < {100 * doc['target']:g} %)"], rows
        )
        L += [""]
    L += [
        "The std is the regression's Cramér-Rao bound; the equations neglect the thrust, the inertia coupling "
        "and the IMU's position, so use these for the flight's progress and `fsid estimate` on the recorded log "
        "for the model."
    ]
    return "\n".join(L) + "\n"
