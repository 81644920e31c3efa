"""The batch's report (batch.md, batch.html, figures/): each log's status and reason, and per
method and derivative the estimates across the flights with their +-2 total std, so that a
trend or a jump shows at a glance; an estimate far outside the others' spread is flagged."""

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

#: an estimate further than this many combined std from the median of the others is flagged
OUTLIER_K = 3.0
#: at most this many derivatives per figure
PER_FIGURE = 12


def outliers(df: pd.DataFrame) -> pd.DataFrame:
    """The (method, parameter, log) rows whose estimate is more than OUTLIER_K combined std
    from the median over the logs, the combined std being the row's total std and the
    flights' spread (1.4826 x the median absolute deviation, at least the median total
    std); with three logs or more."""
    ok = df[(df["status"] == "ok") & df["estimate"].notna()]
    flagged = []
    for (_, _), g in ok.groupby(["method", "parameter"]):
        if len(g) < 3:
            continue
        est, std = g["estimate"].to_numpy(), g["total_std"].to_numpy()
        med = np.median(est)
        spread = max(1.4826 * np.median(np.abs(est - med)), float(np.nanmedian(std)))
        z = np.abs(est - med) / np.sqrt(spread**2 + np.nan_to_num(std) ** 2)
        flagged.append(g[z > OUTLIER_K].assign(z=z[z > OUTLIER_K], median=med))
    return pd.concat(flagged) if flagged else ok.iloc[0:0].assign(z=[], median=[])


def _draw(fig: Figure, g: pd.DataFrame, params: list[str], logs: list[str], flagged: pd.DataFrame) -> None:
    n = len(params)
    cols = min(3, n)
    rows = int(np.ceil(n / cols))
    axes = fig.subplots(rows, cols, squeeze=False)
    x_of = {name: i for i, name in enumerate(logs)}
    for ax, p in zip(axes.flat, params):
        d = g[g["parameter"] == p]
        x = np.array([x_of[n] for n in d["name"]])
        ax.errorbar(x, d["estimate"], yerr=2 * d["total_std"], fmt="o", ms=4, capsize=2, color="tab:blue")
        f = flagged[flagged["parameter"] == p]
        if len(f):
            ax.plot([x_of[n] for n in f["name"]], f["estimate"], "o", ms=9, mfc="none", mec="tab:red", label="outlier")
        ax.set_title(p, fontsize=9)
        ax.set_xticks(range(len(logs)))
        ax.set_xticklabels(logs if len(logs) <= 12 else [""] * len(logs), rotation=60, fontsize=7, ha="right")
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)


def write_batch_report(out: Path, df: pd.DataFrame, facts: dict[str, Any]) -> dict[str, str]:
    """batch.md, batch.html and figures/batch_*.png into ``out``; returns name -> path
    relative to it."""
    (out / "figures").mkdir(exist_ok=True)
    per_log = df.groupby("name", sort=True).first().reset_index()
    logs = list(per_log["name"])
    flagged = outliers(df)
    ok = int((per_log["status"] == "ok").sum())
    L = [
        "# Batch",
        "",
        f"Run {facts['run_id']}. {len(per_log)} of {facts['entries']} logs have a record, {ok} estimated, "
        f"{len(per_log) - ok} not (their reasons below; each log's own report and error.txt are in its folder)."
        + (f" Stopped: {facts['stopped']}." if facts.get("stopped") else ""),
        "",
        "## Logs",
        "",
    ]
    L += table(
        ["log", "status", "reason", "seconds"],
        [
            [f"[{n}]({n}/{'report.md' if s == 'ok' else 'error.txt'})", s, one_line(r), cell(t, ".1f")]
            for n, s, r, t in per_log[["name", "status", "reason", "seconds"]].itertuples(index=False)
        ],
    )
    L += ["## Outliers", ""]
    if flagged.empty:
        L += [f"No estimate is more than {OUTLIER_K:g} combined std from the others' median.", ""]
    else:
        L += table(
            ["log", "method", "parameter", "estimate", "total std", "median of the logs", "z"],
            [
                [n, m, p, cell(e, ".5g"), cell(s, ".3g"), cell(med, ".5g"), cell(z, ".1f")]
                for n, m, p, e, s, med, z in flagged[
                    ["name", "method", "parameter", "estimate", "total_std", "median", "z"]
                ].itertuples(index=False)
            ],
        )
    paths = {}
    est = df[(df["status"] == "ok") & df["estimate"].notna()]
    for method, g in est.groupby("method", sort=True):
        params = list(dict.fromkeys(g["parameter"]))
        for k in range(0, len(params), PER_FIGURE):
            chunk = params[k : k + PER_FIGURE]
            name = f"batch_{method}_{k // PER_FIGURE + 1}"
            rows = int(np.ceil(len(chunk) / 3))
            fig = make(
                out / "figures",
                name,
                "batch",
                f"{method}: each log's estimate +- 2 total std (red rings: outliers)",
                (10.0, 1.0 + 2.2 * rows),
                lambda f, g=g, chunk=chunk, mine=flagged[flagged["method"] == method]: _draw(f, g, chunk, logs, mine),
            )
            L += [f"## {method}" if k == 0 else "", "", *fig.markdown(), ""]
            if fig.path:
                paths[f"{name}.png"] = fig.path
    atomic_write_text(out / "batch.md", "\n".join(L) + "\n")
    write_html(out / "batch.html", out / "batch.md")
    return {"batch.md": "batch.md", "batch.html": "batch.html", **paths}
