"""What do the air-data vanes buy? A Monte Carlo over windy flights: for each seed JSBSim
flies scenarios/longitudinal_3211_calm.toml (or --scenario NAME, fitting --model
longitudinal|lateral) in a steady wind (--wind north,east m/s; default -4,5), the product writes flight.mcap, and
``fsid estimate`` fits the axis with output error twice - from the logged vanes, and through a channel map without them, the
angles rebuilt from the 10 Hz GPS velocity (pipeline.conditioning.flow_angles). The compatibility stage
is off in both, so only the angles differ.

Per derivative and source (``vanes``, ``rebuilt``): empirical std of the estimates over the
seeds / mean reported std (``reported``, 1 = honest; the 95 % band from n seeds is about
+-1.4/sqrt(n)), bias in empirical std, and the ratio of the mean reported std without and
with vanes (``std_ratio``: what losing the vanes costs).

Measured (seeds 200-207, 2026-11-24):
  longitudinal_3211_calm: empirical / reported std 0.58-1.47 with the vanes, 0.60-1.47
      with the rebuilt angles; |bias| <= 1.45 empirical std in both (CLalpha); reported
      std the same (ratio 1.00-1.08) but for CL0 and Cm0 (1.78, 1.87: conservative there,
      empirical/reported 0.60 and 0.75 - the level of alpha comes from 10 Hz GPS samples
      instead of 50 Hz vane samples, while az pins it as well).
  lateral_doublets_calm (--model lateral), since the lateral output error's V and alpha
      are blended with the integrated IMU (pipeline.conditioning.airdata_kinematics): 0.49-1.64 with
      the vanes, 0.47-1.72 rebuilt (Cnda 1.64 / 1.72, Cndr 1.37 / 1.52); |bias| <= 1.68 /
      1.41; reported std ratio 1.00. Before it: 0.55-2.16 with the vanes, 0.55-2.69 rebuilt;
      |bias| <= 1.23 / 1.19; reported std ratio 1.00-1.02. The lateral output error's
      Cramér-Rao std are optimistic on the yaw derivatives with the vanes already (Cnp
      2.16, Cndr 2.14, Cnda 1.81); the rebuilt sideslip adds to it (Cnda 2.69, Cndr 2.54).
      In calm air (--wind=0,0) the same: vanes 0.55-2.15 (Cnp 2.15, Cndr 2.13), rebuilt
      0.55-2.69 - the wind is not the cause; neither is the noise of the pseudo-inputs
      alpha, theta, q (propagated to first order it leaves the std within 0.57-1.03 x).
      The cause was the pitot noise in the pseudo-input V (benchmarks/lateral_airspeed_mc.py);
      these figures predate its blend with the integrated IMU.

    python benchmarks/flow_angles_mc.py [--seeds 8] [--seed-base 200] [--jobs 2]
        [--scenario longitudinal_3211_calm] [--model longitudinal] [--wind=-4,5]
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from _montecarlo import fly, range_line, scatter_table, seed_arguments  # noqa: E402  (benchmarks/)

SCENARIOS = ROOT / "scenarios"


def one_flight(job: tuple[int, str, str, str]) -> list[dict]:
    """Rows (seed, source, parameter, estimate, std, truth) of one windy flight; ``job`` is
    (seed, scenario name, model, wind "north,east" in m/s)."""
    seed, scenario, model, wind = job
    wn, we = (float(x) for x in wind.split(","))
    from pipeline.ingest.maps import plain_map_toml
    from pipeline.ingest.readers import read_log
    from pipeline.jobs.estimate import estimate_log
    from pipeline.jobs.simulate import simulate

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        src = (
            (SCENARIOS / f"{scenario}.toml")
            .read_text()
            .replace('aircraft = "aircraft/', f'aircraft = "{SCENARIOS}/aircraft/')
        )
        (d / "windy.toml").write_text(src + f"\n[wind]\nnorth_mps = {wn}\neast_mps = {we}\n")
        run_dir, _ = simulate(d / "windy.toml", d / "run", seed=seed, progress=False)
        fd = read_log(run_dir / "flight.mcap")
        (d / "novane.toml").write_text(plain_map_toml(fd, "without_vanes", ["mcap"], drop=("alpha", "beta")))
        for source, mp in (("vanes", None), ("rebuilt", str(d / "novane.toml"))):
            estimate_log(
                run_dir / "flight.mcap", d / source, map_path=mp, methods=["oem"], model=model, quiet=True, compat=False
            )
            rep = json.loads((d / source / "report.json").read_text())
            for n, p in rep["methods"]["oem"]["parameters"].items():
                if p.get("truth") is not None and p.get("std") and "[" not in n:
                    rows.append(
                        {
                            "seed": seed,
                            "source": source,
                            "parameter": n,
                            "estimate": p["estimate"],
                            "std": p["std"],
                            "truth": p["truth"],
                        }
                    )
    return rows


def main() -> None:
    seeds, jobs, opt = seed_arguments(
        __doc__.splitlines()[0],
        seeds=8,
        seed_base=200,
        options={"scenario": "longitudinal_3211_calm", "model": "longitudinal", "wind": "-4,5"},
    )
    df = fly(one_flight, [(s, opt["scenario"], opt["model"], opt["wind"]) for s in seeds], jobs)
    tab = scatter_table(df, ["source", "parameter"], {"reported": "std"})
    sd = df.groupby(["source", "parameter"], sort=False)["std"].mean()
    ratio = (sd["rebuilt"] / sd["vanes"]).round(2)
    print("mean reported std without / with vanes:", ratio.to_dict())
    for s in ("vanes", "rebuilt"):
        print(range_line(tab, s))
    print(f"std ratio rebuilt/vanes {ratio.min():.2f}-{ratio.max():.2f}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
