"""Errors the CLI turns into one clear line and a non-zero exit."""

from __future__ import annotations

import errno
import unicodedata

from estimators.errors import DIVERGE_HINT, EstimationError

#: the estimators' advice in Python-API terms -> what a command-line user does instead
CLI_ADVICE = {
    DIVERGE_HINT: (
        "Check the units and signs of the log's channels and of the aircraft file's a-priori "
        "values (they are the start values); for an unstable aircraft use --method fem, ekf or "
        "ukf, which keep the simulation bounded."
    ),
    "Call Segment.split_at_gaps() and fit the pieces as a list of segments": (
        "Give --segments that leave the gap out (fsid check lists the gaps)"
    ),
}


def visible(text: str, keep: str = "\n\t") -> str:
    """``text`` with its control and format characters (ESC, bidirectional overrides, NUL,
    ...) written as escapes (``\\x1b``, ``\\u202e``): names read from a log or a file reach
    the terminal and error.txt as text, never as commands to the terminal. The characters
    in ``keep`` (newlines and tabs) stay."""
    return "".join(
        c.encode("unicode_escape").decode("ascii") if c not in keep and unicodedata.category(c) in ("Cc", "Cf") else c
        for c in text
    )


class VisibleStream:
    """A text stream writing through :func:`visible`: whatever a command prints, a name
    from a log with control characters in it reaches the terminal as text. A write of a
    lone carriage return (``print(..., end="\\r")`` of a progress line redrawing itself)
    stays one."""

    def __init__(self, stream) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        self.stream.write(text if text == "\r" else visible(text))
        return len(text)

    def __getattr__(self, name: str):
        return getattr(self.stream, name)


class FsidError(Exception):
    """A user-facing failure: the message says what went wrong, where, and what to do.

    The CLI prints ``fsid: error: <message>`` and exits with ``exit_code``.
    """

    exit_code = 2

    def __init__(self, message: str, *, exit_code: int | None = None) -> None:
        super().__init__(message)
        if exit_code is not None:
            self.exit_code = exit_code


class Terminated(KeyboardInterrupt):
    """A termination signal (SIGTERM: ``timeout``'s and the schedulers' default) taken as
    an interruption, so that the output folder says where the run stopped.

    ``requested`` stays set once the signal came: an exception raised while C code runs a
    Python callback is lost there, so each progress step raises it again."""

    requested = False


#: the write failures a user can act on: a full disk or quota, a file size limit, a
#: read-only file system
_WRITE_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS)
#: what to do about one
WRITE_REMEDY = "free space on that disk (or raise the file size limit), or give another --out"

#: the errors whose message is written for the user (what, where, what to do)
USER_ERRORS = (FsidError, EstimationError)


def cli_advice(text: str) -> str:
    """``text`` with the estimators' Python-API advice (:data:`CLI_ADVICE`) put in
    command-line terms."""
    for api, cli in CLI_ADVICE.items():
        text = text.replace(api, cli)
    return text


def describe(exc: Exception) -> str:
    """The one line the command line gives for ``exc``: a user error's own message, else
    the unexpected error named, with how to see its traceback."""
    if isinstance(exc, USER_ERRORS):
        return visible(cli_advice(str(exc)))
    if is_write_failure(exc):
        where = f" {exc.filename}" if exc.filename else ""
        return visible(f"cannot write{where}: {exc.strerror or exc}; {WRITE_REMEDY}")
    return visible(f"unexpected {type(exc).__name__}: {exc} (rerun with FSID_DEBUG=1 for the traceback and report it)")


def is_write_failure(exc: BaseException) -> bool:
    """Whether ``exc`` is a write the user can make succeed (_WRITE_ERRNOS): a user error,
    exit 2, not a bug."""
    return isinstance(exc, OSError) and exc.errno in _WRITE_ERRNOS
