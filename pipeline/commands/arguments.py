"""Command-line options shared by several ``fsid`` sub-commands, and how their values are
read."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from pipeline.errors import FsidError


def positive_number(upper: float = math.inf, unit: str = "") -> type:
    """An argparse type: a finite number above 0 and at most ``upper`` (in ``unit``); the
    error says what was given and what is accepted, before any work."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            v = math.nan
        if not (math.isfinite(v) and 0 < v <= upper):
            bound = f" and at most {upper:g}{' ' + unit if unit else ''}" if math.isfinite(upper) else ""
            raise argparse.ArgumentTypeError(f"{text!r} is not a number above 0{bound}")
        return v

    parse.__name__ = "number"
    return parse


def add_time_base_argument(parser: argparse.ArgumentParser) -> None:
    """``--time-base``: the time base of a .tlog or .mcap log (pipeline.ingest.readers.TIME_BASES)."""
    parser.add_argument(
        "--time-base",
        default=None,
        choices=["auto", "boot", "header", "log"],
        help="time base of a .tlog (auto = the autopilot's own stamps, boot = "
        "those only, log = the ground station's receive times) or .mcap "
        "(auto, header = the messages' header stamps, log = log times); "
        "default auto",
    )


SEGMENTS_HELP = (
    "maneuver windows: time ranges T0:T1 in seconds from the log's start (its first sample; "
    "reports, errors and recordings use the same times), segment names as found in the log "
    "(auto_de_0, mode_2_FBWA, ...), or both, comma-separated"
)


def segment_items(text: str) -> list[str | tuple[float, float]]:
    """``--segments`` value: comma-separated items, each T0:T1 (seconds from the log's start)
    or a segment name; FsidError naming the bad item."""
    out: list[str | tuple[float, float]] = []
    for part in (p.strip() for p in text.split(",")):
        if ":" not in part:
            if not part:
                raise FsidError(f"--segments '{text}' has an empty item; e.g. --segments 10:30,45.5:70,auto_de_1")
            out.append(part)
            continue
        try:
            a, b = (float(x) for x in part.split(":"))
        except ValueError:
            raise FsidError(
                f"--segments '{part}' is not T0:T1 (seconds from the log's start); e.g. --segments 10:30,45.5:70"
            ) from None
        if not (math.isfinite(a) and math.isfinite(b) and a < b):
            raise FsidError(f"--segments '{part}': T0 must be below T1 (seconds from the log's start)")
        out.append((a, b))
    return out


def input_dynamics_setting(text: str) -> str | tuple[float, float]:
    """``--input-dynamics`` value: auto, off, or DELAY[,LAG] in seconds (|delay| <= 1,
    0 <= lag <= 1)."""
    if text in ("auto", "off"):
        return text
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) not in (1, 2) or not all(math.isfinite(v) for v in vals):
        raise argparse.ArgumentTypeError(f"{text!r}: give auto, off or DELAY[,LAG] in seconds (e.g. 0.02,0.04)")
    delay, lag = vals[0], (vals[1] if len(vals) == 2 else 0.0)
    if abs(delay) > 1.0 or not 0.0 <= lag <= 1.0:
        raise argparse.ArgumentTypeError(f"{text!r}: the delay must be within -1..1 s and the lag within 0..1 s")
    return delay, lag


def add_input_arguments(p: argparse.ArgumentParser) -> None:
    """Data-preparation options shared by fsid run and fsid estimate."""
    p.add_argument(
        "--raw-inputs",
        action="store_true",
        help="use the logged surface positions (de, da, dr) as they are; by default "
        "those with a flat white noise floor are low-passed zero-phase where it "
        "begins (the corners are in the report's data preparation notes)",
    )
    p.add_argument(
        "--input-dynamics",
        default="auto",
        type=input_dynamics_setting,
        metavar="auto|off|DELAY[,LAG]",
        help="the servo between a logged control input and its surface (a logged "
        "command leads the surface): auto = each surface's delay and first-order "
        "lag estimated from the maneuvers (equation error), applied where "
        "significant and refined by output error's fits when oem is among the "
        "methods, their std carried to the estimates (default); off = inputs "
        "as logged; DELAY[,LAG] = those, in seconds, for every surface",
    )


def add_validation_arguments(p: argparse.ArgumentParser) -> None:
    """Proof-of-match options shared by fsid run and fsid estimate."""
    p.add_argument(
        "--band-rate",
        type=float,
        metavar="DEG_S",
        help="proof-of-match band on p, q, r in deg/s (default 1.5, or the scenario's)",
    )
    p.add_argument("--band-accel", type=float, metavar="G", help="proof-of-match band on ax, ay, az in g (default 0.1)")
    p.add_argument(
        "--band-angle",
        type=float,
        metavar="DEG",
        help="proof-of-match band on alpha, beta, phi, theta, psi in deg (default 1.5)",
    )
    p.add_argument(
        "--proof-of-match",
        default="auto",
        choices=["auto", "simulation", "air-data"],
        help="held-out prediction: open-loop simulation, or the model driven by its "
        "measured air data (turbulence, unstable aircraft); auto picks air-data "
        "for fem/ekf/ukf and unstable models (default)",
    )


def validation_options(args: argparse.Namespace) -> dict:
    """The ``bands`` and ``pom`` settings of the jobs from the parsed options."""
    bands = {
        k: v
        for k, v in (("rate_deg_s", args.band_rate), ("accel_g", args.band_accel), ("angle_deg", args.band_angle))
        if v is not None
    }
    bad = [k for k, v in bands.items() if not v > 0]
    if bad:
        raise FsidError(f"proof-of-match band {bad[0]} must be > 0: give a positive number")
    return {"bands": bands, "pom": args.proof_of_match}


def print_outputs(out: Path, paths: dict[str, Path]) -> None:
    """Where a job wrote its outputs."""
    print(f"wrote {out}/")
    for name, path in paths.items():
        print(f"  {name:<12} {path}")


LOG_KINDS = ".mcap/.bin/.tlog/.ulg/.csv/.npz"


def log_file(arg: str | Path) -> Path:
    """The log path a command was given, checked before any output folder is made: a
    missing path and a directory each get their own message."""
    path = Path(arg)
    if path.is_dir():
        raise FsidError(f"log '{path}' is a directory; give the path of a {LOG_KINDS} file inside it")
    if not path.is_file():
        raise FsidError(f"log '{path}' not found; give the path of a {LOG_KINDS} file")
    return path


def band_hz(text: str) -> tuple[float, float]:
    """A ``--band LO:HI`` value (Hz): 0 <= LO < HI, or one clear error."""
    try:
        lo, hi = (float(x) for x in text.split(":"))
    except ValueError:
        raise FsidError(f"--band '{text}' is not LO:HI in Hz; e.g. --band 0.1:2.0") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo < hi):
        raise FsidError(f"--band {text}: give 0 <= LO < HI in Hz")
    return lo, hi


def add_cluster_arguments(parser: argparse.ArgumentParser) -> None:
    """Where a command's Dask tasks run: ``--scheduler ADDR`` or a local cluster of
    ``--workers N`` (one or the other)."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--scheduler", default=None, metavar="ADDR", help="an existing Dask scheduler, tcp://host:8786")
    where.add_argument(
        "--workers", type=positive_number(1024, "workers"), default=None, help="local cluster size (default: the cores)"
    )
