"""Are the bounds honest after the sensor corrections? A Monte Carlo over flights of
scenarios/sensor_errors_calm.toml (IMU and air-data biases, scale factors, a 40 ms air-data
delay): for each seed JSBSim flies it, the product writes and reads flight.mcap, the
compatibility stage removes the significant sensor errors, output error fits both axes, and
the applied corrections' uncertainty is carried to the derivatives
(pipeline.uncertainty.consider) - exactly ``fsid run --method oem``.

Per derivative: empirical std of the estimates over the seeds divided by the mean
Cramér-Rao std (``crb``) and by the mean total std (``total``: CRB plus the corrections'
part), and the bias (mean estimate - truth) in empirical std. Honest bounds have total ~1
(the 95 % band of a std ratio from n seeds is about +-1.4/sqrt(n)). Then the compatibility
stage itself: per sensor error, the rms and mean of (estimate - truth) / std over the seeds
(honest: rms ~1, mean ~0) and on how many flights it was applied. Last line: the largest
total ratio. ``--scenario`` flies another scenario (default.toml: error-free sensors, so
every applied correction is a false one); ``--baseline yes`` first runs the stage as it
was before it merged overlapping maneuver windows (pipeline.ingest.flightdata.merge_overlapping),
fitting the cross-controlled rudder doublets' aileron and rudder windows each.

Measured (seeds 500-511, 2026-11-24): empirical std / total std 0.62-1.41 over the 29
derivatives of both axes, against 0.66-5.99 for the Cramér-Rao std alone - the lateral
fit's trim CD0, CL0, Cm0 scattered 6.0, 1.6, 2.2x their CRB (conditional on the held
longitudinal estimates) and 1.13, 0.81, 0.94x their total std; longitudinal CLalpha 1.36 ->
1.10, Cmq 1.31 -> 1.13 with the sensor corrections' part; |bias| <= 1.6 empirical std. Re-measured after
the compatibility std started carrying the IMU noise (same seeds): 0.61-1.38 (CRB alone
0.66-5.97).

Measured 2026-11-26, ``--baseline yes`` (the same flights both ways):
  seeds 500-511: derivatives 0.57-1.37 (baseline 0.58-1.38). The stage's rms z 0.65-1.92
      (baseline 0.82-1.98): scale_beta 1.25 -> 0.91, bias_V and scale_V 1.52 -> 1.16,
      bias_q 1.56 -> 1.23, scale_p 1.45 -> 1.22, delay_air 1.36 -> 1.10; bias_ay's mean
      -1.58 is JSBSim's Coriolis force (pipeline.conditioning.compatibility.correct_for_estimation), on
      top of the injected bias, so applied either way. 3 min 25 s.
  --scenario scenarios/default.toml, seeds 1-12: the stage's rms z 0.72-2.28 (baseline
      0.73-2.48): scale_ay 1.90 -> 1.39, delay_air 1.72 -> 1.22; false corrections 4 (bias_ay
      3, the Coriolis force; scale_ay 1 at 3.62 std, seed 6) against 6 (bias_ay 4, scale_ay
      at 4.73, delay_air at 3.99). Over seeds 1-48 (ad hoc, the stage alone) scale_ay's rms
      is 1.03, delay_air's 1.17. Derivatives 0.54-1.82 both ways: lateral CYbeta 1.69 and
      Cnr 1.82 come from seed 6, where scale_ay is applied either way. 1 min 34 s.

    python benchmarks/correction_uncertainty_mc.py [--seeds 10] [--seed-base 500] [--jobs 2]
        [--scenario scenarios/sensor_errors_calm.toml] [--baseline no|yes]
"""

from __future__ import annotations

import json
import sys
import tempfile
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from _montecarlo import fly, judged_parameters, scatter_table, seed_arguments  # noqa: E402  (benchmarks/)

SCENARIO = ROOT / "scenarios" / "sensor_errors_calm.toml"


