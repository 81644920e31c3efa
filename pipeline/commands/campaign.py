"""``fsid campaign SCENARIO.toml --seeds 1:200 [--vary key=v1,v2 ...] [--method ...]
[--scheduler ADDR | --workers N] --out DIR``: Monte Carlo of simulate + estimate over seeds
and varied scenario keys as Dask tasks; bias, efficiency and coverage per method and
parameter. The work is :func:`pipeline.jobs.campaign.campaign`."""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.commands.arguments import add_cluster_arguments, print_outputs
from pipeline.errors import FsidError
from pipeline.jobs.failures import failure_recorded
from pipeline.paths import new_run_dir
from pipeline.registry import METHODS

HELP = "Monte Carlo of a scenario over seeds and varied keys as Dask tasks: bias, std ratio, coverage"

#: at most this many flights in one campaign
MAX_FLIGHTS = 100_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", help="scenario TOML (scenarios/*.toml)")
    parser.add_argument("--seeds", required=True, metavar="A:B", help="seeds A to B inclusive (or one seed N)")
    parser.add_argument(
        "--vary",
        action="append",
        default=[],
        metavar="KEY=V1,V2",
        help="a scenario key (dotted: turbulence.severity, maneuver.amplitude_deg) and its values; repeatable: "
        "every combination is flown",
    )
    parser.add_argument("--method", action="append", choices=METHODS, help="estimation method (repeatable)")
    add_cluster_arguments(parser)
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--out", default=None, help="output folder (default: a new folder under ./runs/)")


def seeds(text: str) -> list[int]:
    """``A:B`` (inclusive) or ``N``."""
    try:
        a, _, b = text.partition(":")
        lo, hi = int(a), int(b or a)
    except ValueError:
        raise FsidError(f"--seeds {text!r}: give A:B (inclusive) or one seed, whole numbers") from None
    if not 0 <= lo <= hi < 2**31:
        raise FsidError(f"--seeds {text}: give 0 <= A <= B")
    return list(range(lo, hi + 1))


def varied(items: list[str]) -> dict[str, list]:
    """``KEY=V1,V2`` items -> {key: [values]} (values read as TOML: numbers, booleans, words)."""
    from pipeline.jobs.campaign import parse_value

    out = {}
    for it in items:
        key, eq, values = it.partition("=")
        if not eq or not key.strip() or not values.strip():
            raise FsidError(f"--vary {it!r}: give KEY=V1,V2 (e.g. turbulence.severity=light,moderate)")
        out[key.strip()] = [parse_value(v.strip()) for v in values.split(",") if v.strip()]
    return out


def run(args: argparse.Namespace) -> int:
    from pipeline.jobs.campaign import CampaignOptions, campaign  # dask, JSBSim: on use only

    path = Path(args.scenario)
    if not path.is_file():
        raise FsidError(f"scenario {path} not found; give a scenario TOML (see scenarios/)")
    s, vary = seeds(args.seeds), varied(args.vary)
    n = len(s)
    for v in vary.values():
        n *= len(v)
    if n > MAX_FLIGHTS:
        raise FsidError(f"the campaign would fly {n} flights (more than {MAX_FLIGHTS}): fewer seeds or values")
    opts = CampaignOptions(
        scenario=path,
        seeds=s,
        vary=vary,
        methods=args.method,
        scheduler=args.scheduler,
        workers=int(args.workers) if args.workers else None,
        quiet=args.quiet,
    )
    out = new_run_dir("campaign", args.out, inputs=[path])
    with failure_recorded(out, "campaign"):
        paths = campaign(out, opts)
    print_outputs(out, paths)
    return 0
