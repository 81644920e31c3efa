"""One module per ``fsid`` sub-command, plus the options they share
(:mod:`pipeline.commands.arguments`).

Each command module exposes ``HELP`` (one line), ``add_arguments(parser)`` and
``run(args) -> int``. ``pipeline.cli`` builds the parser from every command, so a command
module imports only light modules at its top (the argument helpers, the jobs' option
dataclasses, the method catalogue); its ``run`` imports its job, which loads numba, scipy
and pandas (and the simulator or rerun where needed), when the command is used.
"""

#: sub-command name -> module under pipeline.commands
COMMANDS: dict[str, str] = {
    "demo": "demo",
    "simulate": "simulate",
    "check": "check",
    "fields": "fields",
    "estimate": "estimate",
    "run": "run",
    "response": "response",
    "design": "design",
    "live": "live",
    "batch": "batch",
    "campaign": "campaign",
    "view": "view",
    "aircraft": "aircraft",
}
