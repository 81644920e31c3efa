"""``fsid aircraft init [PATH] [--force]``: write the commented aircraft-file template;
``fsid aircraft check PATH``: read an aircraft file as ``fsid estimate --aircraft`` does and
say what it gives (docs/aircraft.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.errors import FsidError
from pipeline.ingest.aircraft_file import TEMPLATE, AircraftFile, read_aircraft_file
from pipeline.paths import atomic_write_text

HELP = "write an aircraft-file template (init) or check an aircraft file (check)"
#: where ``fsid aircraft init`` writes without a PATH
DEFAULT_PATH = "aircraft.toml"


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    init = sub.add_parser(
        "init",
        help="write a commented aircraft-file template to fill in",
        description="write a commented aircraft-file template ([geometry], [mass], [propulsion], "
        "[servos], [sensors], [signs], [apriori]) to fill in with your aircraft's numbers",
    )
    init.add_argument("path", nargs="?", default=DEFAULT_PATH, help=f"file to write (default: {DEFAULT_PATH})")
    init.add_argument("--force", action="store_true", help="overwrite the file when it exists")
    check = sub.add_parser(
        "check",
        help="read an aircraft file and say what it gives",
        description="read an aircraft file as "
        "fsid estimate --aircraft does; print what it gives, or the first problem in it",
    )
    check.add_argument("path", help="aircraft file (.toml)")


def run(args: argparse.Namespace) -> int:
    if args.action == "init":
        return _init(Path(args.path), args.force)
    if args.action == "check":
        print(summary(read_aircraft_file(args.path)))
        return 0
    raise FsidError("fsid aircraft: give an action: init [PATH] (write a template) or check PATH")


def _init(path: Path, force: bool) -> int:
    """Write the template to ``path`` (atomically; an existing file only with ``force``)."""
    if path.is_dir():
        raise FsidError(f"{path} is a directory; give the path of the .toml file to write")
    if path.exists() and not force:
        raise FsidError(f"{path} exists; give another path, or --force to overwrite it")
    if not path.parent.is_dir():
        raise FsidError(f"folder {path.parent} does not exist; create it or give another path")
    atomic_write_text(path, TEMPLATE.read_text())
    print(
        f"wrote {path}: fill in your aircraft's numbers (every key: docs/aircraft.md), then fsid aircraft check {path}"
    )
    return 0


def summary(af: AircraftFile) -> str:
    """What an aircraft file gives, in a few lines."""
    c = af.constants
    lines = [
        f"aircraft {af.name!r} ({af.path}){': a scenario truth set' if af.truth_set else ''}",
        f"  geometry S {c.S:g} m^2, b {c.b:g} m, cbar {c.cbar:g} m; mass {c.mass:g} kg, "
        f"Ixx {c.Ixx:g} Iyy {c.Iyy:g} Izz {c.Izz:g} Ixz {c.Ixz:g} kg m^2",
    ]
    if c.thrust_table is not None:
        lines.append(f"  thrust: map of {len(c.thrust_table[0])} points, {max(c.thrust_table[1]):g} N at most")
    elif c.max_thrust:
        lines.append(f"  thrust: throttle x {c.max_thrust:g} N")
    else:
        lines.append("  thrust: none given (the log's thrust channel, or gliding maneuvers)")
    travel = ", ".join(f"{a} {deg:g} deg" for a, (deg, _) in af.servo_travel.items())
    lines.append(f"  servo travel: {travel or 'none given (30 deg assumed for servo PWM)'}")
    pos = ", ".join(f"{n} ({', '.join(f'{x:g}' for x in p)}) m" for n, p in af.sensors.items())
    lines.append(f"  sensor positions: {pos or 'none given'}")
    rev = ", ".join(c.reversed_inputs)
    own = "fsid's convention (docs/aircraft.md)"
    lines.append(f"  sign conventions: {'reversed on ' + rev if rev else own}")
    signs = c.expected_signs()
    lines.append(
        "  signs the verdict expects: " + ", ".join(f"{n} {'>' if s > 0 else '<'} 0" for n, s in signs.items())
    )
    if c.apriori:
        lines.append(
            "  a-priori values: " + ", ".join(f"{n} {d['value']:g} +- {d['std']:.3g}" for n, d in c.apriori.items())
        )
    return "\n".join(lines)
