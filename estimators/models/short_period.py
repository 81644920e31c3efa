"""Linear short-period model (perturbations from trim), nondimensional derivatives.

States  alpha (rad), q (rad/s); input de (rad); outputs alpha, q, qdot (rad/s^2), az (m/s^2).
All signals are perturbations from the trim point (subtract trim values, or add
per-segment output biases). With qbar = rho V^2 / 2 and qhat = q cbar / (2 V):

    alphadot = q - qbar S / (m V) (CLalpha alpha + CLq qhat + CLde de)
    qdot     = qbar S cbar / Iyy (Cmalpha alpha + Cmq qhat + Cmde de)
    az       = -qbar S / m (CLalpha alpha + CLq qhat + CLde de)

Constants: m, Iyy, S, cbar, rho, V (trim true airspeed, m/s).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from numba.extending import register_jitable

from estimators.model import Model
from estimators.models._build import make_parameters, require_constants

DEFAULTS = {"CLalpha": 5.0, "CLq": 0.0, "CLde": 0.4, "Cmalpha": -0.8, "Cmq": -15.0, "Cmde": -1.5}
DEFAULT_FREE = ("CLalpha", "CLde", "Cmalpha", "Cmq", "Cmde")


@register_jitable
def _accels(alpha, q, de, p, c):
    """Perturbation normal specific force az = Z/m (m/s^2) and pitch acceleration (rad/s^2)."""
    qbar = 0.5 * c.rho * c.V * c.V
    qhat = q * c.cbar / (2.0 * c.V)
    CL = p.CLalpha * alpha + p.CLq * qhat + p.CLde * de
    Cm = p.Cmalpha * alpha + p.Cmq * qhat + p.Cmde * de
    return -qbar * c.S / c.m * CL, qbar * c.S * c.cbar / c.Iyy * Cm


def f(x, u, p, c):
    alpha, q = x
    (de,) = u
    az, qdot = _accels(alpha, q, de, p, c)
    return q + az / c.V, qdot


def g(x, u, p, c):
    alpha, q = x
    (de,) = u
    az, qdot = _accels(alpha, q, de, p, c)
    return alpha, q, qdot, az


def short_period(
    constants: Mapping[str, float],
    values: Mapping[str, float] | None = None,
    free: Iterable[str] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    output_biases: Iterable[str] = (),
    name: str = "short_period",
) -> Model:
    """The linear short-period model; see the module docstring for equations and units."""
    c = require_constants(constants, ("m", "Iyy", "S", "cbar", "rho", "V"), "short-period")
    return Model(
        states=["alpha", "q"],
        inputs=["de"],
        outputs=["alpha", "q", "qdot", "az"],
        parameters=make_parameters(DEFAULTS, values, free, DEFAULT_FREE, bounds),
        constants=c,
        f=f,
        g=g,
        output_biases=list(output_biases),
        name=name,
    )
