"""What parameter names and result keys say: per-segment parameters, method families, axes."""

from __future__ import annotations

from typing import Any


def is_segment_parameter(name: str) -> bool:
    """Per-segment parameters (``bias_az[0]``, ``x0_V[1]``): biases and initial states."""
    return name.endswith("]") and "[" in name


def method_group(key: str) -> str:
    """The axis a result key belongs to: "lateral" for "lateral-fem", "" for a bare method
    name (one axis fitted, or a user model)."""
    return key.rsplit("-", 1)[0] if "-" in key else ""


def is_method(name: Any, base: str) -> bool:
    """Whether a method name or result key is of method ``base``: "fem" for "fem",
    "fem-nl" and "lateral-fem"; "ukf" for "ukf-aug"."""
    return base in str(name or "").split("-")
