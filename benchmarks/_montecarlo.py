"""The Monte Carlo harness of the benchmarks that fly a scenario once per seed: the seed
arguments, the flights in a process pool, and the table that compares the scatter of the
estimates over the seeds with the std the product reported."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import pandas as pd


def seed_arguments(description: str, seeds: int, seed_base: int, options: Mapping[str, str] | None = None):
    """(seeds, jobs) from ``--seeds N --seed-base B --jobs J`` (defaults: ``seeds``,
    ``seed_base``, 2 jobs); with ``options`` (``--name`` -> default text) also a dict of
    those options' values: (seeds, jobs, options)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--seeds", type=int, default=seeds)
    ap.add_argument("--seed-base", type=int, default=seed_base)
    ap.add_argument("--jobs", type=int, default=2)
    for name, default in (options or {}).items():
        ap.add_argument(f"--{name}", default=default)
    args = ap.parse_args()
    out = list(range(args.seed_base, args.seed_base + args.seeds)), args.jobs
    if options is None:
        return out
    return (*out, {name: getattr(args, name.replace("-", "_")) for name in options})


def judged_parameters(report: Mapping) -> Iterator[tuple[str, str, dict, dict]]:
    """(method key, parameter name, parameter entry, method entry) of a report.json for
    every parameter with a truth and a std (what a Monte Carlo over seeds compares)."""
    for key, m in report["methods"].items():
        for name, p in m["parameters"].items():
            if p.get("truth") is not None and p.get("std") is not None:
                yield key, name, p, m


def fly(one_flight: Callable[[int], list[dict]], seeds: Sequence[int], jobs: int) -> pd.DataFrame:
    """The rows of ``one_flight(seed)`` for every seed, ``jobs`` flights at a time."""
    with ProcessPoolExecutor(max_workers=jobs) as ex:
        return pd.DataFrame([r for rows in ex.map(one_flight, seeds) for r in rows])


def scatter_table(df: pd.DataFrame, by: Sequence[str], stds: Mapping[str, str]) -> pd.DataFrame:
    """Per group ``by`` (of rows with ``estimate`` and ``truth``): ``emp_std`` (the
    estimates' std over the seeds), for each ``column: std_column`` of ``stds`` the ratio
    emp_std / mean of that std column (1 = honest), ``bias`` ((mean - truth) / emp_std)
    and ``n``. Printed, and returned."""
    g = df.groupby(list(by), sort=False)
    emp = g["estimate"].std(ddof=1)
    tab = pd.DataFrame(
        {
            "emp_std": emp,
            **{k: emp / g[c].mean() for k, c in stds.items()},
            "bias": (g["estimate"].mean() - g["truth"].first()) / emp,
            "n": g["estimate"].count(),
        }
    )
    with pd.option_context("display.width", 120, "display.max_rows", 200):
        print(tab.round(3).to_string())
    return tab


def range_line(tab: pd.DataFrame, group: str, extra: Mapping[str, str] | None = None) -> str:
    """One group of :func:`scatter_table`: the range of its ``reported`` ratio over the
    parameters, of each ``extra`` ratio column (column -> label) in brackets, and its
    largest |bias|."""
    t = tab.loc[group]
    more = ", ".join(f"{label} {t[c].min():.2f}-{t[c].max():.2f}" for c, label in (extra or {}).items())
    return (
        f"{group}: empirical std / reported std {t['reported'].min():.2f}-{t['reported'].max():.2f}"
        + (f" ({more})" if more else "")
        + f"; |bias| <= {t['bias'].abs().max():.2f} empirical std"
    )


def flown_problem(workdir: Path, axis: str, **kw) -> tuple[Any, dict]:
    """(the multi-axis ``axis`` problem with the gust states, the truth document) of the
    flight written into ``workdir`` (flight.mcap, truth.json): linear inputs, the log's
    noise levels attached; ``kw`` go to pipeline.problems.multiaxis.multiaxis_problem."""
    import json

    from pipeline.ingest.constants import AircraftConstants
    from pipeline.ingest.readers import read_log
    from pipeline.methods.noise import attach_logged_noise
    from pipeline.problems import multiaxis_problem

    truth_doc = json.loads((Path(workdir) / "truth.json").read_text())
    fd = read_log(Path(workdir) / "flight.mcap")
    pb = multiaxis_problem(fd, AircraftConstants.from_truth(truth_doc), axis, gust_states=True, **kw)
    pb.inputs = "linear"
    attach_logged_noise(fd, pb)
    return pb, truth_doc
