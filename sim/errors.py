"""Errors of the simulation package."""

from __future__ import annotations


class ScenarioError(ValueError):
    """A scenario or aircraft file is malformed or describes an impossible flight.

    The message is one line: what is wrong, where (file and key), and what to do.
    """
