"""The closed loop of tests/closed_loop/test_closed_loop_multiaxis.py over many seeds: for each seed
``fsid run scenarios/multiaxis_multisine_turbulence.toml`` (JSBSim flight in light Tustin
turbulence, three simultaneous 3-axis multisines and an elevator sweep, logs written and
read back, no compatibility stage as in the test) with FEM, EKF and UKF on both axes.

The test holds one seed (31); this shows how typical it is. Per method (axis-method):
  * per seed, the worst |error| / reported std over the derivatives, and in how many
    seeds every derivative is within 3 std (the test's criterion);
  * over the seeds, per derivative: empirical std / mean reported std (1 = honest) and
    bias = (mean - truth) / empirical std (the band of the mean of n seeds is
    +-2/sqrt(n)).
Then per method and seed the proof of match (pass, and its worst channel's max |error| /
band) and the largest Theil coefficient. The last line: the share of (seed, method) fits
with every derivative within 3 std.

Measured (2026-11-25, seeds 31-38, FEM, 34 s with the kernels cached) with the maneuver
scatter as the std where it is significant (pipeline.validation.uncertainty.widen_by_scatter):
    longitudinal FEM  2.6 3.9 4.0 2.3 2.4 3.2 2.1 2.3 (5/8 within 3 reported std);
                      empirical / reported std up to 2.39 (Cmalphadot),
                      Cmq 1.30, Cmalpha 1.66; |bias| <= 0.83
    lateral FEM       2.9 2.6 1.6 1.7 3.5 1.8 5.2 1.8 (6/8); up to 1.67 (Cnda)
    fits within 3 std: 11/16 (8/16 with the Cramér-Rao bounds, below)
Measured before that (2026-11-25, seeds 31-38, 2 jobs): the scenario as it is - 3 deg multisines, every
maneuver of the flight fitted, the proof of match on its calm validation flight:
    longitudinal FEM  3.4 3.9 4.0 2.4 2.4 3.2 6.0 2.3 (3/8 within 3 reported std, 6/8 with
                      the larger of reported and maneuver-scatter std); empirical / reported
                      std up to 3.48 (Cmalphadot), 2.46 (Cmq), 2.13 (Cmalpha); |bias| <= 0.83
    lateral FEM       2.9 3.1 1.6 1.7 3.5 1.8 5.2 1.8 (5/8; 6/8); up to 1.87 (Cnbeta);
                      |bias| <= 1.03
    EKF / UKF         0/8 on both axes: longitudinal worst 3.7-7.4 (Cmalphadot, CLq), lateral
                      UKF 3.1-18.8, EKF 3.7-90 (Clp)
    proof of match on the calm validation flight (worst channel's max |error| / band):
                      longitudinal FEM, EKF, UKF pass on 8/8 seeds (0.40-0.81); lateral FEM
                      7/8 (0.50-0.79; seed 35 1.02), UKF 5/8 (0.81-2.04), EKF 1/8 (0.83-4.10)
    largest Theil coefficient: longitudinal 0.090-0.097, lateral 0.070-0.081 (every method,
                      every seed)
  Tried and dropped (2026-11-25): EKF/UKF with the run's filter-error noise model (its F
  x2, tau_pg held at its estimate) instead of twice the Dryden level: lateral UKF within 3
  std on 2/8 seeds (worst 2.4-14.3; seed 31 from 6.5 to 2.4), but its proof of match 3/8;
  longitudinal EKF/UKF worse on every seed (worst 5.3-9.1 / 6.4-11.2, CLq); lateral EKF
  3.5-79; 10/48 fits within 3 std. Real logs (no level known) take that noise model.
  Tried and dropped (2026-11-26, ad hoc, seeds 31-38, EKF/UKF only, scripts not kept): the
  filters' process noise reshaped around the gust models. Baseline: within 3 std on 0/8
  seeds on either axis, the longitudinal bias over the seeds Cmalphadot -5.4 / -4.5 mean
  reported std (EKF / UKF), CLq +3.8 / +4.3, Cmq +3.0 / +1.6, the empirical / reported
  std 1.2 (median): a shared bias, not a variance. The white pitch/roll/yaw-rate noise
  (0.3 x the gust level, x2) times 3: longitudinal EKF 1/8, UKF 4/8 (Cmalphadot bias -3.9
  / -2.8), lateral 0/8 and worse (Clbeta +3.8 / +2.8); times 10: longitudinal 0/8, 3/8
  (Cmq +4.7 / +3.2), lateral EKF up to 19 std; times 0.1: everything worse (seed 31: CLq
  6.9, Clp 9.5). The alpha/beta noise at the Dryden level (1x, as the gust states' colour
  would have it) instead of 2x: seed 31 CLq 7.5, Clr 8.7. FEM's own noise model at 1x
  (its F on every state, tau_pg held): seed 31 EKF/UKF Cmde 6.6 / 6.8, Cm0 5.8 / 6.1, Cmq
  5.9 / 6.0 std off while FEM is within 2.6 - the same model and noise, so the gap is the
  parameter-in-the-state filter itself (as Ljung's gain sensitivity found, the docstring
  of tests/closed_loop/test_closed_loop_multiaxis.py).
  The same with 1.5 deg multisines (FEM only): longitudinal 1.8 3.5 4.2 3.0 4.1 3.1 5.4 2.8
  (3/8; 6/8), empirical / reported up to 3.29 (Cmalphadot), 1.90 (Cmq); lateral 5/8, 5/8;
  the 3 deg empirical std a median 0.65 of it (0.26-1.13 by derivative: Cmde 0.018 against
  0.028, Clp 0.021 against 0.033, Cmq 0.70 against 0.62).
Earlier (1.5 deg, the last multisine held out of the fit), worst
|error|/std per seed and empirical / reported std over the seeds (|bias| in empirical std):
  turbulence in the aircraft's axes (the scenario's setting):
    longitudinal FEM  2.0 3.6 4.0 2.6 6.0 3.3 5.0 2.8 (3/8 within 3); 0.45-3.07 (Cmalphadot
                      3.07, Cmq 2.01), |bias| <= 1.5
    lateral FEM       2.7 3.6 1.8 2.3 3.7 1.6 5.6 2.4 (5/8); 0.65-2.15, |bias| <= 1.4
    EKF / UKF         0/8 on both axes: longitudinal worst 4.2-6.5 on every seed
                      (Cmalphadot or CLq); lateral UKF worst 4.3-19.7, EKF 5.2-113 (Clp's
                      scatter 26x its reported std)
  JSBSim's wind-azimuth frame (--axes wind):
    longitudinal FEM  1.7 8.9 4.5 2.2 4.4 2.6 15.8 1.9 (4/8); 0.81-7.95 (Cmq 7.95,
                      Cmalphadot 7.57)
    lateral FEM       2.8 6.6 1.8 2.5 3.4 1.6 12.2 1.9 (5/8); 0.92-5.24 (Cnr 5.24, Cnp 3.74)
    EKF / UKF         0/8 on both axes (longitudinal Cmalpha 18.5-18.8 std on seeds 32, 37)
  maneuver-scatter std (estimators.covariance.cluster; the longitudinal fit has 3
  maneuvers, the lateral 2), FEM only (2026-11-25): empirical / scatter std longitudinal
  0.37-2.12, lateral 0.83-2.07; / the larger of reported and scatter 0.33-2.01
  (Cmalphadot 3.07 -> 2.01, Cmq 2.01 -> 1.33) and 0.57-1.59 (Cnbeta 2.15 -> 1.25, Cnr
  2.09 -> 1.59); worst |error| / that std per seed longitudinal 2.0 3.6 4.0 2.6 4.5 2.3
  2.1 2.3 (within 3 in 5/8 seeds, 3/8 with the reported std), lateral 2.7 2.3 1.8 2.3 3.7
  1.5 3.8 2.3 (6/8, 5/8).
  fits within 3 std: 8/48 (aircraft axes), 9/48 (wind frame). In JSBSim's frame the FEM
  bounds were 8x too small on Cmq; in the aircraft's axes at most 3x (Cmalphadot). Seed 31
  (the test's) is among FEM's good seeds in both.

    python benchmarks/multiaxis_seeds.py [--seeds 8] [--seed-base 31] [--jobs 2]
        [--methods fem,ekf,ukf] [--axes wind|aircraft] [--scenario path.toml]

``--axes``: the scenario's [turbulence] axes (sim.scenario.Turbulence.axes: JSBSim's
wind-azimuth frame, or the aircraft's axes as MIL-F-8785C defines the gusts above
2000 ft); ``--scenario``: another variant of the scenario file.
"""

