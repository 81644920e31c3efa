"""The campaign's report (campaign.md, campaign.html, figures/): per variant, method and
parameter the bias, the empirical std over the reported std and the coverage of +-2 total
std, with the flights that failed and why."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from pipeline.outputs.figures.refs import make
from pipeline.outputs.html import write_html
from pipeline.outputs.markdown import cell, one_line, table
from pipeline.paths import atomic_write_text

#: the empirical / reported std band read as honest (the benchmarks' goal)
HONEST = (0.8, 1.25)


def _draw(fig: Figure, s: pd.DataFrame) -> None:
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    params = list(dict.fromkeys(s["parameter"]))
    variants = list(dict.fromkeys(s["variant"]))
    w = 0.8 / max(len(variants), 1)
    x = np.arange(len(params))
    for k, v in enumerate(variants):
        d = s[s["variant"] == v].set_index("parameter").reindex(params)
        ax1.bar(x + k * w, d["empirical_over_reported"], w, label=v)
        ax2.bar(x + k * w, 100 * d["coverage_2std"], w)
    ax1.axhspan(*HONEST, color="0.85", zorder=0)
    ax1.axhline(1.0, color="k", lw=0.8)
    ax1.set_ylabel("empirical / reported std")
    ax2.axhline(95.4, color="k", lw=0.8)
    ax2.set_ylabel("coverage of +-2 std (%)")
    ax2.set_xticks(x + w * (len(variants) - 1) / 2)
    ax2.set_xticklabels(params, rotation=60, ha="right", fontsize=8)
    if len(variants) > 1:
        ax1.legend(fontsize=7, loc="upper right")


def write_campaign_report(out: Path, df: pd.DataFrame, s: pd.DataFrame, facts: dict[str, Any]) -> dict[str, str]:
    """campaign.md, campaign.html and figures/campaign_*.png into ``out``; returns name ->
    path relative to it."""
    (out / "figures").mkdir(exist_ok=True)
    flights = df.groupby(["variant", "seed"]).first().reset_index()
    failed = flights[flights["status"] != "ok"]
    L = [
        "# Monte Carlo campaign",
        "",
        f"Run {facts['run_id']}. Scenario {facts['scenario']}; {len(facts['variants'])} variant(s) x "
        f"{len(facts['seeds'])} seeds = {facts['flights']} flights, {len(flights)} done, {len(failed)} failed."
        + (f" Stopped: {facts['stopped']}." if facts.get("stopped") else ""),
        "",
        "Per variant, method and parameter: the bias of the estimates in their empirical std, the empirical std "
        f"over the mean std the product reported (1: honest; {HONEST[0]}-{HONEST[1]} is the goal), and how often "
        "the truth lies within estimate +- 2 total std (95.4 % for honest Gaussian bounds).",
        "",
    ]
    paths = {}
    for (v, m), g in s.groupby(["variant", "method"], sort=True) if not s.empty else []:
        L += [f"## {v}: {m}", ""]
        L += table(
            ["parameter", "flights", "bias / emp. std", "emp. / reported std", "coverage +-2 std"],
            [
                [p, str(n), cell(b, "+.2f"), cell(r, ".2f"), f"{100 * c:.0f} %"]
                for p, n, b, r, c in g[
                    ["parameter", "flights", "bias_in_std", "empirical_over_reported", "coverage_2std"]
                ].itertuples(index=False)
            ],
        )
    for m, g in s.groupby("method", sort=True) if not s.empty else []:
        name = f"campaign_{m}"
        fig = make(
            out / "figures",
            name,
            "campaign",
            f"{m}: empirical / reported std and coverage per parameter",
            (10.0, 6.0),
            lambda f, g=g: _draw(f, g),
        )
        L += [*fig.markdown(), ""]
        if fig.path:
            paths[f"{name}.png"] = fig.path
    if len(failed):
        L += ["## Failed flights", ""]
        L += table(
            ["variant", "seed", "status", "reason"],
            [
                [v, str(sd), st, one_line(r)]
                for v, sd, st, r in failed[["variant", "seed", "status", "reason"]].itertuples(index=False)
            ],
        )
    atomic_write_text(out / "campaign.md", "\n".join(L) + "\n")
    write_html(out / "campaign.html", out / "campaign.md")
    return {"campaign.md": "campaign.md", "campaign.html": "campaign.html", **paths}
