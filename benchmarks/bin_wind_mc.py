"""What does the wind of the rebuilt air-data angles cost? A Monte Carlo over seeds of
multiaxis_multisine_turbulence's ArduPilot log: for each seed JSBSim flies the scenario
(light turbulence, a calm validation flight), the product writes flight.bin (no vane: alpha
and beta are rebuilt from the 10 Hz GPS velocity, pipeline.flow_angles) and ``fsid
estimate flight.bin --method fem --no-compat --validate-with validation.bin`` fits both
axes. The reconstruction assumes no vertical wind; the uncertainty of the flight-mean
vertical gust and of the fitted horizontal wind reaches the estimates as a consider part
(pipeline.correction_uncertainty.wind).

Per method and derivative: empirical std of the estimates over the seeds / mean Cramér-Rao
std (``crb``) and / mean total std (``total``, the CRB with the wind's part; 1 = honest,
the 95 % band from n seeds about +-1.4/sqrt(n)), bias in empirical std; then per seed the
largest |error| / total std of each axis.

Measured (seeds 31-38, 2026-11-25; the vertical std given 0.41-0.77 m/s longitudinal):
  trim terms CL0, Cm0, CD0: empirical / CRB 3.74-4.80, / total 0.71-0.98 - honest with
      the wind's part, 4-5 x optimistic without; CDalpha 3.77 -> 1.36, CLde 2.59 -> 1.40.
  the rest stays optimistic (total = CRB there): Cmq 3.70, Cmalphadot 3.39, CLalpha 2.53,
      CLq 2.39, CDalpha2 2.03 (bias 2.2 empirical std); lateral CYbeta 3.38, Cnbeta 3.17,
      Cnr 2.52. With the vanes (flight.mcap, benchmarks/multiaxis_seeds.py) filter error
      has Cmalphadot 3.1 and Cmq 2.0, so rebuilt angles add CLalpha, CYbeta, Cnbeta.
  worst |error| / total std per seed 31-38: longitudinal 3.7, 8.6, 5.9, 13.7, 9.1, 5.7,
      7.4, 2.2 (CRB alone 9.6, 8.6, 7.8, 14.5, 10.4, 5.8, 8.7, 2.3), lateral 4.3, 3.5, 4.5,
      2.8, 3.2, 3.8, 4.2, 6.2: the trim terms are no longer the worst, Cmq is.

    python benchmarks/bin_wind_mc.py [--seeds 8] [--seed-base 31] [--jobs 2]
"""
from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from _montecarlo import fly, range_line, scatter_table, seed_arguments  # noqa: E402  (benchmarks/)

SCENARIO = ROOT / "scenarios" / "multiaxis_multisine_turbulence.toml"


def one_flight(seed: int) -> list[dict]:
    """Rows (seed, key, parameter, estimate, std, total_std, truth, vertical) of one flight;
    ``vertical`` is the flight-mean vertical wind's std the fit was given [m/s]."""
    from pipeline.commands.simulate import simulate
    from pipeline.run import estimate_log

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        run_dir, _ = simulate(SCENARIO, d / "run", seed=seed, progress=False)
        estimate_log(run_dir / "flight.bin", d / "est", methods=["fem"], quiet=True, compat=False,
                     validation_log=run_dir / "validation.bin")
        rep = json.loads((d / "est" / "report.json").read_text())
        wu = rep["meta"]["flow_angles"].get("wind_uncertainty", {}).get("std_mps", {})
        for key, m in rep["methods"].items():
            for n, p in m["parameters"].items():
                if p.get("truth") is not None and p.get("std") and "[" not in n:
                    rows.append({"seed": seed, "key": key, "parameter": n, "estimate": p["estimate"],
                                 "std": p["std"], "total_std": p.get("total_std") or p["std"],
                                 "truth": p["truth"], "converged": m["converged"],
                                 "vertical": wu.get(key, {}).get("vertical wind", 0.0)})
    return rows


def main() -> None:
    seeds, jobs = seed_arguments(__doc__.splitlines()[0], 8, 31)
    df = fly(one_flight, seeds, jobs)
    tab = scatter_table(df, ["key", "parameter"], {"crb": "std", "reported": "total_std"})
    df["err_crb"] = (df["estimate"] - df["truth"]).abs() / df["std"]
    df["err_total"] = (df["estimate"] - df["truth"]).abs() / df["total_std"]
    worst = df.groupby(["key", "seed"]).agg(crb=("err_crb", "max"), total=("err_total", "max"),
                                            vertical=("vertical", "first"),
                                            converged=("converged", "first"))
    print(worst.round(2).to_string())
    for key in dict.fromkeys(tab.index.get_level_values(0)):
        print(range_line(tab, key, {"crb": "CRB alone"}))
        w = worst.loc[key]
        print(f"  {key}: within 3 total std on {(w['total'] <= 3).sum()}/{len(w)} seeds "
              f"({(w['crb'] <= 3).sum()}/{len(w)} with the CRB alone); worst per seed "
              + ", ".join(f"{v:.1f}" for v in w["total"]))
    trim = tab.loc[[(k, n) for k, n in tab.index if n in ("CL0", "Cm0", "CD0")]]
    print("trim terms (the flight-mean vertical gust's): empirical / CRB "
          f"{trim['crb'].min():.2f}-{trim['crb'].max():.2f}, / total "
          f"{trim['reported'].min():.2f}-{trim['reported'].max():.2f}")


if __name__ == "__main__":
    main()
