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


def run(args: argparse.Namespace) -> int:
    from pipeline.jobs.simulate import simulate  # the job loads the simulator: on use only

    t0 = time.perf_counter()
    run_dir, result = simulate(args.scenario, args.out, args.seed, args.keep_jsbsim)
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