from __future__ import annotations

import functools
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _montecarlo import fly, judged_parameters, scatter_table, seed_arguments  # noqa: E402

SCENARIO = ROOT / "scenarios" / "multiaxis_multisine_turbulence.toml"
METHODS = "fem,ekf,ukf"


def one_seed(seed: int, methods: str = METHODS, scenario: str = str(SCENARIO)) -> list[dict]:
    from pipeline.jobs.scenario import run_scenario

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        run_scenario(scenario, out, seed=seed, methods=methods.split(","), quiet=True, compat=False)
        rep = json.loads((out / "report.json").read_text())
    val = {key: _pom_and_tic(m) for key, m in rep["methods"].items()}
    return [
        {
            "seed": seed,
            "method": key,
            "parameter": name,
            "estimate": p["estimate"],
            "truth": p["truth"],
            "reported": p["std"],
            "err": abs(p["error_in_std"]),
            "scatter": p.get("cluster_std") if p.get("cluster_std") is not None else float("nan"),
            "converged": m["converged"],
            **val[key],
        }
        for key, name, p, m in judged_parameters(rep)
    ]


def _pom_and_tic(m: dict) -> dict:
    """A method's proof of match (pass, and the worst channel's max |error| / band) and its
    largest Theil coefficient."""
    pm = (m.get("validation") or {}).get("proof_of_match") or {}
    ratios = [
        d["max_abs_error"] / d["tolerance"]
        for sg in pm.get("segments", [])
        for d in sg["channels"].values()
        if d.get("pass") is not None and d.get("tolerance")
    ]
    tic = [d["TIC"] for d in ((m.get("validation") or {}).get("fit") or {}).get("per_output", {}).values()]
    return {
        "pom_pass": bool(pm.get("all_pass")),
        "pom_ratio": max(ratios, default=float("nan")),
        "max_tic": max(tic, default=float("nan")),
    }


