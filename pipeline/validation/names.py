"""What parameter names and result keys say: per-segment parameters, method families, axes."""

from __future__ import annotations

from typing import Any

from pipeline.registry import FitKey


def is_segment_parameter(name: str) -> bool:
    """Per-segment parameters (``bias_az[0]``, ``x0_V[1]``): biases and initial states."""
    return name.endswith("]") and "[" in name


def method_group(key: str) -> str:
    """The axis a result key belongs to: "lateral" for "lateral-fem", "" for a bare method
    name (one axis fitted, or a user model)."""
    return FitKey.parse(key).axis


def is_method(name: Any, base: str) -> bool:
    """Whether a method name or result key is of method ``base``: "fem" for "fem",
    "fem-nl" and "lateral-fem"; "ukf" for "ukf-aug"."""
    return FitKey.parse(str(name or "")).base == base