def one_flight(seed: int, scenario: Path = SCENARIO, overlapping: bool = False) -> list[dict]:
    """Rows (seed, key, parameter, estimate, std, total_std, truth) of one run; the
    compatibility stage's sensor errors as key "compatibility" (estimate, std, truth,
    applied). ``overlapping``: the baseline, the compatibility stage fitting the log's
    maneuver windows as detected (a window per surface, overlapping ones fitted each)."""
    import pipeline.conditioning.compatibility as compatibility
    from pipeline.jobs.scenario import run_scenario

    keep = compatibility.merge_overlapping
    if overlapping:
        compatibility.merge_overlapping = list
    try:
        with tempfile.TemporaryDirectory() as tmp:
            run_scenario(scenario, Path(tmp), seed=seed, methods=["oem"], quiet=True)
            rep = json.loads((Path(tmp) / "report.json").read_text())
    finally:
        compatibility.merge_overlapping = keep
    rows = [
        {
            "seed": seed,
            "key": key,
            "parameter": n,
            "estimate": p["estimate"],
            "std": p["std"],
            "total_std": p.get("total_std") or p["std"],
            "truth": p["truth"],
        }
        for key, n, p, _ in judged_parameters(rep)
    ]
    for n, p in (rep.get("compatibility") or {}).get("parameters", {}).items():
        if p.get("std") and p.get("truth") is not None:
            rows.append(
                {
                    "seed": seed,
                    "key": "compatibility",
                    "parameter": n,
                    "estimate": p["estimate"],
                    "std": p["std"],
                    "total_std": p["std"],
                    "truth": p["truth"],
                    "applied": bool(p.get("applied")),
                }
            )
    return rows


def compatibility_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per sensor error of the compatibility stage (its full fit, every error free): rms
    and mean of (estimate - truth) / std over the seeds (honest: rms ~1, mean ~0) and on
    how many flights it was applied. Printed, and returned."""
    c = df[df["key"] == "compatibility"].assign(z=lambda d: (d["estimate"] - d["truth"]) / d["std"])
    g = c.groupby("parameter", sort=False)
    tab = pd.DataFrame(
        {
            "rms_z": g["z"].apply(lambda z: float(np.sqrt(np.mean(z**2)))),
            "mean_z": g["z"].mean(),
            "max_abs_z": g["z"].apply(lambda z: z.abs().max()),
            "applied": g["applied"].sum().astype(int),
            "n": g["z"].count(),
        }
    )
    print(tab.round(2).to_string())
    return tab


def main() -> None:
    seeds, jobs, opt = seed_arguments(
        __doc__.splitlines()[0], seeds=10, seed_base=500, options={"scenario": str(SCENARIO), "baseline": "no"}
    )
    if opt["baseline"] == "yes":
        print("== baseline: overlapping maneuver windows fitted each by the compatibility stage")
        base = fly(partial(one_flight, scenario=Path(opt["scenario"]), overlapping=True), seeds, jobs)
        bcomp = base["key"] == "compatibility"
        btab = scatter_table(base[~bcomp], ["key", "parameter"], {"crb": "std", "total": "total_std"})
        compatibility_table(base)
        print("== as the product runs")
    df = fly(partial(one_flight, scenario=Path(opt["scenario"])), seeds, jobs)
    comp = df["key"] == "compatibility"
    tab = scatter_table(df[~comp], ["key", "parameter"], {"crb": "std", "total": "total_std"})
    print(
        f"seeds {seeds[0]}..{seeds[-1]}: empirical std / total std {tab['total'].min():.2f}-"
        f"{tab['total'].max():.2f} (CRB alone {tab['crb'].min():.2f}-{tab['crb'].max():.2f})"
    )
    if comp.any():
        print("compatibility stage, (estimate - truth) / std over the seeds:")
        ctab = compatibility_table(df)
        print(
            f"compatibility: rms z {ctab['rms_z'].min():.2f}-{ctab['rms_z'].max():.2f}, "
            f"applied {int(ctab['applied'].sum())} times on {len(seeds)} flights"
        )
    if opt["baseline"] == "yes":
        print(f"baseline: empirical std / total std {btab['total'].min():.2f}-{btab['total'].max():.2f}")
    print(f"largest empirical/total std ratio: {tab['total'].max():.2f}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
