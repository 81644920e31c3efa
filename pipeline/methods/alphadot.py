"""When a fit holds the angle-of-attack-rate derivatives (CLalphadot, Cmalphadot) at 0: the
flight does not separate them from the damping derivatives CLq, Cmq. The gust angle of
attack separates alphadot from q only where the turbulence is strong against the maneuver;
otherwise CLq and Cmq carry their effect."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

#: (damping, angle-of-attack-rate) derivative pairs of the gust models
ALPHADOT_PAIRS = (("CLq", "CLalphadot"), ("Cmq", "Cmalphadot"))
#: |correlation| of a pair above which the flight does not separate them (the report's
#: flag of near-linear dependence)
ALPHADOT_CORR = 0.9


def free_alphadot(model: Any) -> list[str]:
    """The alphadot derivatives of ``model`` that are free."""
    return [b for _, b in ALPHADOT_PAIRS if b in model.parameter_names and model.parameter(b).free]


def unidentifiable_alphadot(exc: Any, alphadot: Sequence[str]) -> str | None:
    """The note for holding CLalphadot, Cmalphadot at 0 when a fit with them free stopped on
    a singular information matrix that names one of them (an IdentifiabilityError), else
    None."""
    named = [n for n in (getattr(exc, "parameters", None) or []) if n in alphadot]
    if not named:
        return None
    return (
        "CLalphadot, Cmalphadot held at 0: this flight does not separate them from CLq, "
        f"Cmq (with them free the information matrix was singular in {', '.join(named)}), "
        "so CLq and Cmq carry their effect (Cmq estimates about Cmq + Cmalphadot)"
    )


def inseparable_alphadot(res: Any) -> str | None:
    """The note for holding CLalphadot, Cmalphadot at 0 when a fit with them free could not
    separate them from CLq, Cmq (|correlation| above :data:`ALPHADOT_CORR` for either
    pair), else None."""
    free = set(res.free_names)
    pairs = [(a, b) for a, b in ALPHADOT_PAIRS if a in free and b in free]
    if not pairs:
        return None
    corr = res.corr
    r = {f"{a}~{b}": float(corr.loc[a, b]) for a, b in pairs}
    if max(abs(v) for v in r.values()) <= ALPHADOT_CORR:
        return None
    return (
        "CLalphadot, Cmalphadot held at 0: this flight does not separate them from CLq, "
        f"Cmq (correlation {', '.join(f'{k} {v:+.2f}' for k, v in r.items())} with them "
        "free), so CLq and Cmq carry their effect (Cmq estimates about Cmq + Cmalphadot)"
    )
