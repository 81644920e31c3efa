"""``fsid response LOG --input U --output Y [--input ... --output ...] [--segments ...]
[--band LO:HI] [--fit M/N [--delay]]``: frequency responses with coherence over the airborne
time or the given windows of any log the ingest reads, and a transfer-function (LOES with
1/2) fit when asked. The work is :func:`pipeline.jobs.response.response_log`."""

from __future__ import annotations

import argparse
import math

from pipeline.commands.arguments import SEGMENTS_HELP, add_time_base_argument, log_file, print_outputs, segment_items
from pipeline.errors import FsidError
from pipeline.ingest.flightdata import CANONICAL_UNITS
from pipeline.jobs.failures import failure_recorded
from pipeline.paths import new_run_dir

HELP = "frequency responses (Bode, coherence, random error) of outputs to inputs, with a transfer-function/LOES fit"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", help="flight log: .mcap, .bin, .tlog, .ulg, .csv or .npz")
    parser.add_argument(
        "--input",
        action="append",
        required=True,
        help="input channel (canonical name: de, da, dr, ...); repeat for several",
    )
    parser.add_argument(
        "--output", action="append", required=True, help="output channel (canonical name: q, p, r, az, ...); repeat"
    )
    parser.add_argument("--segments", default=None, help=f"{SEGMENTS_HELP} (default: the airborne time)")
    parser.add_argument(
        "--band", default=None, metavar="LO:HI", help="frequency band in Hz (default: what the windows resolve)"
    )
    parser.add_argument(
        "--fit",
        default=None,
        metavar="M/N",
        help="fit a transfer function of M zeros and N poles to each pair (1/2: the short-period LOES figures too)",
    )
    parser.add_argument("--delay", action="store_true", help="the fitted transfer function has a time delay")
    parser.add_argument("--map", default=None, help="channel map (built-in name or TOML file)")
    parser.add_argument("--aircraft", default=None, help="aircraft TOML (its [servos] travel decodes servo PWM)")
    add_time_base_argument(parser)
    parser.add_argument("--out", default=None, help="output folder (default: a new folder under ./runs/)")
    parser.add_argument("--no-figures", action="store_true", help="write no figures")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def _pair(text: str | None, what: str, kind: type) -> tuple | None:
    if text is None:
        return None
    sep = ":" if what == "--band" else "/"
    try:
        a, b = (kind(x) for x in text.split(sep))
    except ValueError:
        example = "0.1:5" if what == "--band" else "1/2"
        raise FsidError(f"{what} '{text}' is not two numbers separated by '{sep}'; e.g. {what} {example}") from None
    if kind is float and not (math.isfinite(a) and math.isfinite(b)):
        raise FsidError(f"{what} '{text}': give finite frequencies in Hz")
    return a, b


def _channels(names: list[str], what: str) -> list[str]:
    bad = [n for n in names if n not in CANONICAL_UNITS]
    if bad:
        raise FsidError(
            f"{what} {', '.join(bad)}: not a canonical channel; use names such as {', '.join(list(CANONICAL_UNITS)[:14])} "
            "(fsid fields LOG lists what a log fills)"
        )
    return list(dict.fromkeys(names))


def run(args: argparse.Namespace) -> int:
    from pipeline.jobs.response import ResponseOptions, response_log  # numerics: on use only

    log = log_file(args.log)
    inputs, outputs = _channels(args.input, "--input"), _channels(args.output, "--output")
    both = set(inputs) & set(outputs)
    if both:
        raise FsidError(f"{', '.join(sorted(both))} given as both --input and --output; a channel is one or the other")
    fit = _pair(args.fit, "--fit", int)
    if fit is not None and not (0 <= fit[0] <= fit[1] and fit[1] >= 1):
        raise FsidError(f"--fit {args.fit}: give M/N with 0 <= M <= N and N >= 1 (e.g. 1/2 for the short-period LOES)")
    if args.delay and fit is None:
        raise FsidError("--delay needs --fit M/N")
    opts = ResponseOptions(
        inputs=inputs,
        outputs=outputs,
        segments=segment_items(args.segments) if args.segments else None,
        map_path=args.map,
        aircraft=args.aircraft,
        time_base=args.time_base,
        band=_pair(args.band, "--band", float),
        fit=fit,
        delay=args.delay,
        quiet=args.quiet,
        figures=not args.no_figures,
    )
    out = new_run_dir("response", args.out, inputs=[log, args.map, args.aircraft])
    with failure_recorded(out, "response"):
        paths = response_log(log, out, opts)
    print_outputs(out, paths)
    return 0
