"""``fsid run SCENARIO [--out DIR] [--seed N]``."""
from __future__ import annotations

import argparse

from pipeline.paths import new_run_dir

#: kept in step with pipeline.run.METHODS / METHOD_HELP (not imported: --help stays fast)
METHODS = ("oem", "ls", "fem", "ekf", "ukf", "soem", "eigen", "decouple")
METHOD_LIST = ("oem: output error; ls: equation error; fem: filter error; ekf/ukf: extended/"
               "unscented Kalman filter; soem: stabilised output error; eigen: eigenvalue "
               "transformation; decouple: equation decoupling")

HELP = "simulate a scenario, write its logs, ingest them, identify, validate, report"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario TOML (see scenarios/)")
    p.add_argument("--out", help="output folder (default: a new folder under ./runs/)")
    p.add_argument("--seed", type=int, help="override the scenario's seed")
    p.add_argument("--method", action="append", choices=list(METHODS),
                   help="estimation method (repeat for several; default: the ones that suit the "
                        "scenario - calm: oem ls; turbulence: oem fem ekf ukf; unstable with a "
                        "SAS: soem eigen decouple fem ekf ukf). " + METHOD_LIST)
    p.add_argument("--no-compat", action="store_true",
                   help="skip the sensor-compatibility stage (flight path reconstruction); by "
                        "default sensor errors estimated at >= 3 std are removed from the data "
                        "before estimation")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def print_outputs(out, paths) -> None:
    print(f"wrote {out}/")
    for name, path in paths.items():
        print(f"  {name:<12} {path}")


def run(args: argparse.Namespace) -> int:
    from pipeline.run import run_scenario

    out = new_run_dir("run", args.out)
    paths = run_scenario(args.scenario, out, seed=args.seed, methods=args.method,
                         quiet=args.quiet, compat=not args.no_compat)
    print_outputs(out, paths)
    return 0
