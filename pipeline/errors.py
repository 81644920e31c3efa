"""Errors the CLI turns into one clear line and a non-zero exit."""

from __future__ import annotations

from estimators.errors import EstimationError


class FsidError(Exception):
    """A user-facing failure: the message says what went wrong, where, and what to do.

    The CLI prints ``fsid: error: <message>`` and exits with ``exit_code``.
    """

    exit_code = 2

    def __init__(self, message: str, *, exit_code: int | None = None) -> None:
        super().__init__(message)
        if exit_code is not None:
            self.exit_code = exit_code


#: the errors whose message is written for the user (what, where, what to do)
USER_ERRORS = (FsidError, EstimationError)


def describe(exc: Exception) -> str:
    """The one line the command line gives for ``exc``: a user error's own message, else
    the unexpected error named, with how to see its traceback."""
    if isinstance(exc, USER_ERRORS):
        return str(exc)
    return f"unexpected {type(exc).__name__}: {exc} (rerun with FSID_DEBUG=1 for the traceback and report it)"
