"""``fsid live SOURCE --aircraft A.toml [--map M]`` or ``fsid live --replay LOG [--speed N|max]``:
identification while flying, from a MAVLink stream (udpin:, udp:, tcp:, a serial device) or
a replayed log; the estimates each second, written at the end. The work is
:func:`pipeline.jobs.live.live`."""

from __future__ import annotations

import argparse

from pipeline.commands.arguments import band_hz, log_file, positive_number, print_outputs
from pipeline.errors import FsidError
from pipeline.jobs.failures import failure_recorded
from pipeline.paths import new_run_dir

HELP = "identify while flying: frequency-domain equation error per axis on a MAVLink stream or a replayed log"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "source",
        nargs="?",
        default=None,
        help="MAVLink source: udpin:0.0.0.0:14550, udp:HOST:PORT, tcp:HOST:PORT or a serial device /dev/ttyUSB0,57600",
    )
    parser.add_argument("--replay", default=None, metavar="LOG", help="replay a log file instead of a stream")
    parser.add_argument(
        "--speed",
        default="1",
        metavar="N|max",
        help="replay speed: times real time, or max (as fast as it goes); default 1",
    )
    parser.add_argument("--aircraft", default=None, help="aircraft TOML (mass, inertia, geometry, servo travel)")
    parser.add_argument("--map", default=None, help="channel map (built-in name or TOML file)")
    parser.add_argument("--band", default="0.1:2.0", metavar="LO:HI", help="frequency band in Hz (default 0.1:2.0)")
    parser.add_argument(
        "--target",
        type=positive_number(1.0, ""),
        default=0.1,
        help="a derivative is enough when its std falls below this share of its value (default 0.1)",
    )
    parser.add_argument(
        "--idle",
        type=positive_number(86400.0, "s"),
        default=None,
        help="stop a stream after this many s without a packet",
    )
    parser.add_argument("--viewer", action="store_true", help="spawn a rerun viewer showing the estimates live")
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--out", default=None, help="output folder (default: a new folder under ./runs/)")


def _speed(text: str) -> float | None:
    if text == "max":
        return None
    try:
        v = float(text)
    except ValueError:
        raise FsidError(f"--speed {text!r}: give a number (times real time) or max") from None
    if not 0 < v < 1e6:
        raise FsidError(f"--speed {text}: give a positive number or max")
    return v


def run(args: argparse.Namespace) -> int:
    from pipeline.jobs.live import LiveOptions, live  # numerics, rerun: on use only

    if (args.source is None) == (args.replay is None):
        raise FsidError("fsid live: give a MAVLink SOURCE (e.g. udpin:0.0.0.0:14550) or --replay LOG, one of them")
    if args.replay is not None:
        log_file(args.replay)
    elif args.aircraft is None:
        raise FsidError("fsid live on a stream needs --aircraft A.toml (mass, inertia, geometry of the aircraft)")
    opts = LiveOptions(
        source=args.source,
        replay=args.replay,
        speed=_speed(args.speed),
        aircraft=args.aircraft,
        map_path=args.map,
        band=band_hz(args.band),
        target=args.target,
        idle=args.idle,
        viewer=args.viewer,
        quiet=args.quiet,
    )
    out = new_run_dir("live", args.out, inputs=[args.replay, args.aircraft, args.map])
    with failure_recorded(out, "live"):
        paths = live(out, opts)
    print_outputs(out, paths)
    return 0
