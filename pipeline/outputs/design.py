"""What ``fsid design`` writes besides design.json: the inputs as CSV (rad and deg), a figure
of their time histories and spectra, and report.md/html with the predicted accuracy."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from pipeline.outputs.figures.refs import make
from pipeline.outputs.figures.style import panel_grid, top_legend
from pipeline.outputs.html import write_html
from pipeline.outputs.lua_player import player_script
from pipeline.outputs.markdown import cell, table
from pipeline.paths import atomic_write_text


def _draw(fig: Figure, U: pd.DataFrame) -> None:
    """One row per input: its time history (deg) and its amplitude spectrum (its harmonics
    marked), so that the split of the band and the orthogonality show."""
    ax = panel_grid(fig, len(U.columns), 2)
    t = U.index.to_numpy()
    for row, name in enumerate(U.columns):
        u = np.degrees(U[name].to_numpy())
        ax[row, 0].plot(t, u, lw=1.0, color="k", label="input")
        ax[row, 0].set_ylabel(f"{name} [deg]")
        n = t.size - 1
        spec = np.abs(np.fft.rfft(u[:-1])) * 2 / n
        f = np.fft.rfftfreq(n, t[1] - t[0])
        ax[row, 1].vlines(f, 0, spec, lw=1.2, color="k")
        harm = np.asarray(U.attrs["frequencies"][name])
        ax[row, 1].plot(harm, np.interp(harm, f, spec), "o", ms=3, color="tab:orange", label="its harmonics")
        ax[row, 1].set_xlim(0, 1.3 * max(max(v) for v in U.attrs["frequencies"].values()))
        ax[row, 1].set_ylabel(f"{name} amplitude [deg]")
        ax[row, 0].set_title(f"{name}: RPF {U.attrs['rpf'][name]:.3f}", fontsize=9)
    ax[-1, 0].set_xlabel("time [s]")
    ax[-1, 1].set_xlabel("frequency [Hz]")
    h, lab = ax[0, 1].get_legend_handles_labels()
    top_legend(fig, h, lab, "designed inputs: mutually orthogonal multisines")


def _markdown(doc: dict[str, Any], fig: Any) -> str:
    L = [
        f"# Input design: {', '.join(doc['inputs'])}",
        "",
        f"Run {doc['run_id']}. Aircraft {doc['aircraft']}; {doc['duration_s']:g} s at {doc['rate_hz']:g} Hz, band "
        f"{doc['band_hz'][0]:g}-{doc['band_hz'][1]:g} Hz, harmonics of 1/{doc['duration_s']:g} s split among the "
        "inputs (mutually orthogonal), phases for a low relative peak factor, each input starting and ending at zero.",
        "",
    ]
    rows = [
        [u, f"{np.degrees(doc['amplitude_rad'][u]):.3g}", str(len(doc["frequencies_hz"][u])), f"{doc['rpf'][u]:.3f}"]
        for u in doc["inputs"]
    ]
    L += table(["input", "peak (deg)", "harmonics", "RPF"], rows)
    tr = doc["trim"]
    L += [
        "",
        "## Predicted accuracy",
        "",
        f"One flight of these inputs from trim at {tr['speed_mps']:g} m/s and {tr['altitude_m']:g} m "
        f"(rho {tr['rho_kgm3']:.4g} kg/m^3); derivatives from {doc['apriori_from']}; the simulated sensors' default "
        "noise. Cramér-Rao std: what output error on such a flight would state (fly it more than once to see the "
        "scatter; turbulence and model error add to it).",
        "",
    ]
    if doc.get("previous_log"):
        L += [
            f"With the previous flight {doc['previous_log']}: its output-error std of each derivative both fits "
            "share, and the std of both flights together (their information added); the gain is how many times "
            "smaller the std gets." + (f" {doc['previous_note']}." if doc.get("previous_note") else ""),
            "",
        ]
    for axis, d in doc["predicted"].items():
        prev = "previous" in d
        rows = [
            [n, f"{p['value']:.4g}", cell(p["std"], ".3g"), cell(p["rel_std_pct"], ".1f")]
            + (
                [cell(p.get("previous_std"), ".3g"), cell(p.get("combined_std"), ".3g"), cell(p.get("gain"), ".2f")]
                if prev
                else []
            )
            for n, p in d["parameters"].items()
        ]
        head = ["derivative", "assumed value", "predicted std", "rel. std %"]
        head += ["previous flight std", "both flights std", "gain"] if prev else []
        L += [f"### {axis} ({d['model']} model; outputs {', '.join(d['outputs'])})", ""]
        L += table(head, rows) + [""]
    pl = doc["player"]
    L += [
        "## Flying it",
        "",
        f"`{pl['file']}`: an ArduPilot Lua script (copy it to the autopilot's `APM/scripts/`, set `SCR_ENABLE = 1`) "
        f"that adds these inputs to the surface outputs while the RC switch with `RCx_OPTION = {pl['switch_option']}` "
        f"is high. Surface travel at full servo throw: "
        + ", ".join(f"{u} {d:g} deg" for u, d in pl["travel_deg"].items())
        + f" ({pl['travel_from']}). It stops when the switch goes low, when |bank| > {pl['roll_limit_deg']:g} deg or "
        f"|pitch| > {pl['pitch_limit_deg']:g} deg, and at the end; it needs one output per surface (no elevon or "
        "V-tail mixing) and clamps every pulse to the servo's MIN/MAX.",
        "",
    ]
    L += [*fig.markdown()] if fig is not None else []
    return "\n".join(L) + "\n"


def write_design(folder: Path, U: pd.DataFrame, doc: dict[str, Any]) -> dict[str, str]:
    """inputs.csv, the Lua player (doc["player"]["file"]), figures/inputs.png, report.md,
    report.html into ``folder``; returns name -> path relative to it."""
    csv = U.copy()
    for c in U.columns:
        csv[f"{c}_deg"] = np.degrees(U[c])
    atomic_write_text(folder / "inputs.csv", csv.reset_index().to_csv(index=False, float_format="%.9g"))
    (folder / "figures").mkdir(exist_ok=True)
    fig = make(
        folder / "figures",
        "inputs",
        "design",
        "the designed inputs and their spectra",
        (9.0, 1.0 + 1.8 * len(U.columns)),
        lambda f: _draw(f, U),
    )
    pl = doc["player"]
    atomic_write_text(folder / pl["file"], player_script(U, pl["travel_deg"], tuple(doc["band_hz"])))
    atomic_write_text(folder / "report.md", _markdown(doc, fig))
    write_html(folder / "report.html", folder / "report.md")
    out = {"inputs.csv": "inputs.csv", pl["file"]: pl["file"], "report.md": "report.md", "report.html": "report.html"}
    if fig.path:
        out["inputs.png"] = fig.path
    return out
