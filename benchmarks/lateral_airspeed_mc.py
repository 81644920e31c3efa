"""Which airspeed and angle of attack should drive the lateral output-error model? A
Monte Carlo on scenarios/lateral_doublets_calm.toml (aileron and rudder doublets only, so output error
fits the lateral model driven by the measured V, alpha, theta, q, with a per-maneuver
airspeed correction dV under its a-priori std): per seed JSBSim flies the scenario twice
(the pitot noise of the scenario, and none), the product writes flight.mcap, and the same
problem is fitted three ways:

* ``pitot``:     the pseudo-inputs V and alpha are the pitot and the vane low-passed at
                 1 and 5 Hz (the baseline);
* ``kinematic``: pitot and vane below 0.1 Hz blended with the integrated IMU rates above
                 (``lateral_problem(kinematic=True)``, what ``fsid`` uses);
* ``no_noise``:  the baseline on the flight whose pitot has no noise.

Per derivative and source: empirical std of the estimates over the seeds / mean reported
Cramér-Rao std (``reported``, 1 = honest; the 95 % band from n seeds is about
+-1.4/sqrt(n)), the same over the Morelli-Klein std (``mk``, the bound corrected for
coloured residuals that report.md shows beside it), and the bias in empirical std. Then the ratio of the empirical std of
``kinematic`` to ``pitot`` (what the blend buys, same flights).

Measured (2026-11-24): seeds 200-215 | 216-231
  pitot:     empirical / reported std 0.66-2.09 | 1.15-1.91 (Cnbeta 2.09 | 1.91, Cnp 2.04,
             Cnda 1.92, Cndr 2.00 on the first set)
  kinematic: 0.72-1.44 | 0.63-1.38;  no_noise: 0.72-1.44 | 0.74-1.93
  The blend takes the moment derivatives to or below the level of a noise-free pitot:
  their empirical std fall by 1.4-2.3x | 1.1-1.9x (Clr, Cnp, Clbeta most); the side-force
  derivatives (from ay) barely move. |bias| <= 1.08 | 2.18 empirical std (CYr, truth 0,
  which every variant biases the same way: 0.8-1.2 empirical std otherwise).
  Morelli-Klein (seeds 200-215): pitot 0.67-1.93, kinematic 0.73-1.45, no_noise
  0.73-1.35 - the residuals are white, so it follows the Cramér-Rao bound. Before the
  a-priori information of the airspeed corrections entered its middle term it had been
  up to 1.8x below the bound (kinematic 0.73-2.57: Cnbeta, Cldr, Clbeta).

    python benchmarks/lateral_airspeed_mc.py [--seeds 16] [--seed-base 200] [--jobs 2]
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

from pipeline.problems.lateral import LAT_FREE  # noqa: E402

SCENARIO = ROOT / "scenarios" / "lateral_doublets_calm.toml"
LATERAL = LAT_FREE


def _fit(fd, ac, kinematic: bool) -> tuple[dict, dict, dict]:
    """Estimates, Cramér-Rao std and Morelli-Klein std (coloured residuals) by name."""
    from estimators.validation import morelli_klein
    from pipeline.methods.fitting import fit_problem
    from pipeline.problems import lateral_problem, with_airspeed_offsets

    pb = lateral_problem(fd, ac, measured_longitudinal=True, kinematic=kinematic)
    pb = with_airspeed_offsets(pb, fd)
    pb.inputs = "linear"
    res = fit_problem(pb, "oem")
    mk = morelli_klein(
        res.sensitivities,
        [r.to_numpy() for r in res.residuals],
        R=res.R,
        info=res.information,
        names=res.free_names,
        prior_info=res.extra.get("prior_information"),
    )
    return dict(res.params), dict(res.std), dict(zip(res.free_names, mk.std))


def one_flight(seed: int) -> list[dict]:
    """Rows (seed, source, parameter, estimate, std, truth) of the three fits of one seed."""
    from pipeline.ingest.constants import AircraftConstants
    from pipeline.ingest.readers import read_log
    from pipeline.jobs.simulate import simulate

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        src = SCENARIO.read_text().replace('aircraft = "aircraft/', f'aircraft = "{SCENARIO.parent}/aircraft/')
        (d / "noisy.toml").write_text(src)
        # the same flight with a noise-free pitot
        quiet = src.replace("[sensors.airdata]", "[sensors.airdata]\nairspeed_noise_mps = 0.0", 1)
        if quiet == src:
            quiet = src + "\n[sensors.airdata]\nairspeed_noise_mps = 0.0\n"
        (d / "quiet.toml").write_text(quiet)
        for name, fits in (("noisy", (("pitot", False), ("kinematic", True))), ("quiet", (("no_noise", False),))):
            run_dir, _ = simulate(d / f"{name}.toml", d / name, seed=seed, progress=False)
            truth = json.loads((run_dir / "truth.json").read_text())
            ac = AircraftConstants.from_truth(truth)
            fd = read_log(run_dir / "flight.mcap")
            for source, kin in fits:
                params, std, mk = _fit(fd, ac, kin)
                rows += [
                    {
                        "seed": seed,
                        "source": source,
                        "parameter": n,
                        "estimate": params[n],
                        "std": std[n],
                        "mk_std": mk[n],
                        "truth": truth["derivatives"][n],
                    }
                    for n in LATERAL
                ]
    return rows


def main() -> None:
    seeds, jobs = seed_arguments(__doc__.splitlines()[0], seeds=16, seed_base=200)
    df = fly(one_flight, seeds, jobs)
    tab = scatter_table(df, ["source", "parameter"], {"reported": "std", "mk": "mk_std"})
    for s in ("pitot", "kinematic", "no_noise"):
        print(range_line(tab, s, {"mk": "Morelli-Klein"}))
    gain = (tab.loc["pitot"]["emp_std"] / tab.loc["kinematic"]["emp_std"]).round(2)
    print("empirical std pitot / kinematic:", gain.to_dict())


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
