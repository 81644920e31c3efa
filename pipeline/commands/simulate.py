"""``fsid simulate SCENARIO [--out DIR] [--seed N]``: fly a scenario, write its logs.

Writes ``DIR/flight.mcap`` (the product's own MCAP), ``DIR/flight.bin`` (ArduPilot
DataFlash) and ``DIR/truth.json`` (truth set, trim, sensor errors, seed, versions); a
scenario with a ``[validation_flight]`` also ``DIR/validation.mcap`` and
``DIR/validation.bin`` (for ``fsid estimate DIR/flight.mcap --validate-with
DIR/validation.mcap``).
SCENARIO is a path to a scenario TOML or the name of a built-in one (``default``,
``longitudinal_3211_calm``, ... in the repository's ``scenarios/`` folder); the work is
:func:`pipeline.jobs.simulate.simulate`.
"""

from __future__ import annotations

import argparse
import time

from pipeline.jobs.failures import failure_recorded
from pipeline.paths import new_run_dir

HELP = "fly a scenario in JSBSim (Dryden turbulence, sensor models) and write flight.mcap, flight.bin, truth.json"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", help="scenario .toml file or built-in name (e.g. default)")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: a new folder under ./runs/)")
    parser.add_argument(
        "--seed", type=int, metavar="N", help="seed for turbulence and sensor noise (default: the scenario's seed)"
    )
    parser.add_argument(
        "--keep-jsbsim", action="store_true", help="keep the generated JSBSim aircraft XML in DIR/jsbsim"
    )
    parser.add_argument(
        "--force", action="store_true", help="replace flight logs already in DIR (default: refuse to write over them)"
    )


def run(args: argparse.Namespace) -> int:
    from pipeline.jobs.simulate import simulate  # the job loads the simulator: on use only

    t0 = time.perf_counter()
    out = new_run_dir("simulate", args.out, logs=True, force=args.force)
    with failure_recorded(out, "simulate"):
        run_dir, result = simulate(args.scenario, out, args.seed, args.keep_jsbsim, force=True)
    dt = time.perf_counter() - t0
    s = result.scenario
    print(
        f"simulated {s.name} ({s.aircraft.name}, {s.duration:g} s, seed {result.meta['seed']}, "
        f"{len(result.maneuvers)} maneuvers) in {dt:.1f} s"
    )
    for f in ("flight.mcap", "flight.bin", "truth.json", "validation.mcap", "validation.bin"):
        if (run_dir / f).exists():
            print(f"wrote {run_dir / f}")
    return 0
