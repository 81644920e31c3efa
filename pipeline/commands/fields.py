"""``fsid fields LOG [--map MAP] [--json]``: the log's message tables and fields, and the
canonical channel each field fills under the channel map (the built-in one for the log's
format by default), then the channels the map could not fill and why. Writes nothing; the
work is :func:`pipeline.jobs.fields.list_fields`."""

from __future__ import annotations

import argparse

from pipeline.commands.arguments import log_file

HELP = "list a log's fields and the canonical channels a channel map makes of them"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", help="flight log: .mcap, .bin, .tlog, .ulg, .csv or .npz (an archive of named windows)")
    parser.add_argument(
        "--map", default=None, help="channel map (built-in name or TOML file; default: built-in for the format)"
    )
    parser.add_argument("--mapped-only", action="store_true", help="list only the tables that fill a canonical channel")
    parser.add_argument("--json", action="store_true", help="print the listing as JSON")


def run(args: argparse.Namespace) -> int:
    from pipeline.jobs.fields import fields_json, format_fields, list_fields  # reads logs: on use only

    lf = list_fields(log_file(args.log), args.map)
    print(fields_json(lf) if args.json else format_fields(lf, all_fields=not args.mapped_only))
    return 0
