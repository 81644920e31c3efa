"""Statistical efficiency of the filter-error method (and the EKF) on the simulator's own
turbulence scenario, through the real-log path: for each seed JSBSim flies
scenarios/longitudinal_3211_turbulence.toml (MIL-spec light Dryden turbulence, its own
seed), the product writes flight.mcap, reads it back, builds the longitudinal problem and
fits it - exactly what ``fsid run`` does, without the compatibility stage.

Per derivative: ratio = empirical std of the estimates over the seeds / mean reported
std (Cramér-Rao for FEM, final filter std for the EKF), and bias = (mean estimate -
truth) / empirical std. An efficient, unbiased estimator with honest bounds has ratio ~1
and |bias| small (the 95 % band of the mean of n seeds is +-2/sqrt(n) std). Unlike
benchmarks/fem_efficiency.py the data do not come from the estimator's own model: the
turbulence is JSBSim's (coloured Dryden gusts plus rotary gusts), the aircraft JSBSim's.
The last line is the worst FEM ratio.

Measured (30 seeds from 100, 2026-11-21): FEM ratios 1.00-1.82 (drag polar CD0, CDalpha,
CDalpha2 1.7-1.8, Cmde 1.5, Cm0 1.4, the others 1.0-1.3), |bias| <= 1.1 empirical std, but
with 30 seeds Cmq's mean (-3.36 for -3.6, 7 % low) and Cmalpha's are systematic (the
rotary gusts JSBSim adds are not in the longitudinal model). The EKF, its process noise
fixed at twice the gust level, lost its way on some seeds (ratios 20-240 on CLalpha, Cm0,
Cmalpha): not robust across flights.

Measured (16 seeds from 100, 2026-11-24, --grid-noise) after FEM's measurement noise came
from the log's native samples (pipeline.methods.noise.attach_logged_noise): FEM ratios 0.82-1.53
(CD0 1.53, Cmq 1.28, Cm0 1.18, the others 0.82-1.09), |bias| <= 1.3; the same flights with
the grid's second-difference noise (fem-grid): 0.83-2.02 (CD0 2.02, Cmq 1.51, Cm0 1.31,
Cmde 1.24). Cmq stays 8 % low (-3.31 for -3.6) with either.

    python benchmarks/fem_efficiency_sim.py [--seeds 20] [--seed-base 100] [--ekf] [--grid-noise]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "longitudinal_3211_turbulence.toml"


def one_seed(seed: int, methods: list[str], work: Path) -> dict[str, tuple[dict, dict]]:
    import sim
    from pipeline.ingest.constants import AircraftConstants
    from pipeline.ingest.readers import read_log
    from pipeline.methods.fitting import fit_problem
    from pipeline.methods.noise import attach_logged_noise
    from pipeline.outputs.writers import write_mcap, write_truth_json
    from pipeline.problems import LONG_OUTPUTS, longitudinal_problem

    out = work / f"s{seed}"
    out.mkdir()
    result = sim.fly(sim.load_scenario(SCENARIO), seed=seed, workdir=out / ".jsbsim")
    write_mcap(out / "flight.mcap", result)
    write_truth_json(out / "truth.json", result)
    doc = json.loads((out / "truth.json").read_text())
    fd = read_log(out / "flight.mcap")
    ac = AircraftConstants.from_truth(doc)
    pb = longitudinal_problem(fd, ac, rate_hz=min(fd[c].rate_hz for c in LONG_OUTPUTS))
    pb.inputs = "linear"
    attach_logged_noise(fd, pb)  # as fsid run does for the filters
    logged = dict(pb.noise_std)
    res = {}
    for m in methods:
        # fem-grid: the measurement noise from the grid's second differences (the R FEM
        # used before attach_logged_noise), on the same flight
        pb.noise_std = {} if m == "fem-grid" else logged
        r = fit_problem(pb, "fem" if m == "fem-grid" else m, turbulence=doc.get("turbulence"))
        names = [n for n in r.free_names if n in doc["derivatives"]]
        res[m] = ({n: float(r.params[n]) for n in names}, {n: float(r.std[n]) for n in names})
    return res, {k: float(v) for k, v in doc["derivatives"].items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--seed-base", type=int, default=100)
    ap.add_argument("--ekf", action="store_true", help="also the EKF on the same flights")
    ap.add_argument(
        "--grid-noise",
        action="store_true",
        help="also FEM with the measurement noise from the grid's second differences",
    )
    args = ap.parse_args()
    methods = ["fem"] + (["fem-grid"] if args.grid_noise else []) + (["ekf"] if args.ekf else [])
    est = {m: [] for m in methods}
    std = {m: [] for m in methods}
    truth, names = None, None
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="fsid-fem-eff-") as tmp:
        for k in range(args.seeds):
            seed = args.seed_base + k
            try:
                res, truth = one_seed(seed, methods, Path(tmp))
            except Exception as exc:  # a benchmark counts failures and goes on
                print(f"seed {seed}: failed: {type(exc).__name__}: {exc}", flush=True)
                continue
            for m in methods:
                e, s = res[m]
                names = names or list(e)
                est[m].append([e[n] for n in names])
                std[m].append([s[n] for n in names])
            print(f"seed {seed}: done ({time.perf_counter() - t0:.0f} s)", flush=True)
    worst = np.nan
    for m in methods:
        E, S = np.array(est[m]), np.array(std[m])
        if len(E) < 3:
            print(f"{m.upper()}: too few successful seeds ({len(E)})")
            continue
        tr = np.array([truth[n] for n in names])
        emp = E.std(axis=0, ddof=1)
        ratio = emp / S.mean(axis=0)
        bias = (E.mean(axis=0) - tr) / emp
        print(f"\n{m.upper()} over {len(E)} seeds: empirical std / mean reported std, (mean - truth) / empirical std")
        print(f"{'parameter':>10} {'truth':>10} {'mean':>10} {'ratio':>7} {'bias':>7}")
        for i, n in enumerate(names):
            print(f"{n:>10} {tr[i]:10.4g} {E[:, i].mean():10.4g} {ratio[i]:7.2f} {bias[i]:7.2f}")
        if m == "fem":
            worst = float(ratio[np.argmax(np.abs(np.log(ratio)))])
    print(f"\nFEM worst ratio (empirical / Cramer-Rao std): {worst:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
