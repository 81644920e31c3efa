"""What ``fsid response`` writes: the responses as CSV, a Bode figure with coherence and the
random error's band (and a fitted transfer function's response), report.md/html and the
rerun recording (magnitude, phase and coherence per pair on a ``frequency`` timeline, mHz)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from estimators import FrequencyResponse
from pipeline.outputs.figures.refs import make
from pipeline.outputs.figures.style import (
    MEASURED,
    bode_axes,
    grid_size,
    panel_grid,
    scale_label,
    top_legend,
    unit_text,
)
from pipeline.outputs.html import write_html
from pipeline.outputs.markdown import table
from pipeline.paths import atomic_write_text

#: the fit's colour
FIT_COLOUR = "tab:orange"


def _gain(o: str, i: str) -> float:
    """Display units per display unit of a pair (deg/s per deg, g per deg)."""
    return scale_label(o)[0] / scale_label(i)[0]


def response_frame(fr: FrequencyResponse) -> pd.DataFrame:
    """One row per frequency: per pair magnitude (dB, display units), phase (deg),
    coherence, random error; per output the multiple coherence."""
    cols: dict[str, np.ndarray] = {"f_hz": fr.f}
    for k, o in enumerate(fr.outputs):
        for u in fr.inputs:
            p = fr.pair(o, u)
            key = f"{o}/{u}"
            cols[f"{key} magnitude_db"] = p["magnitude_db"].to_numpy() + 20 * np.log10(_gain(o, u))
            cols[f"{key} phase_deg"] = p["phase_deg"].to_numpy()
            cols[f"{key} coherence"] = p["coherence"].to_numpy()
            cols[f"{key} random_error"] = p["random_error"].to_numpy()
        cols[f"{o} multiple_coherence"] = fr.multiple_coherence[:, k]
    return pd.DataFrame(cols)


def _draw(fig: Figure, fr: FrequencyResponse, fits: Mapping[str, Mapping[str, Any]]) -> None:
    """Rows: output/input pairs; columns: magnitude with the random error's +-1 band, phase,
    coherence (partial with several inputs) and the output's multiple coherence."""
    pairs = [(o, u) for o in fr.outputs for u in fr.inputs]
    ax = panel_grid(fig, len(pairs), 3)
    for row, (o, u) in enumerate(pairs):
        p = fr.pair(o, u)
        g = 20 * np.log10(_gain(o, u))
        mag, ph, eps = p["magnitude_db"].to_numpy() + g, p["phase_deg"].to_numpy(), p["random_error"].to_numpy()
        ax[row, 0].plot(fr.f, mag, color=MEASURED, lw=1.1, label="data")
        with np.errstate(invalid="ignore", divide="ignore"):
            lo, hi = mag + 20 * np.log10(np.clip(1 - eps, 1e-3, None)), mag + 20 * np.log10(1 + eps)
        ax[row, 0].fill_between(fr.f, lo, hi, color=MEASURED, alpha=0.15, lw=0, label="random error (1 std)")
        ax[row, 1].plot(fr.f, ph, color=MEASURED, lw=1.1, label="data")
        ax[row, 1].fill_between(fr.f, ph - np.degrees(eps), ph + np.degrees(eps), color=MEASURED, alpha=0.15, lw=0)
        fit = fits.get(f"{o}/{u}") or {}
        if "H" in fit:
            H = np.asarray(fit["H"]) * _gain(o, u)
            fph = np.degrees(np.unwrap(np.angle(H)))
            fph += 360.0 * np.round((np.nanmedian(ph - fph)) / 360.0)  # on the data's branch
            ax[row, 0].plot(fr.f, 20 * np.log10(np.abs(H)), color=FIT_COLOUR, ls="--", lw=1.3, label="fit")
            ax[row, 1].plot(fr.f, fph, color=FIT_COLOUR, ls="--", lw=1.3, label="fit")
            for a in ax[row, :2]:
                a.axvspan(*fit["band_hz"], color=FIT_COLOUR, alpha=0.06, lw=0)
        ax[row, 2].plot(fr.f, p["coherence"], color=MEASURED, lw=1.1, label="coherence")
        k = fr.outputs.index(o)
        if len(fr.inputs) > 1:
            ax[row, 2].plot(
                fr.f, fr.multiple_coherence[:, k], color="0.55", lw=0.9, ls="--", label="multiple coherence"
            )
        ax[row, 2].set_ylim(0.0, 1.05)
        ax[row, 0].set_ylabel(f"{o}/{u} [dB]\n({unit_text(o)} per {unit_text(u)})")
        # the pair is named once, on the magnitude; the other columns' titles say what they
        # hold, so their labels stay short and clear of the panel to their left
        ax[row, 1].set_ylabel("deg")
        ax[row, 2].set_ylabel("")
    bode_axes(ax)
    handles, labels = [], []
    for a in (ax[0, 0], ax[0, 2]):
        h, lab = a.get_legend_handles_labels()
        handles += h
        labels += lab
    top_legend(
        fig,
        handles,
        labels,
        "frequency responses" + (" (each input's conditioned on the others)" if len(fr.inputs) > 1 else ""),
    )


