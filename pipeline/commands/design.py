"""``fsid design --aircraft A.toml --inputs de,da,dr --band LO:HI --duration S
[--amplitude de=3deg,...] [--speed M/S] [--altitude M] [--rate HZ]``: mutually orthogonal
multisine inputs for the flight, and the accuracy each derivative would get from them. The
work is :func:`pipeline.jobs.design.design`."""

from __future__ import annotations

import argparse
import math

from pipeline.commands.arguments import band_hz, log_file, positive_number, print_outputs
from pipeline.errors import FsidError
from pipeline.jobs.failures import failure_recorded
from pipeline.paths import new_run_dir

HELP = "design mutually orthogonal multisine inputs and predict the accuracy they give"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--aircraft", required=True, help="aircraft TOML (geometry, mass, [apriori] derivatives)")
    parser.add_argument("--inputs", required=True, help="the surfaces to move at once, e.g. de,da,dr")
    parser.add_argument("--band", required=True, metavar="LO:HI", help="frequency band in Hz, e.g. 0.1:2.0")
    parser.add_argument("--duration", type=positive_number(3600.0, "s"), required=True, help="length of the input in s")
    parser.add_argument(
        "--rate", type=positive_number(1000.0, "Hz"), default=50.0, help="sample rate of inputs.csv (Hz)"
    )
    parser.add_argument(
        "--amplitude", default=None, help="peak per input, e.g. de=3deg,da=5deg (deg or rad; default 3 deg each)"
    )
    parser.add_argument("--speed", type=positive_number(400.0, "m/s"), default=None, help="trim airspeed in m/s")
    parser.add_argument("--altitude", type=float, default=100.0, help="altitude in m (ISA density; default 100)")
    parser.add_argument(
        "--log",
        default=None,
        help="a previous flight of the aircraft: the prediction adds the new flight's information to what it knows",
    )
    parser.add_argument("--out", default=None, help="output folder (default: a new folder under ./runs/)")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def _amplitudes(text: str | None) -> dict[str, float] | None:
    if not text:
        return None
    out = {}
    for item in text.split(","):
        name, _, value = item.partition("=")
        v = value.strip().lower()
        scale = math.pi / 180 if v.endswith("deg") else 1.0
        try:
            a = float(v.removesuffix("deg").removesuffix("rad")) * scale
        except ValueError:
            raise FsidError(f"--amplitude '{item}' is not NAME=VALUE[deg|rad]; e.g. de=3deg") from None
        if not (math.isfinite(a) and a > 0):
            raise FsidError(f"--amplitude '{item}': give a peak above 0")
        out[name.strip()] = a
    return out


def run(args: argparse.Namespace) -> int:
    from pipeline.jobs.design import DesignOptions, design  # numerics: on use only

    opts = DesignOptions(
        aircraft=args.aircraft,
        inputs=[s.strip() for s in args.inputs.split(",") if s.strip()],
        band=band_hz(args.band),
        duration=args.duration,
        rate=args.rate,
        amplitude=_amplitudes(args.amplitude),
        speed=args.speed,
        altitude=args.altitude,
        log=str(log_file(args.log)) if args.log else None,
        quiet=args.quiet,
    )
    out = new_run_dir("design", args.out, inputs=[args.aircraft, args.log])
    with failure_recorded(out, "design"):
        paths = design(out, opts)
    print_outputs(out, paths)
    return 0
