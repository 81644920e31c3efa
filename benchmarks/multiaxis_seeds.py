"""The closed loop of tests/test_closed_loop_multiaxis.py over many seeds: for each seed
``fsid run scenarios/multiaxis_multisine_turbulence.toml`` (JSBSim flight in light Tustin
turbulence, three simultaneous 3-axis multisines and an elevator sweep, logs written and
read back, no compatibility stage as in the test) with FEM, EKF and UKF on both axes.

The test holds one seed (31); this shows how typical it is. Per method (axis-method):
  * per seed, the worst |error| / reported std over the derivatives, and in how many
    seeds every derivative is within 3 std (the test's criterion);
  * over the seeds, per derivative: empirical std / mean reported std (1 = honest) and
    bias = (mean - truth) / empirical std (the band of the mean of n seeds is
    +-2/sqrt(n)).
The last line: the share of (seed, method) fits with every derivative within 3 std.

    python benchmarks/multiaxis_seeds.py [--seeds 8] [--seed-base 31] [--jobs 2]
        [--methods fem,ekf,ukf] [--scenario path.toml (a variant of the scenario)]
"""
from __future__ import annotations

import functools
import json
import sys
import tempfile
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _montecarlo import fly, scatter_table, seed_arguments  # noqa: E402

SCENARIO = ROOT / "scenarios" / "multiaxis_multisine_turbulence.toml"
METHODS = "fem,ekf,ukf"


def one_seed(seed: int, methods: str = METHODS, scenario: str = str(SCENARIO)) -> list[dict]:
    from pipeline.run import run_scenario

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        run_scenario(scenario, out, seed=seed, methods=methods.split(","), quiet=True, compat=False)
        rep = json.loads((out / "report.json").read_text())
    rows = []
    for key, m in rep["methods"].items():
        for name, p in m["parameters"].items():
            if p.get("truth") is None or p.get("std") is None:
                continue
            rows.append({"seed": seed, "method": key, "parameter": name, "estimate": p["estimate"],
                         "truth": p["truth"], "reported": p["std"],
                         "err": abs(p["error_in_std"]), "converged": m["converged"]})
    return rows


def main() -> float:
    seeds, jobs, opts = seed_arguments(__doc__.split("\n\n")[0], 8, 31,
                                       {"methods": METHODS, "scenario": str(SCENARIO)})
    print(f"{Path(opts['scenario']).name}, seeds {seeds[0]}-{seeds[-1]}")
    df = fly(functools.partial(one_seed, methods=opts["methods"], scenario=opts["scenario"]), seeds, jobs)
    worst = df.groupby(["method", "seed"])["err"].max().unstack("seed")
    which = df.loc[df.groupby(["method", "seed"])["err"].idxmax()].set_index(["method", "seed"])["parameter"]
    print("worst |error| / reported std per seed (the derivative):")
    for method, row in worst.iterrows():
        cells = [f"{row[s]:5.1f} {which[(method, s)]:<10s}" for s in worst.columns]
        ok = int((row <= 3.0).sum())
        print(f"  {method:18s} within 3 std in {ok}/{len(row)} seeds | " + " ".join(cells))
    print("\nover the seeds, per derivative:")
    scatter_table(df, ["method", "parameter"], {"reported": "reported"})
    share = float((worst <= 3.0).to_numpy().mean())
    print(f"\nfits with every derivative within 3 std: {int((worst <= 3.0).to_numpy().sum())}"
          f"/{worst.size} = {share:.2f}")
    return share


if __name__ == "__main__":
    pd.set_option("display.width", 140)
    main()
