"""One module per ``fsid`` sub-command.

Each module exposes ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``.
``pipeline.cli`` imports them lazily, so a slow import (jsbsim, rerun) costs only the
command that needs it.
"""

#: sub-command name -> module under pipeline.commands
COMMANDS: dict[str, str] = {
    "demo": "demo",
    "simulate": "simulate",
    "check": "check",
    "estimate": "estimate",
    "run": "run",
    "view": "view",
}