def with_axes(scenario: Path, axes: str, folder: Path) -> Path:
    """A copy of ``scenario`` in ``folder`` with ``[turbulence] axes`` set (its aircraft
    path made absolute)."""
    text = scenario.read_text()
    lines = []
    for line in text.splitlines():
        if line.strip().startswith("axes ="):
            continue
        if line.startswith("aircraft ="):
            rel = line.split("=", 1)[1].strip().strip('"')
            line = f'aircraft = "{(scenario.parent / rel).resolve()}"'
        lines.append(line)
        if line.strip() == "[turbulence]":
            lines.append(f'axes = "{axes}"')
    out = folder / scenario.name
    out.write_text("\n".join(lines) + "\n")
    return out


def main() -> float:
    seeds, jobs, opts = seed_arguments(
        __doc__.split("\n\n")[0], 8, 31, {"methods": METHODS, "scenario": str(SCENARIO), "axes": ""}
    )
    with tempfile.TemporaryDirectory() as tmp:
        scenario = Path(opts["scenario"]).resolve()
        if opts["axes"]:
            scenario = with_axes(scenario, opts["axes"], Path(tmp))
        print(
            f"{scenario.name}, seeds {seeds[0]}-{seeds[-1]}"
            + (f", turbulence axes {opts['axes']}" if opts["axes"] else "")
        )
        df = fly(functools.partial(one_seed, methods=opts["methods"], scenario=str(scenario)), seeds, jobs)
    worst = df.groupby(["method", "seed"])["err"].max().unstack("seed")
    which = df.loc[df.groupby(["method", "seed"])["err"].idxmax()].set_index(["method", "seed"])["parameter"]
    print("worst |error| / reported std per seed (the derivative):")
    for method, row in worst.iterrows():
        cells = [f"{row[s]:5.1f} {which[(method, s)]:<10s}" for s in worst.columns]
        ok = int((row <= 3.0).sum())
        print(f"  {method:18s} within 3 std in {ok}/{len(row)} seeds | " + " ".join(cells))
    print(
        "\nover the seeds, per derivative (reported: the method's std; scatter: the "
        "maneuver-scatter std of the report, with 2+ maneuvers; wider: the larger of both):"
    )
    df["wider"] = np.fmax(df["reported"], df["scatter"])
    scatter_table(df, ["method", "parameter"], {"reported": "reported", "scatter": "scatter", "wider": "wider"})
    wide = (
        df.assign(err=(df["estimate"] - df["truth"]).abs() / df["wider"])
        .groupby(["method", "seed"])["err"]
        .max()
        .unstack("seed")
    )
    print("worst |error| / wider std per seed:")
    for method, row in wide.iterrows():
        print(
            f"  {method:18s} within 3 std in {int((row <= 3.0).sum())}/{len(row)} seeds | "
            + " ".join(f"{v:5.1f}" for v in row)
        )
    per = df.groupby(["method", "seed"]).first()
    print("proof of match per seed (worst channel's max |error| / band; * = fails) and the largest Theil coefficient:")
    for method in worst.index:
        rows = per.loc[method]
        print(
            f"  {method:18s} passes in {int(rows['pom_pass'].sum())}/{len(rows)} seeds | "
            + " ".join(f"{r:4.2f}{' ' if ok else '*'}" for r, ok in zip(rows["pom_ratio"], rows["pom_pass"]))
            + f" | TIC {rows['max_tic'].min():.3f}-{rows['max_tic'].max():.3f}"
        )
    share = float((worst <= 3.0).to_numpy().mean())
    print(
        f"\nfits with every derivative within 3 std: {int((worst <= 3.0).to_numpy().sum())}/{worst.size} = {share:.2f}"
    )
    return share


if __name__ == "__main__":
    pd.set_option("display.width", 140)
    main()
