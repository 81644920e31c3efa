"""Nonlinear longitudinal point-mass-plus-pitch model in stability axes.

States  V (m/s), alpha (rad), theta (rad), q (rad/s)
Inputs  de (rad), thrust (N)
Outputs V, alpha, theta, q, qdot (rad/s^2), ax, az (m/s^2, body-axis specific force at the CG)

Aerodynamics (rates nondimensionalised with cbar/(2V)):
    CL = CL0 + CLalpha alpha + CLq q cbar/(2V) + CLde de
    CD = CD0 + CDalpha alpha + CDalpha2 alpha^2 + CDde de
    Cm = Cm0 + Cmalpha alpha + Cmq q cbar/(2V) + Cmde de
Thrust acts at angle ``sigmaT`` (rad, up from body x) with its line ``zT`` (m) below the
CG. Wings level, no sideslip: flight-path angle gamma = theta - alpha.

Constants: m (kg), Iyy (kg m^2), S (m^2), cbar (m), rho (kg/m^3); optional g (m/s^2,
default 9.80665), sigmaT (rad, 0), zT (m, 0), and the sensor positions in body axes
from the CG (m, default 0): x_vane, z_vane (air data: V and alpha are observed there,
u + q z, w - q x) and x_imu, z_imu (accelerometer: ax + qdot z - q^2 x, az - qdot x - q^2 z).
"""
from __future__ import annotations

from typing import Iterable, Mapping

import numpy as np
from numba.extending import register_jitable

from estimators.model import Model
from estimators.models._build import make_parameters, require_constants

LONGITUDINAL_DEFAULTS: dict[str, float] = {
    "CD0": 0.03, "CDalpha": 0.2, "CDalpha2": 0.0, "CDde": 0.0,
    "CL0": 0.2, "CLalpha": 5.0, "CLq": 0.0, "CLde": 0.4,
    "Cm0": 0.0, "Cmalpha": -0.8, "Cmq": -15.0, "Cmde": -1.5,
}
DEFAULT_FREE = ("CD0", "CDalpha", "CL0", "CLalpha", "CLde", "Cm0", "Cmalpha", "Cmq", "Cmde")


@register_jitable
def _loads(V, alpha, q, de, thrust, p, c):
    """Lift, drag (N), pitching moment (N m) and total thrust-axis terms."""
    qbar = 0.5 * c.rho * V * V
    qhat = q * c.cbar / (2.0 * V)
    CL = p.CL0 + p.CLalpha * alpha + p.CLq * qhat + p.CLde * de
    CD = p.CD0 + p.CDalpha * alpha + p.CDalpha2 * alpha * alpha + p.CDde * de
    Cm = p.Cm0 + p.Cmalpha * alpha + p.Cmq * qhat + p.Cmde * de
    L = qbar * c.S * CL
    D = qbar * c.S * CD
    M = qbar * c.S * c.cbar * Cm + c.zT * thrust
    return L, D, M


def f(x, u, p, c):
    V, alpha, theta, q = x
    de, thrust = u
    L, D, M = _loads(V, alpha, q, de, thrust, p, c)
    gam = theta - alpha
    Vdot = (thrust * np.cos(alpha + c.sigmaT) - D) / c.m - c.g * np.sin(gam)
    alphadot = q + (-L - thrust * np.sin(alpha + c.sigmaT)) / (c.m * V) + c.g * np.cos(gam) / V
    return Vdot, alphadot, q, M / c.Iyy


def g(x, u, p, c):
    V, alpha, theta, q = x
    de, thrust = u
    L, D, M = _loads(V, alpha, q, de, thrust, p, c)
    qdot = M / c.Iyy
    ca, sa = np.cos(alpha), np.sin(alpha)
    ax = (thrust * np.cos(c.sigmaT) + L * sa - D * ca) / c.m
    az = (-thrust * np.sin(c.sigmaT) - L * ca - D * sa) / c.m
    # sensors away from the CG: air-data vane/pitot at (x_vane, z_vane), IMU at (x_imu, z_imu)
    ub = V * ca + q * c.z_vane
    wb = V * sa - q * c.x_vane
    ax_s = ax + qdot * c.z_imu - q * q * c.x_imu
    az_s = az - qdot * c.x_imu - q * q * c.z_imu
    return np.sqrt(ub * ub + wb * wb), np.arctan2(wb, ub), theta, q, qdot, ax_s, az_s


def longitudinal(constants: Mapping[str, float], values: Mapping[str, float] | None = None,
                 free: Iterable[str] | None = None,
                 bounds: Mapping[str, tuple[float, float]] | None = None,
                 output_biases: Iterable[str] = (), name: str = "longitudinal") -> Model:
    """The nonlinear longitudinal model.

    constants : m, Iyy, S, cbar, rho (SI); g, sigmaT, zT optional.
    values : start values by derivative name (defaults in ``LONGITUDINAL_DEFAULTS``).
    free : names to estimate (default CD0 CDalpha CL0 CLalpha CLde Cm0 Cmalpha Cmq Cmde;
        the others are held at their values).
    output_biases : outputs that get a per-segment bias ``bias_<output>[k]``.
    """
    c = require_constants(constants, ("m", "Iyy", "S", "cbar", "rho"), "longitudinal")
    for k, v in {"g": 9.80665, "sigmaT": 0.0, "zT": 0.0, "x_vane": 0.0, "z_vane": 0.0,
                 "x_imu": 0.0, "z_imu": 0.0}.items():
        c.setdefault(k, v)
    params = make_parameters(LONGITUDINAL_DEFAULTS, values, free, DEFAULT_FREE, bounds)
    return Model(states=["V", "alpha", "theta", "q"], inputs=["de", "thrust"],
                 outputs=["V", "alpha", "theta", "q", "qdot", "ax", "az"],
                 parameters=params, constants=c, f=f, g=g, output_biases=list(output_biases),
                 name=name)
