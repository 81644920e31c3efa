"""Nonlinear six-degree-of-freedom rigid-body model (flat Earth, calm air, body axes).

States  u, v, w (m/s, body-axis air-relative velocity), p, q, r (rad/s), phi, theta (rad)
Inputs  de, da, dr (rad), thrust (N)
Outputs V (m/s), alpha, beta (rad), p, q, r (rad/s), phi, theta (rad), ax, ay, az (m/s^2,
        specific force)

Aerodynamics with the DESIGN.md derivative names, rates nondimensionalised with
b/(2V) (p, r) and cbar/(2V) (q); lift and drag act in stability axes, side force along
body y:

    CL = CL0 + CLalpha a + CLq qhat + CLde de          CD = CD0 + CDalpha a + CDalpha2 a^2 + CDde de
    CY = CYbeta b + CYp phat + CYr rhat + CYda da + CYdr dr
    Cl, Cn like CY;  Cm = Cm0 + Cmalpha a + Cmq qhat + Cmde de

Thrust acts along body x with its line ``zT`` (m) below the CG. The moment equations keep
Ixz coupling and the gyroscopic terms. Optional CLalphadot, Cmalphadot (alphadot
cbar/(2V); default 0 and held), alphadot solved algebraically for the lift's own
alphadot term. Sensors away from the CG (m, body axes): the air
data at (x_vane, y_vane, z_vane) and the accelerometer at (x_imu, 0, z_imu), with the full
lever-arm terms.

Constants: m, Ixx, Iyy, Izz, Ixz (kg m^2), S (m^2), b, cbar (m), rho (kg/m^3); optional
g (9.80665), zT, x_vane, y_vane, z_vane, x_imu, z_imu (0).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
from numba.extending import register_jitable

from estimators.model import Model
from estimators.models._build import make_parameters, require_constants
from estimators.models.lateral import DEFAULT_FREE as LAT_FREE
from estimators.models.lateral import DEFAULTS as LATERAL_DEFAULTS
from estimators.models.longitudinal import DEFAULT_FREE as LONG_FREE
from estimators.models.longitudinal import LONGITUDINAL_DEFAULTS

SIXDOF_DEFAULTS: dict[str, float] = {**LONGITUDINAL_DEFAULTS, **LATERAL_DEFAULTS}
STATES = ["u", "v", "w", "p", "q", "r", "phi", "theta"]
INPUTS = ["de", "da", "dr", "thrust"]
OUTPUTS = ["V", "alpha", "beta", "p", "q", "r", "phi", "theta", "ax", "ay", "az"]


@register_jitable
def _dynamics(u, v, w, pr, qr, rr, phi, theta, de, da, dr, thrust, p, c):
    """Body-axis accelerations: (udot, vdot, wdot, pdot, qdot, rdot, fx, fy, fz) with
    f = specific force (m/s^2)."""
    V = np.sqrt(u * u + v * v + w * w)
    a = np.arctan2(w, u)
    b = np.arcsin(v / V)
    qbar = 0.5 * c.rho * V * V
    ph = pr * c.b / (2.0 * V)
    qh = qr * c.cbar / (2.0 * V)
    rh = rr * c.b / (2.0 * V)
    CL = p.CL0 + p.CLalpha * a + p.CLq * qh + p.CLde * de
    CD = p.CD0 + p.CDalpha * a + p.CDalpha2 * a * a + p.CDde * de
    CY = p.CYbeta * b + p.CYp * ph + p.CYr * rh + p.CYda * da + p.CYdr * dr
    Cl = p.Clbeta * b + p.Clp * ph + p.Clr * rh + p.Clda * da + p.Cldr * dr
    Cm = p.Cm0 + p.Cmalpha * a + p.Cmq * qh + p.Cmde * de
    Cn = p.Cnbeta * b + p.Cnp * ph + p.Cnr * rh + p.Cnda * da + p.Cndr * dr
    qS = qbar * c.S
    ca, sa = np.cos(a), np.sin(a)
    st, ct = np.sin(theta), np.cos(theta)
    sp, cp = np.sin(phi), np.cos(phi)
    # CLalphadot, Cmalphadot (default 0): alphadot = (u wdot - w udot) / (u^2 + w^2) is
    # solved for the lift's own alphadot term, alphadot_0 / (1 + qS CLalphadot cbar/(2V) /
    # (m sqrt(u^2 + w^2)))
    fx0 = (qS * (CL * sa - CD * ca) + thrust) / c.m
    fz0 = qS * (-CL * ca - CD * sa) / c.m
    uw2 = u * u + w * w
    a0 = (u * (qr * u - pr * v + c.g * ct * cp + fz0) - w * (rr * v - qr * w - c.g * st + fx0)) / uw2
    adot = a0 / (1.0 + qS * p.CLalphadot * c.cbar / (2.0 * V) / (c.m * np.sqrt(uw2)))
    ah = adot * c.cbar / (2.0 * V)
    CL = CL + p.CLalphadot * ah
    Cm = Cm + p.Cmalphadot * ah
    fx = (qS * (CL * sa - CD * ca) + thrust) / c.m
    fy = qS * CY / c.m
    fz = qS * (-CL * ca - CD * sa) / c.m
    Lm = qS * c.b * Cl
    Mm = qS * c.cbar * Cm + c.zT * thrust
    Nm = qS * c.b * Cn
    udot = rr * v - qr * w - c.g * st + fx
    vdot = pr * w - rr * u + c.g * ct * sp + fy
    wdot = qr * u - pr * v + c.g * ct * cp + fz
    gam = c.Ixx * c.Izz - c.Ixz * c.Ixz
    pdot = (
        c.Izz * Lm
        + c.Ixz * Nm
        + c.Ixz * (c.Ixx - c.Iyy + c.Izz) * pr * qr
        - (c.Izz * (c.Izz - c.Iyy) + c.Ixz * c.Ixz) * qr * rr
    ) / gam
    qdot = (Mm - (c.Ixx - c.Izz) * pr * rr - c.Ixz * (pr * pr - rr * rr)) / c.Iyy
    rdot = (
        c.Ixz * Lm
        + c.Ixx * Nm
        + (c.Ixx * (c.Ixx - c.Iyy) + c.Ixz * c.Ixz) * pr * qr
        - c.Ixz * (c.Ixx - c.Iyy + c.Izz) * qr * rr
    ) / gam
    return udot, vdot, wdot, pdot, qdot, rdot, fx, fy, fz


def f(x, u_in, p, c):
    u, v, w, pr, qr, rr, phi, theta = x
    de, da, dr, thrust = u_in
    ud, vd, wd, pd, qd, rd, fx, fy, fz = _dynamics(u, v, w, pr, qr, rr, phi, theta, de, da, dr, thrust, p, c)
    phidot = pr + np.tan(theta) * (qr * np.sin(phi) + rr * np.cos(phi))
    thetadot = qr * np.cos(phi) - rr * np.sin(phi)
    return ud, vd, wd, pd, qd, rd, phidot, thetadot


def g(x, u_in, p, c):
    u, v, w, pr, qr, rr, phi, theta = x
    de, da, dr, thrust = u_in
    ud, vd, wd, pd, qd, rd, fx, fy, fz = _dynamics(u, v, w, pr, qr, rr, phi, theta, de, da, dr, thrust, p, c)
    # air data at (xv, yv, zv): velocity + omega x r
    ub = u + qr * c.z_vane - rr * c.y_vane
    vb = v + rr * c.x_vane - pr * c.z_vane
    wb = w + pr * c.y_vane - qr * c.x_vane
    Vb = np.sqrt(ub * ub + vb * vb + wb * wb)
    # accelerometer at (xi, 0, zi): f + omegadot x r + omega x (omega x r)
    xi, zi = c.x_imu, c.z_imu
    ax = fx + qd * zi + qr * (-qr * xi) - rr * (rr * xi - pr * zi)
    ay = fy + rd * xi - pd * zi + rr * (qr * zi) - pr * (-qr * xi)
    az = fz - qd * xi + pr * (rr * xi - pr * zi) - qr * (qr * zi)
    return Vb, np.arctan2(wb, ub), np.arcsin(vb / Vb), pr, qr, rr, phi, theta, ax, ay, az


def sixdof(
    constants: Mapping[str, float],
    values: Mapping[str, float] | None = None,
    free: Iterable[str] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    output_biases: Iterable[str] = (),
    name: str = "sixdof",
) -> Model:
    """The nonlinear 6-DoF model; see the module docstring. ``free`` defaults to the
    derivatives the longitudinal and lateral builders estimate by default."""
    c = require_constants(
        constants, ("m", "Ixx", "Iyy", "Izz", "Ixz", "S", "b", "cbar", "rho"), "six-degree-of-freedom"
    )
    for k, v in {
        "g": 9.80665,
        "zT": 0.0,
        "x_vane": 0.0,
        "y_vane": 0.0,
        "z_vane": 0.0,
        "x_imu": 0.0,
        "z_imu": 0.0,
    }.items():
        c.setdefault(k, v)
    params = make_parameters(SIXDOF_DEFAULTS, values, free, tuple(LONG_FREE) + tuple(LAT_FREE), bounds)
    return Model(
        states=STATES,
        inputs=INPUTS,
        outputs=OUTPUTS,
        parameters=params,
        constants=c,
        f=f,
        g=g,
        output_biases=list(output_biases),
        name=name,
    )


def body_velocity(V: float, alpha: float, beta: float) -> tuple[float, float, float]:
    """(u, v, w) in m/s from airspeed (m/s), angle of attack and sideslip (rad)."""
    return (V * np.cos(alpha) * np.cos(beta), V * np.sin(beta), V * np.sin(alpha) * np.cos(beta))
