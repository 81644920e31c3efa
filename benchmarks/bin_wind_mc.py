"""What does the wind of the rebuilt air-data angles cost? A Monte Carlo over seeds of
multiaxis_multisine_turbulence's ArduPilot log: for each seed JSBSim flies the scenario
(light turbulence, a calm validation flight), the product writes flight.bin (no vane: alpha
and beta are rebuilt from the 10 Hz GPS velocity, pipeline.conditioning.flow_angles) and ``fsid
estimate flight.bin --method fem --no-compat --validate-with validation.bin`` fits both
axes. The reconstruction assumes no vertical wind; the uncertainty of the flight-mean
vertical gust and of the fitted horizontal wind reaches the estimates as a consider part
(pipeline.uncertainty.consider.wind).

Per method and derivative: empirical std of the estimates over the seeds / mean Cramér-Rao
std (``crb``) and / mean total std (``total``, the CRB with the wind's part; 1 = honest,
the 95 % band from n seeds about +-1.4/sqrt(n)), bias in empirical std; then per seed the
largest |error| / total std of each axis.

Measured (seeds 31-38, 2026-11-26, at 27344cf and with the pitot's scale factor):
  the wind fit estimates the pitot's scale factor with the wind where its std is at most
      2 % (the flight turns 80 deg; truth 0): +2.99 +- 1.91, +0.12 +- 1.03, not
      identifiable (2.03), -0.53 +- 1.50, +2.91 +- 1.63, +0.71 +- 1.35, -0.39 +- 0.68, not
      identifiable (2.43) %, estimate / std rms 1.03 over the 6; applied on no seed, so the
      estimates are those of 27344cf, and where estimated its std is carried.
  empirical / total std: longitudinal 0.53-1.38 (27344cf 0.56-1.38), lateral 0.42-2.17
      (0.47-2.46): CYbeta 2.24 -> 1.70, Cnbeta 2.46 -> 1.78, Cnr 2.41 -> 2.17; the control
      derivatives scale with the dynamic pressure, so the scale factor's 1-2 % makes Cndr
      0.42, Cmde 0.55 (this pitot has no error for the scatter to show).
  within 3 total std: longitudinal 5/8 seeds (4/8), lateral 4/8 (2/8); worst per seed
      longitudinal 1.8, 4.0, 7.0, 3.7, 2.4, 3.0, 2.9, 1.8 (3.0, 4.2, 7.0, 4.4, 2.8, 3.7,
      2.9, 1.8), lateral 3.0, 2.3, 4.6, 2.6, 2.7, 3.7, 2.7, 3.5 (4.4, 3.6, 4.6, 2.8, 3.2,
      3.9, 2.8, 3.5).
  trim terms CL0, Cm0, CD0: empirical / CRB 0.69-0.84, / total 0.53-0.69 (0.56-0.70).
  An earlier run (2026-11-25, before the maneuver-scatter std and the input smoothing of
  later sessions) had the trim terms' empirical / CRB at 3.74-4.80.

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
    from pipeline.jobs.estimate import estimate_log
    from pipeline.jobs.simulate import simulate

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        run_dir, _ = simulate(SCENARIO, d / "run", seed=seed, progress=False)
        estimate_log(
            run_dir / "flight.bin",
            d / "est",
            methods=["fem"],
            quiet=True,
            compat=False,
            validation_log=run_dir / "validation.bin",
        )
        rep = json.loads((d / "est" / "report.json").read_text())
        wu = rep["meta"]["flow_angles"].get("wind_uncertainty", {}).get("std_mps", {})
        cal = rep["meta"]["flow_angles"].get("airspeed_scale") or {}
        for key, m in rep["methods"].items():
            for n, p in m["parameters"].items():
                if p.get("truth") is not None and p.get("std") and "[" not in n:
                    rows.append(
                        {
                            "seed": seed,
                            "key": key,
                            "parameter": n,
                            "estimate": p["estimate"],
                            "std": p["std"],
                            "total_std": p.get("total_std") or p["std"],
                            "truth": p["truth"],
                            "converged": m["converged"],
                            "vertical": wu.get(key, {}).get("vertical wind", 0.0),
                            "scale": cal.get("estimate", 0.0),
                            "scale_std": cal.get("std", 0.0),
                            "scale_applied": bool(cal.get("applied")),
                            "scale_estimated": cal.get("status") == "estimated",
                        }
                    )
    return rows


def main() -> None:
    seeds, jobs = seed_arguments(__doc__.splitlines()[0], 8, 31)
    df = fly(one_flight, seeds, jobs)
    tab = scatter_table(df, ["key", "parameter"], {"crb": "std", "reported": "total_std"})
    df["err_crb"] = (df["estimate"] - df["truth"]).abs() / df["std"]
    df["err_total"] = (df["estimate"] - df["truth"]).abs() / df["total_std"]
    worst = df.groupby(["key", "seed"]).agg(
        crb=("err_crb", "max"),
        total=("err_total", "max"),
        vertical=("vertical", "first"),
        converged=("converged", "first"),
    )
    print(worst.round(2).to_string())
    for key in dict.fromkeys(tab.index.get_level_values(0)):
        print(range_line(tab, key, {"crb": "CRB alone"}))
        w = worst.loc[key]
        print(
            f"  {key}: within 3 total std on {(w['total'] <= 3).sum()}/{len(w)} seeds "
            f"({(w['crb'] <= 3).sum()}/{len(w)} with the CRB alone); worst per seed "
            + ", ".join(f"{v:.1f}" for v in w["total"])
        )
    # the pitot's scale factor the wind fit estimated (truth 0)
    cal = df.groupby("seed")[["scale", "scale_std", "scale_applied", "scale_estimated"]].first()
    est = cal[cal["scale_estimated"]]
    z = est["scale"] / est["scale_std"]
    print(
        "pitot scale factor (truth 0) per seed: "
        + ", ".join(
            (
                f"{100 * k:+.2f} +- {100 * sd:.2f} %{' applied' if a else ''}"
                if e
                else f"not identifiable (std {100 * sd:.2f} %)"
            )
            for k, sd, a, e in cal.itertuples(index=False)
        )
        + f"; estimated on {len(est)}/{len(cal)} seeds, estimate / std rms "
        f"{float((z**2).mean() ** 0.5):.2f}"
    )
    trim = tab.loc[[(k, n) for k, n in tab.index if n in ("CL0", "Cm0", "CD0")]]
    print(
        "trim terms (the flight-mean vertical gust's): empirical / CRB "
        f"{trim['crb'].min():.2f}-{trim['crb'].max():.2f}, / total "
        f"{trim['reported'].min():.2f}-{trim['reported'].max():.2f}"
    )


if __name__ == "__main__":
    main()
