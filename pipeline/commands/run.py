"""``fsid run SCENARIO [--out DIR] [--seed N]``."""

from __future__ import annotations

import argparse

from pipeline.commands.arguments import add_input_arguments, add_validation_arguments, print_outputs, validation_options
from pipeline.jobs.failures import failure_recorded
from pipeline.jobs.options import RunOptions
from pipeline.paths import new_run_dir
from pipeline.registry import METHOD_LIST, METHODS

HELP = "simulate a scenario, write its logs, ingest them, identify, validate, report"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="scenario TOML (see scenarios/)")
    p.add_argument("--out", help="output folder (default: a new folder under ./runs/)")
    p.add_argument("--seed", type=int, help="override the scenario's seed")
    p.add_argument(
        "--method",
        action="append",
        choices=list(METHODS),
        help="estimation method (repeat for several; default: the ones that suit the "
        "scenario - calm: oem ls; turbulence: oem fem ekf ukf; unstable with a "
        "SAS: soem decouple fem ekf ukf; eigen needs a linear model). " + METHOD_LIST,
    )
    p.add_argument(
        "--no-compat",
        action="store_true",
        help="skip the sensor-compatibility stage (flight path reconstruction); by "
        "default sensor errors estimated at >= 3 std are removed from the data "
        "before estimation",
    )
    add_input_arguments(p)
    add_validation_arguments(p)
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--no-figures", action="store_true", help="write report.md without its figures (faster batch runs)")


def options(args: argparse.Namespace) -> RunOptions:
    """The run's settings from the parsed command line."""
    return RunOptions(
        seed=args.seed,
        methods=args.method,
        quiet=args.quiet,
        figures=not args.no_figures,
        compat=not args.no_compat,
        smooth_inputs=not args.raw_inputs,
        input_dynamics=args.input_dynamics,
        **validation_options(args),
    )


def run(args: argparse.Namespace) -> int:
    from pipeline.jobs.scenario import run_scenario  # the job loads numba, scipy, pandas: on use only

    opts = options(args)
    out = new_run_dir("run", args.out)
    with failure_recorded(out, "run"):
        paths = run_scenario(args.scenario, out, opts)
    print_outputs(out, paths)
    return 0
