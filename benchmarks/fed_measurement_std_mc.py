"""Are the std of stabilised OEM and equation decoupling honest? A Monte Carlo over flights
of scenarios/unstable_short_period.toml (statically unstable UAV, pitch SAS, calm air): for
each seed JSBSim flies it, the product writes and reads flight.mcap and fits the
longitudinal axis with ``soem`` and ``decouple`` - exactly ``fsid run --method soem
--method decouple``. Both feed measured outputs back into the model; their reported std
carry that measurement noise (estimators.output_error.pseudo_input_noise), the Cramér-Rao bounds do not.

Per derivative: empirical std of the estimates over the seeds divided by the mean reported
std (``reported``), by the mean Cramér-Rao std (``crb``) and by the mean Morelli-Klein std
of the validation (``mk``), and the bias (mean estimate - truth) in empirical std. Honest
bounds have reported ~1 (the 95 % band of a std ratio from n seeds is about
+-1.4/sqrt(n)).

Measured (seeds 100-111, 2026-11-24):
  soem: empirical std / reported std 0.77-1.33 over the 11 derivatives (Cramér-Rao alone
        2.15-7.21: Cmalpha 7.2, Cm0 6.2, Cmde 5.9, Cmq 5.4; Morelli-Klein 1.11-1.72);
        |bias| <= 0.87 empirical std.
  decouple: 0.51-1.00 - conservative (Cramér-Rao alone 1.57-18.3, Cmq 18.3; the
        Morelli-Klein std it reported before 0.90-3.47, Cmq 3.5); |bias| <= 1.33
        empirical std (CLde, Cmalpha, CLalpha: errors in variables, the noisy alpha
        in the pitch equation, second order in the noise and not in any std).

    python benchmarks/fed_measurement_std_mc.py [--seeds 12] [--seed-base 100] [--jobs 2]
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from _montecarlo import fly, judged_parameters, range_line, scatter_table, seed_arguments  # noqa: E402  (benchmarks/)

SCENARIO = ROOT / "scenarios" / "unstable_short_period.toml"
METHODS = ["soem", "decouple"]


def one_flight(seed: int) -> list[dict]:
    """Rows (seed, method, parameter, estimate, std, crb_std, mk_std, truth) of one run."""
    from pipeline.jobs.scenario import run_scenario

    with tempfile.TemporaryDirectory() as tmp:
        run_scenario(SCENARIO, Path(tmp), seed=seed, methods=METHODS, quiet=True, compat=False)
        rep = json.loads((Path(tmp) / "report.json").read_text())
    rows = []
    for key, n, p, m in judged_parameters(rep):
        unc = (m["validation"].get("uncertainty") or {}).get("per_parameter", {}).get(n) or {}
        rows.append(
            {
                "seed": seed,
                "method": key,
                "parameter": n,
                "estimate": p["estimate"],
                "std": p["std"],
                "crb_std": unc.get("crb_std", np.nan),
                "mk_std": unc.get("mk_std", np.nan),
                "truth": p["truth"],
            }
        )
    return rows


def main() -> None:
    seeds, jobs = seed_arguments(__doc__.splitlines()[0], seeds=12, seed_base=100)
    tab = scatter_table(
        fly(one_flight, seeds, jobs), ["method", "parameter"], {"reported": "std", "crb": "crb_std", "mk": "mk_std"}
    )
    for m in METHODS:
        print(range_line(tab, m, {"crb": "Cramér-Rao", "mk": "Morelli-Klein"}))


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
