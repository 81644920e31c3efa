"""``fsid check LOG [--aircraft A.toml]``: ingest a log, run the data-quality checks (and,
when the log has the channels, the sensor-compatibility reconstruction), write
``checks.json`` and the canonical data (``canonical.csv``: every canonical channel
resampled to one time base), and end with whether each axis can be identified and why not
(:mod:`pipeline.conditioning.identifiability`, the same verdict ``fsid estimate`` refuses
with)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from pipeline.commands.arguments import SEGMENTS_HELP, add_time_base_argument, log_file, positive_number, segment_items
from pipeline.errors import FsidError
from pipeline.ingest.sampling import MAX_GRID_HZ
from pipeline.jobs.failures import failure_recorded
from pipeline.paths import new_run_dir

HELP = "ingest a flight log, check its data quality and sensor compatibility, and whether each axis can be identified"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", help="flight log: .mcap, .bin, .tlog, .ulg, .csv or .npz (an archive of named windows)")
    parser.add_argument(
        "--map", default=None, help="channel map (built-in name or TOML file; default: built-in for the format)"
    )
    parser.add_argument(
        "--aircraft",
        default=None,
        help="aircraft TOML: its [servos] travel decodes servo PWM (30 deg assumed without), its "
        "[sensors.imu|airdata] position_m place the sensors, its [propulsion] max_thrust_N turns "
        "throttle into thrust (default: a truth.json next to the log)",
    )
    parser.add_argument("--out", default=None, help="output folder (default: a new folder under ./runs/)")
    parser.add_argument(
        "--rate",
        type=positive_number(MAX_GRID_HZ, "Hz"),
        default=None,
        help="rate of canonical.csv in Hz (default: fastest core channel, at most 100)",
    )
    parser.add_argument("--segments", default=None, help=f"'mode', 'auto' or {SEGMENTS_HELP}")
    add_time_base_argument(parser)
    parser.add_argument("--no-compat", action="store_true", help="skip the sensor-compatibility fit")
    parser.add_argument(
        "--imu-pos",
        default=None,
        metavar="X,Y,Z",
        help="IMU position from the CG, body axes, m (default: the aircraft TOML's [sensors.imu], else a "
        "truth.json next to the log, else 0,0,0)",
    )
    parser.add_argument(
        "--boom-pos",
        default=None,
        metavar="X,Y,Z",
        help="air-data boom position from the CG, body axes, m (default as --imu-pos)",
    )


def _vec(text: str | None, name: str):
    if text is None:
        return None
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise FsidError(f"{name} '{text}' is not three numbers x,y,z in metres; e.g. {name} 0.8,0,0.05")
    return v


def _positions(log: Path, args) -> tuple[list[float], list[float], str]:
    """(IMU, boom positions [m], where they came from): the command line's, else the
    aircraft TOML's [sensors], else a truth.json's next to the log, else 0,0,0."""
    imu, boom = _vec(args.imu_pos, "--imu-pos"), _vec(args.boom_pos, "--boom-pos")
    origin = "command line" if imu or boom else "default 0,0,0"
    if args.aircraft and (imu is None or boom is None):
        from pipeline.ingest.aircraft import load_aircraft_toml  # loads the simulator's aircraft reader

        sens = load_aircraft_toml(args.aircraft)[2]
        if sens:
            imu, boom = imu or sens.get("imu"), boom or sens.get("airdata")
            origin = f"{args.aircraft} [sensors]"
    tj = log.parent / "truth.json"
    if (imu is None or boom is None) and tj.is_file():
        try:
            sens = json.loads(tj.read_text()).get("sensors", {})
            imu = imu or sens.get("imu", {}).get("position_m")
            boom = boom or sens.get("airdata", {}).get("position_m")
            origin = f"{tj} (sensor positions)"
        except (ValueError, AttributeError):
            pass
    return list(imu or [0.0, 0.0, 0.0]), list(boom or [0.0, 0.0, 0.0]), origin


def _segments(spec: str | None):
    if spec is None or spec in ("mode", "auto"):
        return spec
    return segment_items(spec)


def run(args: argparse.Namespace) -> int:
    from pipeline.jobs.check import check_log  # the job loads numba, scipy, pandas: on use only

    log = log_file(args.log)
    out = new_run_dir("check", args.out, inputs=[log, args.map, args.aircraft])
    with failure_recorded(out, "check"):
        return check_log(
            log,
            out,
            map_path=args.map,
            segments=_segments(args.segments),
            time_base=args.time_base,
            compat=not args.no_compat,
            rate=args.rate,
            positions=None if args.no_compat else _positions(log, args),
            aircraft=args.aircraft,
        )
