"""What the noise of measured surface positions does to the lateral fit, and what the
pipeline's input smoothing (pipeline.conditioning.input_smoothing) gives back: a Monte Carlo on one
JSBSim flight of multiaxis_multisine_turbulence.

Each draw simulates the lateral gust model (as benchmarks/lateral_gust_filters_mc.py: the
lateral problem of pipeline.problems.multiaxis.multiaxis_problem, the first-order roll gust with the
time constant and rms of JSBSim's p_turb on that flight, white process noise on beta and r,
sensor noise at the flight's logged levels) driven by JSBSim's TRUE aileron and rudder
positions, and fits it with filter error (pipeline.methods.fitting.fit_problem) given

* ``true``: the true positions (the reference: no input noise);
* ``logged``: the logged positions (0.05 deg sensor noise at 100 Hz), as logged;
* ``smoothed``: the logged positions low-passed where their noise floor begins, as the
  pipeline does by default (here da 6.0, dr 7.6 Hz).

The roll mode here has a time constant of ~0.08 s. Per variant and derivative: empirical std over the draws / mean reported std, the bias in
empirical std and the mean |error| / reported std (what the closed-loop tests hold below
3).

Measured (2026-11-25, flight seed 31 with the turbulence in JSBSim's frame - the scenario
has since put it in the aircraft's axes - draws 0-7; empirical/reported std, largest |bias|
in empirical std, worst mean |error|/std, mean error/std of Clp and Clda):
  true      0.38-1.47, 0.88, 1.21 (CYbeta); Clp +0.35, Clda -0.27
  logged    0.57-1.51, 4.57, 2.91 (Clda);   Clp +2.13, Clda -2.91
  smoothed  0.49-1.49, 0.75, 1.24 (CYbeta); Clp +0.11, Clda -0.12
The logged surfaces bias the roll derivatives low together (Clp less negative, Clda
smaller, by 4-5 of their empirical std; Cnp, Cnda likewise), as on the JSBSim flight
itself (tests/closed_loop/test_closed_loop_multiaxis.py: Clp, Clda 4.7 std off before the smoothing);
smoothed, the fit is as good as given the true surfaces. The whole run takes ~2 min.

    python benchmarks/input_noise_mc.py [--seeds 8] [--seed-base 0] [--jobs 2]
        [--flight-seed 31] [--method fem]
"""

from __future__ import annotations

import copy
import sys
import tempfile
from functools import lru_cache, partial
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from _montecarlo import fly, range_line, scatter_table, seed_arguments  # noqa: E402  (benchmarks/)
from lateral_gust_filters_mc import NAMES, flight, fly_once, simulate  # noqa: E402

VARIANTS = ("true", "logged", "smoothed")


@lru_cache(maxsize=1)
def problems(workdir: Path) -> dict:
    """The lateral problem of the flight with the surfaces as logged ("logged") and
    smoothed ("smoothed", the flight() problem), and the true surfaces of each fit segment
    (rad, relative to the segment's first sample as the problem's)."""
    from pipeline.ingest.constants import AircraftConstants
    from pipeline.ingest.readers import read_log
    from pipeline.methods.noise import attach_logged_noise
    from pipeline.problems import multiaxis_problem

    fl = flight(workdir)
    fd = read_log(workdir / "flight.mcap")
    raw = multiaxis_problem(
        fd, AircraftConstants.from_truth(fl["truth"]), "lateral", gust_states=True, rate_hz=50.0, smooth_inputs=False
    )
    raw.inputs = "linear"
    attach_logged_noise(fd, raw)
    t, da, dr = np.load(workdir / "surfaces.npy")
    true_u = []
    for s in fl["problem"].fit:
        u = s.u.copy()
        for i, x in enumerate((da, dr)):
            xi = np.interp(s.t, t, x)
            u[:, i] = xi - xi[0]
        true_u.append(u)
    return {"smoothed": fl["problem"], "logged": raw, "true_u": true_u}


def one_draw(seed: int, *, workdir: Path, method: str) -> list[dict]:
    """One draw simulated with the true surfaces, fitted with each variant's surfaces:
    rows of (variant, name, estimate, std, truth)."""
    from pipeline.methods.fitting import fit_problem

    fl, pbs = flight(workdir), problems(workdir)
    segs = simulate(pbs["smoothed"], fl["truth"], "markov", fl, np.random.default_rng(2000 + seed), u_sim=pbs["true_u"])
    rows = []
    for variant in VARIANTS:
        given = pbs["true_u"] if variant == "true" else [s.u for s in pbs[variant].fit]
        pb = copy.copy(pbs["smoothed"])
        pb.fit = [copy.copy(s) for s in segs]
        for s, u in zip(pb.fit, given):
            s.u = u
        res = fit_problem(pb, method, turbulence=fl["truth"]["turbulence"])
        rows += [
            {
                "variant": variant,
                "name": n,
                "estimate": float(res.params[n]),
                "std": float(res.std[n]),
                "truth": float(fl["truth"]["derivatives"][n]),
            }
            for n in NAMES
        ]
    return rows


def main() -> None:
    seeds, jobs, opt = seed_arguments(__doc__.splitlines()[0], 8, 0, {"flight-seed": "31", "method": "fem"})
    with tempfile.TemporaryDirectory() as d:
        fly_once(Path(d), int(opt["flight-seed"]))
        note = next(n for n in flight(Path(d))["problem"].notes if n.startswith("control inputs"))
        print(f"flight seed {opt['flight-seed']}: {note}")
        df = fly(partial(one_draw, workdir=Path(d), method=opt["method"]), seeds, jobs)
    df["err_std"] = (df["estimate"] - df["truth"]) / df["std"]
    tab = scatter_table(df, ["variant", "name"], {"reported": "std"})
    g = df.groupby(["variant", "name"], sort=False)["err_std"]
    tab["mean_abs_err_std"] = g.apply(lambda e: e.abs().mean())
    tab["mean_err_std"] = g.mean()
    for variant in VARIANTS:
        t = tab.loc[variant]
        print(
            range_line(tab, variant) + f"; mean |error|/std worst {t['mean_abs_err_std'].max():.2f} "
            f"({t['mean_abs_err_std'].idxmax()}); mean error/std Clp "
            f"{t.loc['Clp', 'mean_err_std']:+.2f}, Clda {t.loc['Clda', 'mean_err_std']:+.2f}"
        )


if __name__ == "__main__":
    main()
