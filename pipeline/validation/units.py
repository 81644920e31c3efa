"""Display units of the canonical channels: the human-facing form of an SI value.

Reports and proof-of-match bands read angles in degrees and specific forces in g; the
data and report.json stay SI."""

from __future__ import annotations

import numpy as np

from estimators import validation as V

#: channels shown in degrees (rad -> deg) and degrees per second (rad/s -> deg/s)
ANGLES = frozenset({"alpha", "beta", "phi", "theta", "psi", "de", "da", "dr"})
RATES = frozenset({"p", "q", "r"})
ACCELS = frozenset({"ax", "ay", "az"})
ANG_ACCELS = frozenset({"pdot", "qdot", "rdot"})
#: SI units of the other channels that have one
_SI_UNITS = {
    "V": "m/s",
    "u": "m/s",
    "v": "m/s",
    "w": "m/s",
    "h": "m",
    "qbar": "Pa",
    "rho": "kg/m^3",
    "thrust": "N",
    "throttle": "-",
}


def display_unit(channel: str) -> tuple[float, str]:
    """(factor, unit) turning an SI value of a canonical channel into its human-facing form:
    angles deg, rates deg/s, angular accelerations deg/s^2, specific forces g; else SI."""
    if channel in ANGLES:
        return 180.0 / np.pi, "deg"
    if channel in RATES:
        return 180.0 / np.pi, "deg/s"
    if channel in ANG_ACCELS:
        return 180.0 / np.pi, "deg/s^2"
    if channel in ACCELS:
        return 1.0 / V.match.G0, "g"
    return 1.0, _SI_UNITS.get(channel, "SI")
