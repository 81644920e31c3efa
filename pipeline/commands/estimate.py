"""``fsid estimate LOG [--model auto|longitudinal|lateral|FILE.py:NAME] [--aircraft AIRCRAFT.toml]
[--method oem] [--map MAP] [--segments T0:T1,...] [--no-holdout] [--out DIR]``."""

from __future__ import annotations

import argparse

from pipeline.commands.arguments import (
    SEGMENTS_HELP,
    add_input_arguments,
    add_time_base_argument,
    add_validation_arguments,
    log_file,
    print_outputs,
    segment_items,
    validation_options,
)
from pipeline.errors import FsidError
from pipeline.jobs.failures import failure_recorded
from pipeline.jobs.options import EstimateOptions
from pipeline.paths import new_run_dir
from pipeline.registry import METHOD_LIST, METHODS

HELP = "identify derivatives from a log with a built-in model (and an aircraft description) or your own model"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="flight log: .mcap, .bin, .tlog, .ulg, .csv or .npz (an archive of named windows)")
    p.add_argument(
        "--aircraft",
        help="aircraft file ([geometry], [mass], optional [propulsion], [servos] de/da/dr_travel_deg "
        "to decode servo PWM (30 deg assumed without), [sensors.airdata|imu] position_m, [signs], "
        "[apriori]; fsid aircraft init writes a template, docs/aircraft.md): needed by "
        "the built-in models unless the log sits next to a truth.json from "
        "fsid run/simulate; offered to a user model's function",
    )
    p.add_argument(
        "--model",
        default="auto",
        metavar="auto|longitudinal|lateral|FILE.py:NAME",
        help="built-in model: longitudinal (nonlinear, stability axes), lateral "
        "(6-DoF with the longitudinal estimates held when the log also has "
        "elevator maneuvers, else linear), or auto = every axis the log's "
        "maneuvers excite (default); or your own: FILE.py:NAME, an "
        "estimators.Model or a function (aircraft=None, flight=None) returning "
        "one, its inputs/outputs named as the log's canonical channels. "
        "FILE.py is run as Python with your rights: give only files you trust",
    )
    p.add_argument(
        "--method",
        action="append",
        choices=list(METHODS),
        help="estimation method (repeat for several; default: oem). " + METHOD_LIST,
    )
    p.add_argument("--map", help="channel map TOML extending the built-in one")
    add_time_base_argument(p)
    p.add_argument(
        "--inputs",
        default="linear",
        choices=["linear", "hold"],
        help="how control inputs vary between log samples (default: linear)",
    )
    p.add_argument("--out", help="output folder (default: a new folder under ./runs/)")
    p.add_argument("--no-compat", action="store_true", help="skip the sensor-compatibility stage")
    p.add_argument(
        "--validate-with",
        metavar="LOG2",
        action="append",
        help="a second flight log (same aircraft, channel map and sensors) for the "
        "proof of match: every maneuver of LOG is then fitted and the model "
        "is proved on LOG2's maneuvers (repeat for several flights; default: "
        "the last maneuver of each axis of LOG is held out)",
    )
    p.add_argument("--segments", metavar="T0:T1,...", help=SEGMENTS_HELP + " (default: the maneuvers found)")
    p.add_argument(
        "--no-holdout",
        action="store_true",
        help="fit every maneuver, holding none out (no proof of match unless --validate-with gives a flight)",
    )
    p.add_argument(
        "--structure",
        choices=("stepwise", "mof"),
        default=None,
        help="with --method ls: search each coefficient's regression for the structure the data ask for "
        "(stepwise regression or multivariate orthogonal functions over the model's terms and alpha^2, "
        "alpha*de, beta^2, ...); the report says what enters and why",
    )
    p.add_argument(
        "--accept-low-rate",
        action="store_true",
        help="estimate an axis whose body rates or accelerations are logged slower than the motion they show "
        "needs (ten samples a period), instead of refusing it; the report states the risk",
    )
    p.add_argument(
        "--priors",
        action="store_true",
        help="use the aircraft file's [apriori] values as priors of output error's fit (they "
        "are always judged against: an estimate beyond 3 combined std of one fails the verdict)",
    )
    add_input_arguments(p)
    add_validation_arguments(p)
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--no-figures", action="store_true", help="write report.md without its figures (faster batch runs)")


def options(args: argparse.Namespace) -> EstimateOptions:
    """The estimate's settings from the parsed command line."""
    return EstimateOptions(
        aircraft=args.aircraft,
        map_path=args.map,
        methods=args.method or ["oem"],
        inputs=args.inputs,
        model=args.model,
        quiet=args.quiet,
        figures=not args.no_figures,
        compat=not args.no_compat,
        smooth_inputs=not args.raw_inputs,
        validation_log=args.validate_with,
        time_base=args.time_base,
        input_dynamics=args.input_dynamics,
        segments=segment_items(args.segments) if args.segments else None,
        hold_out=not args.no_holdout,
        accept_low_rate=args.accept_low_rate,
        structure=args.structure,
        priors=args.priors,
        **validation_options(args),
    )


def run(args: argparse.Namespace) -> int:
    from pipeline.jobs.estimate import estimate_log  # the job loads numba, scipy, pandas: on use only

    if args.structure and "ls" not in (args.method or []):
        raise FsidError("--structure searches equation error's regressions: add --method ls")
    log_file(args.log)
    opts = options(args)
    out = new_run_dir("estimate", args.out, inputs=[args.log, *(args.validate_with or []), args.aircraft, args.map])
    with failure_recorded(out, "estimate"):
        paths = estimate_log(args.log, out, opts)
    print_outputs(out, paths)
    return 0
