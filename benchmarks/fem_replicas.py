"""Filter error on simulated replicas of the reference software's three filter-error cases:
does it recover the truth, and is its Cramér-Rao bound honest?

Per seed, each replica (:mod:`estimators.replicas`: HFB-320 longitudinal with process noise
on V, alpha, theta, q; the linear lateral case with process noise on p and r; the unstable
short period with process noise on w and q and az computed from w, q, de) is flown with the
reference's estimates as truth and fitted by ``FilterError`` from the reference's start
values with default options (the reference's criterion: diagonal R). Printed per parameter:
the estimates' scatter over the seeds against the mean reported std (``scatter/CRB``, 1 =
honest), the bias in scatter units, and per case the seeds whose every derivative lies
within 3 std of the truth and the seeds whose process noise does; the last line is the
range of scatter/CRB over the derivatives (goal: inside [0.7, 1.4]). ``--full-R`` fits the
full-R likelihood instead (refused on the unstable case, whose az is a function of w, q
and de).

Measured on 2026-12-02, 10 seeds (``--seeds 10 --jobs 1``), the reference's criterion:
every derivative within 3 std on 10/10 seeds (HFB-320), 9/10 (lateral), 8/10 (unstable),
converged 30/30; scatter/CRB over the 31 derivatives 0.33-1.30 (median 0.81: the diagonal
R's bounds are conservative where the innovations correlate); the process noise is
biased low where they correlate (bias/scatter: lateral F_p -10.3, unstable F_w -10.0,
HFB-320 F_alpha -4.0), no seed has every F within 3 std. Before (2026-11-27, full R,
discrete gain, 40 seeds): 39/40 and 38/40 seeds within 3 std, F included, scatter/CRB
0.82-1.29.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimators import EstimationError, FilterError  # noqa: E402
from estimators.replicas import REPLICA_CASES as CASES  # noqa: E402


def one(args: tuple[str, int, bool]) -> list[dict]:
    case, seed, full = args
    if full and case == "unstable":  # az is a function of w, q, de: the full R is refused
        return []
    make, f_start = CASES[case]
    ex = make(seed)
    truth = {**ex.truth, **{f"F_{s}": ex.process_noise[i, i] for i, s in enumerate(ex.model.states)}}
    try:
        res = FilterError(ex.model, process_noise=f_start, full_R=full).fit(ex.segments)
    except EstimationError as exc:
        return [{"case": case, "seed": seed, "name": "(failed)", "error": str(exc)[:80]}]
    return [
        {
            "case": case,
            "seed": seed,
            "name": n,
            "estimate": float(res.params[n]),
            "std": float(res.std[n]),
            "truth": v,
            "converged": res.converged,
            "iterations": res.iterations,
        }
        for n, v in truth.items()
        if n in res.free_names
    ]


def main() -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--full-R", action="store_true")
    a = ap.parse_args()
    jobs = [(c, s, a.full_R) for c in CASES for s in range(a.seeds)]
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        df = pd.DataFrame([r for rows in ex.map(one, jobs) for r in rows])
    failed = df[df["name"] == "(failed)"]
    if len(failed):
        print(f"{len(failed)} fits raised EstimationError:\n{failed[['case', 'seed', 'error']]}")
    df = df[df["name"] != "(failed)"]
    df["off"] = (df["estimate"] - df["truth"]).abs() / df["std"]
    g = df.groupby(["case", "name"], sort=False)
    emp = g["estimate"].std(ddof=1)
    tab = pd.DataFrame(
        {
            "truth": g["truth"].first(),
            "mean_std": g["std"].mean(),
            "emp_std": emp,
            "scatter/CRB": emp / g["std"].mean(),
            "bias/scatter": (g["estimate"].mean() - g["truth"].first()) / emp,
        }
    )
    with pd.option_context("display.width", 140, "display.max_rows", 200):
        print(tab.round(4).to_string())
    df["noise"] = df["name"].str.startswith("F_")
    for case, d in df.groupby("case"):
        per_seed = d[~d["noise"]].groupby("seed")
        within = (per_seed["off"].max() < 3.0).sum()
        f_within = (d[d["noise"]].groupby("seed")["off"].max() < 3.0).sum()
        conv = per_seed["converged"].all().sum()
        print(
            f"{case}: every derivative within 3 std on {within}/{per_seed.ngroups} seeds, the process "
            f"noise on {f_within}/{per_seed.ngroups}; converged {conv}/{per_seed.ngroups}; iterations "
            f"median {per_seed['iterations'].first().median():.0f}"
        )
    bias = tab.index.get_level_values("name").str.match(r"^B[XY]\d")
    b = tab["scatter/CRB"][bias]
    if len(b):
        print(f"the {len(b)} lateral biases: scatter/CRB {b.min():.2f}-{b.max():.2f}")
    noise = tab.index.get_level_values("name").str.startswith("F_")
    f = tab["bias/scatter"][noise]
    print(f"the {len(f)} process noises: bias/scatter {f.min():.2f} to {f.max():.2f}")
    r = tab["scatter/CRB"][~bias & ~noise]
    print(
        f"scatter/CRB over the {len(r)} derivatives: min {r.min():.2f}, "
        f"median {r.median():.2f}, max {r.max():.2f} ({r.idxmax()[0]} {r.idxmax()[1]}); "
        "goal [0.7, 1.4]"
    )
    return float(r.max())


if __name__ == "__main__":
    main()
