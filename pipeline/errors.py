"""Errors the CLI turns into one clear line and a non-zero exit."""

from __future__ import annotations


class FsidError(Exception):
    """A user-facing failure: the message says what went wrong, where, and what to do.

    The CLI prints ``fsid: error: <message>`` and exits with ``exit_code``.
    """

    exit_code = 2

    def __init__(self, message: str, *, exit_code: int | None = None) -> None:
        super().__init__(message)
        if exit_code is not None:
            self.exit_code = exit_code