def _markdown(fr: FrequencyResponse, fits: Mapping[str, Mapping[str, Any]], meta: Mapping[str, Any], fig: Any) -> str:
    L = [
        f"# Frequency responses: {meta['log']}",
        "",
        f"Run {meta['run_id']}. {', '.join(fr.outputs)} to {', '.join(fr.inputs)} over {meta['windows']}: "
        f"{len(meta['stretches'])} stretch{'es' if len(meta['stretches']) != 1 else ''}, {meta['seconds']:.1f} s at {meta['rate_hz']:g} Hz; "
        f"{fr.f.size} frequencies {fr.f[0]:.3g}-{fr.f[-1]:.3g} Hz, Hann windows of {fr.windows.min():.3g}-"
        f"{fr.windows.max():.3g} s combined (composite)"
        + ("; each input's response conditioned on the others (partial coherence)" if len(fr.inputs) > 1 else "")
        + ".",
        "",
        "Coherence says where the data hold a linear response (>= 0.6 is the usual threshold); the random error is "
        "the normalised std of |H| (of the phase in rad), from the coherence and the number of averages.",
        "",
    ]
    rows = []
    for o in fr.outputs:
        for u in fr.inputs:
            c = fr.pair(o, u)["coherence"].to_numpy()
            good = fr.f[c >= 0.6]
            rows.append(
                [
                    f"{o}/{u}",
                    f"{good.min():.3g}-{good.max():.3g}" if good.size else "-",
                    f"{np.mean(c >= 0.6):.0%}",
                    f"{np.nanmax(c):.2f}",
                ]
            )
    L += table(["pair", "coherent band (Hz)", "share of frequencies coherent", "max coherence"], rows)
    if fits:
        L += ["", "## Transfer-function fits", ""]
        frows = []
        for k, v in fits.items():
            if "error" in v:
                frows.append([k, "-", "-", v["error"]])
                continue
            ps = ", ".join(f"{n} {d['estimate']:.4g} +- {d['std']:.2g}" for n, d in v["parameters"].items())
            loes = v.get("loes")
            if loes:
                ps += (
                    f"; LOES: omega_sp {loes['omega_sp']:.3g} rad/s, zeta_sp {loes['zeta_sp']:.3g}, "
                    f"1/T_theta2 {loes['one_over_T_theta2']:.3g} 1/s, tau {loes['tau']:.3g} s"
                )
            frows.append([k, f"{v['band_hz'][0]:.3g}-{v['band_hz'][1]:.3g}", f"{v['J']:.3g}", ps])
        L += table(["pair", "band (Hz)", "cost J (<= 100 acceptable)", "parameters (SI: per rad, s)"], frows)
    L += ["", *fig.markdown()] if fig is not None else []
    return "\n".join(L) + "\n"


def _recording(
    path: Path, fr: FrequencyResponse, fits: Mapping[str, Mapping[str, Any]], recording_id: str | None
) -> None:
    from pipeline.outputs.recording import open_recording
    from pipeline.outputs.recording_layout import entity_part
    from pipeline.outputs.recording_series import SeriesWriter

    fm = np.round(fr.f * 1000.0).astype(np.int64)
    with open_recording(path, "fsid", recording_id) as rec:
        w = SeriesWriter(rec, [])
        w.text("/README", __doc__ or "")
        for o in fr.outputs:
            for u in fr.inputs:
                p, base = fr.pair(o, u), f"/response/{entity_part(o)}/{entity_part(u)}"
                g = 20 * np.log10(_gain(o, u))
                kw = {"sequence": fm, "timeline": "frequency"}
                w.series(f"{base}/magnitude_db", p["magnitude_db"] + g, name=f"{o}/{u} [dB]", color=(40, 40, 40), **kw)
                w.series(f"{base}/phase_deg", p["phase_deg"], name=f"{o}/{u} phase [deg]", color=(40, 40, 40), **kw)
                w.series(f"{base}/coherence", p["coherence"], name=f"{o}/{u} coherence", color=(90, 90, 90), **kw)
                fit = fits.get(f"{o}/{u}") or {}
                if "H" in fit:
                    H = np.asarray(fit["H"]) * _gain(o, u)
                    w.series(f"{base}/fit_db", 20 * np.log10(np.abs(H)), name="fit [dB]", color=(255, 127, 14), **kw)


def write_response(
    folder: Path,
    fr: FrequencyResponse,
    fits: Mapping[str, Mapping[str, Any]],
    meta: Mapping[str, Any],
    *,
    figures: bool = True,
    recording_id: str | None = None,
) -> dict[str, str]:
    """response.csv, figures/bode.png, report.md, report.html and run.rrd into ``folder``;
    returns name -> path relative to it."""
    atomic_write_text(folder / "response.csv", response_frame(fr).to_csv(index=False, float_format="%.6g"))
    fig = None
    if figures:
        (folder / "figures").mkdir(exist_ok=True)
        n = len(fr.outputs) * len(fr.inputs)
        fig = make(
            folder / "figures",
            "bode",
            "response",
            "frequency responses with the random error's band and coherence" + (", and the fits" if fits else ""),
            grid_size(n, 1.15),
            lambda f: _draw(f, fr, fits),
        )
    atomic_write_text(folder / "report.md", _markdown(fr, fits, meta, fig))
    write_html(folder / "report.html", folder / "report.md")
    _recording(folder / "run.rrd", fr, fits, recording_id)
    out = {"response.csv": "response.csv", "report.md": "report.md", "report.html": "report.html", "run.rrd": "run.rrd"}
    if fig is not None and fig.path:
        out["bode.png"] = fig.path
    return out
