"""Are the bounds honest after the sensor corrections? A Monte Carlo over flights of
scenarios/sensor_errors_calm.toml (IMU and air-data biases, scale factors, a 40 ms air-data
delay): for each seed JSBSim flies it, the product writes and reads flight.mcap, the
compatibility stage removes the significant sensor errors, output error fits both axes, and
the applied corrections' uncertainty is carried to the derivatives
(pipeline.correction_uncertainty) - exactly ``fsid run --method oem``.

Per derivative: empirical std of the estimates over the seeds divided by the mean
Cramér-Rao std (``crb``) and by the mean total std (``total``: CRB plus the corrections'
part), and the bias (mean estimate - truth) in empirical std. Honest bounds have total ~1
(the 95 % band of a std ratio from n seeds is about +-1.4/sqrt(n)). Last line: the largest
total ratio.

Measured (seeds 500-511, 2026-11-24): empirical std / total std 0.62-1.41 over the 29
derivatives of both axes, against 0.66-5.99 for the Cramér-Rao std alone - the lateral
fit's trim CD0, CL0, Cm0 scattered 6.0, 1.6, 2.2x their CRB (conditional on the held
longitudinal estimates) and 1.13, 0.81, 0.94x their total std; longitudinal CLalpha 1.36 ->
1.10, Cmq 1.31 -> 1.13 with the sensor corrections' part; |bias| <= 1.6 empirical std. Re-measured after
the compatibility std started carrying the IMU noise (same seeds): 0.61-1.38 (CRB alone
0.66-5.97).

    python benchmarks/correction_uncertainty_mc.py [--seeds 10] [--seed-base 500] [--jobs 2]
"""
from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from _montecarlo import fly, judged_parameters, scatter_table, seed_arguments  # noqa: E402  (benchmarks/)
SCENARIO = ROOT / "scenarios" / "sensor_errors_calm.toml"


def one_flight(seed: int) -> list[dict]:
    """Rows (seed, key, parameter, estimate, std, total_std, truth) of one run."""
    from pipeline.run import run_scenario

    with tempfile.TemporaryDirectory() as tmp:
        run_scenario(SCENARIO, Path(tmp), seed=seed, methods=["oem"], quiet=True)
        rep = json.loads((Path(tmp) / "report.json").read_text())
    return [{"seed": seed, "key": key, "parameter": n, "estimate": p["estimate"], "std": p["std"],
             "total_std": p.get("total_std") or p["std"], "truth": p["truth"]}
            for key, n, p, _ in judged_parameters(rep)]


def main() -> None:
    seeds, jobs = seed_arguments(__doc__.splitlines()[0], seeds=10, seed_base=500)
    tab = scatter_table(fly(one_flight, seeds, jobs), ["key", "parameter"],
                        {"crb": "std", "total": "total_std"})
    print(f"seeds {seeds[0]}..{seeds[-1]}: empirical std / total std {tab['total'].min():.2f}-"
          f"{tab['total'].max():.2f} (CRB alone {tab['crb'].min():.2f}-{tab['crb'].max():.2f})")
    print(f"largest empirical/total std ratio: {tab['total'].max():.2f}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
