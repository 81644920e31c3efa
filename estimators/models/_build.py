"""Shared builder for the built-in models: start values, free set and bounds."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from estimators.errors import ModelDefinitionError
from estimators.model import Parameter


def make_parameters(
    defaults: Mapping[str, float],
    values: Mapping[str, float] | None,
    free: Iterable[str] | None,
    default_free: Iterable[str],
    bounds: Mapping[str, tuple[float, float]] | None,
) -> list[Parameter]:
    """Parameters in ``defaults`` order; ``values`` override starts, ``free`` names the
    estimated ones (default ``default_free``), ``bounds`` by name."""
    values = dict(values or {})
    unknown = sorted(set(values) - set(defaults))
    free = set(default_free if free is None else free)
    unknown += sorted(free - set(defaults))
    unknown += sorted(set(bounds or {}) - set(defaults))
    if unknown:
        raise ModelDefinitionError(f"unknown parameter names {sorted(set(unknown))}; this model has {list(defaults)}")
    return [
        Parameter(n, values.get(n, v), n in free, (bounds or {}).get(n, (-float("inf"), float("inf"))))
        for n, v in defaults.items()
    ]


def require_constants(constants: Mapping[str, float], needed: Iterable[str], model: str) -> dict:
    missing = [k for k in needed if k not in constants]
    if missing:
        raise ModelDefinitionError(f"{model} model needs constants {missing} (SI units)")
    return {k: float(v) for k, v in constants.items()}
