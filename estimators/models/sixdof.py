"""Nonlinear six-degree-of-freedom rigid-body model (flat Earth, calm air, body axes).

States  u, v, w (m/s, body-axis air-relative velocity), p, q, r (rad/s), phi, theta (rad)
        [with ``navigation``: psi (rad), x_n, y_e, z_d (m, local NED position in still air)]
Inputs  de, da, dr (rad, or normalised commands times the constants k_de, k_da, k_dr),
        thrust (N; or ``throttle`` 0..1 with thrust = kT throttle)
Outputs V (m/s), alpha, beta (rad), p, q, r (rad/s), phi, theta (rad), ax, ay, az (m/s^2,
        specific force) [with ``navigation``: psi, x_n, y_e, z_d]

Aerodynamics with the DESIGN.md derivative names, rates nondimensionalised with
b/(2V) (p, r) and cbar/(2V) (q); lift and drag act in stability axes, side force along
body y:

    CL = CL0 + CLalpha a + CLq qhat + CLde de          CD = CD0 + CDalpha a + CDalpha2 a^2 + CDde de
    CY = CY0 + CYbeta b + CYp phat + CYr rhat + CYda da + CYdr dr
    Cl, Cn like CY;  Cm = Cm0 + Cmalpha a + Cmq qhat + Cmde de

CY0, Cl0, Cn0 are the trim terms (coefficients at zero states and inputs: the aircraft's
asymmetry and its trimmed surfaces; 0 and held unless freed). Thrust = kT x the thrust
input: kT = 1 held with a thrust channel in N; with ``throttle=True`` the input is the
throttle (0..1) and kT (N at full throttle, proportional) an unknown to estimate. The
surface inputs are multiplied by the constants k_de, k_da, k_dr (rad per input unit,
default 1): normalised -1..1 commands become deflections with k = the deflection at full
travel. Thrust acts along body x with its line ``zT`` (m) below the CG. The moment equations keep
Ixz coupling and the gyroscopic terms. Optional CLalphadot, Cmalphadot (alphadot
cbar/(2V); default 0 and held), alphadot solved algebraically for the lift's own
alphadot term. Sensors away from the CG (m, body axes): the air
data at (x_vane, y_vane, z_vane) and the accelerometer at (x_imu, y_imu, z_imu), with the full
lever-arm terms.

With ``navigation`` the heading and the position are integrated too (psidot from the
Euler kinematics, position rate = body velocity rotated to NED): a rollout then gives the
whole pose, in still air.

Constants: m, Ixx, Iyy, Izz, Ixz (kg m^2), S (m^2), b, cbar (m), rho (kg/m^3); optional
g (9.80665), zT, x_vane, y_vane, z_vane, x_imu, y_imu, z_imu (0), k_de, k_da, k_dr (1).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
from numba.extending import register_jitable

from estimators.model import Model
from estimators.models._build import make_parameters, require_constants
from estimators.models.aero import lateral_coefficients, longitudinal_coefficients, roll_yaw_accelerations
from estimators.models.lateral import DEFAULT_FREE as LAT_FREE
from estimators.models.lateral import DEFAULTS as LATERAL_DEFAULTS
from estimators.models.lateral import TRIM_TERMS
from estimators.models.longitudinal import DEFAULT_FREE as LONG_FREE
from estimators.models.longitudinal import LONGITUDINAL_DEFAULTS

#: start values: both axes' derivatives, the lateral trim terms, the thrust per unit of the thrust input
SIXDOF_DEFAULTS: dict[str, float] = {
    **LONGITUDINAL_DEFAULTS,
    **{k: 0.0 for k in TRIM_TERMS},
    **LATERAL_DEFAULTS,
    "kT": 1.0,
}
STATES = ["u", "v", "w", "p", "q", "r", "phi", "theta"]
INPUTS = ["de", "da", "dr", "thrust"]
OUTPUTS = ["V", "alpha", "beta", "p", "q", "r", "phi", "theta", "ax", "ay", "az"]
#: what ``navigation`` adds to the states and the outputs
NAVIGATION = ["psi", "x_n", "y_e", "z_d"]


@register_jitable
def _dynamics(u, v, w, pr, qr, rr, phi, theta, de, da, dr, thrust, p, c):
    """Body-axis accelerations: (udot, vdot, wdot, pdot, qdot, rdot, fx, fy, fz) with
    f = specific force (m/s^2)."""
    de, da, dr, thrust = c.k_de * de, c.k_da * da, c.k_dr * dr, p.kT * thrust
    V = np.sqrt(u * u + v * v + w * w)
    a = np.arctan2(w, u)
    b = np.arcsin(v / V)
    qbar = 0.5 * c.rho * V * V
    ph = pr * c.b / (2.0 * V)
    qh = qr * c.cbar / (2.0 * V)
    rh = rr * c.b / (2.0 * V)
    CL, CD, Cm = longitudinal_coefficients(a, qh, de, 0.0, p)  # the alphadot terms below
    CY, Cl, Cn = lateral_coefficients(b, ph, rh, da, dr, p)
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
    pdot, rdot = roll_yaw_accelerations(Lm, Nm, pr, qr, rr, c)
    qdot = (Mm - (c.Ixx - c.Izz) * pr * rr - c.Ixz * (pr * pr - rr * rr)) / c.Iyy
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
    return _observations(u, v, w, pr, qr, rr, phi, theta, de, da, dr, thrust, p, c)


@register_jitable
def _observations(u, v, w, pr, qr, rr, phi, theta, de, da, dr, thrust, p, c):
    """The 11 outputs of :data:`OUTPUTS` at the sensors' positions."""
    ud, vd, wd, pd, qd, rd, fx, fy, fz = _dynamics(u, v, w, pr, qr, rr, phi, theta, de, da, dr, thrust, p, c)
    # air data at (xv, yv, zv): velocity + omega x r
    ub = u + qr * c.z_vane - rr * c.y_vane
    vb = v + rr * c.x_vane - pr * c.z_vane
    wb = w + pr * c.y_vane - qr * c.x_vane
    Vb = np.sqrt(ub * ub + vb * vb + wb * wb)
    # accelerometer at r = (xi, yi, zi): f + omegadot x r + omega x (omega x r)
    xi, yi, zi = c.x_imu, c.y_imu, c.z_imu
    cx = qr * zi - rr * yi  # omega x r
    cy = rr * xi - pr * zi
    cz = pr * yi - qr * xi
    ax = fx + qd * zi - rd * yi + qr * cz - rr * cy
    ay = fy + rd * xi - pd * zi + rr * cx - pr * cz
    az = fz + pd * yi - qd * xi + pr * cy - qr * cx
    return Vb, np.arctan2(wb, ub), np.arcsin(vb / Vb), pr, qr, rr, phi, theta, ax, ay, az


@register_jitable
def _navigation_rates(u, v, w, pr, qr, rr, phi, theta, psi):
    """(psidot, x_n dot, y_e dot, z_d dot): Euler heading rate and the body velocity in NED."""
    sp, cp = np.sin(phi), np.cos(phi)
    st, ct = np.sin(theta), np.cos(theta)
    ss, cs = np.sin(psi), np.cos(psi)
    psidot = (qr * sp + rr * cp) / ct
    xd = ct * cs * u + (sp * st * cs - cp * ss) * v + (cp * st * cs + sp * ss) * w
    yd = ct * ss * u + (sp * st * ss + cp * cs) * v + (cp * st * ss - sp * cs) * w
    zd = -st * u + sp * ct * v + cp * ct * w
    return psidot, xd, yd, zd


def f_navigation(x, u_in, p, c):
    u, v, w, pr, qr, rr, phi, theta, psi, xn, ye, zd = x
    de, da, dr, thrust = u_in
    ud, vd, wd, pd, qd, rd, fx, fy, fz = _dynamics(u, v, w, pr, qr, rr, phi, theta, de, da, dr, thrust, p, c)
    phidot = pr + np.tan(theta) * (qr * np.sin(phi) + rr * np.cos(phi))
    thetadot = qr * np.cos(phi) - rr * np.sin(phi)
    psidot, xnd, yed, zdd = _navigation_rates(u, v, w, pr, qr, rr, phi, theta, psi)
    return ud, vd, wd, pd, qd, rd, phidot, thetadot, psidot, xnd, yed, zdd


def g_navigation(x, u_in, p, c):
    u, v, w, pr, qr, rr, phi, theta, psi, xn, ye, zd = x
    de, da, dr, thrust = u_in
    Vb, a, b, p_, q_, r_, phi_, th_, ax, ay, az = _observations(
        u, v, w, pr, qr, rr, phi, theta, de, da, dr, thrust, p, c
    )
    return Vb, a, b, p_, q_, r_, phi_, th_, ax, ay, az, psi, xn, ye, zd


def sixdof(
    constants: Mapping[str, float],
    values: Mapping[str, float] | None = None,
    free: Iterable[str] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    output_biases: Iterable[str] = (),
    name: str = "sixdof",
    *,
    throttle: bool = False,
    navigation: bool = False,
) -> Model:
    """The nonlinear 6-DoF model; see the module docstring. ``free`` defaults to the
    derivatives the longitudinal and lateral builders estimate by default (and kT with
    ``throttle``). ``throttle``: the fourth input is the throttle (0..1) and kT, the thrust
    at full throttle (N), starts at ``values["kT"]`` (default: the weight, m g);
    ``navigation``: heading and NED position integrated too (states and outputs
    psi, x_n, y_e, z_d)."""
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
        "y_imu": 0.0,
        "z_imu": 0.0,
        "k_de": 1.0,
        "k_da": 1.0,
        "k_dr": 1.0,
    }.items():
        c.setdefault(k, v)
    values = dict(values or {})
    default_free = tuple(LONG_FREE) + tuple(LAT_FREE)
    if throttle:
        values.setdefault("kT", c["m"] * c["g"])
        default_free += ("kT",)
    params = make_parameters(SIXDOF_DEFAULTS, values, free, default_free, bounds)
    nav = NAVIGATION if navigation else []
    return Model(
        states=STATES + nav,
        inputs=INPUTS[:3] + ["throttle" if throttle else "thrust"],
        outputs=OUTPUTS + nav,
        parameters=params,
        constants=c,
        f=f_navigation if navigation else f,
        g=g_navigation if navigation else g,
        output_biases=list(output_biases),
        name=name,
    )


def body_velocity(V: float, alpha: float, beta: float) -> tuple[float, float, float]:
    """(u, v, w) in m/s from airspeed (m/s), angle of attack and sideslip (rad)."""
    return (V * np.cos(alpha) * np.cos(beta), V * np.sin(beta), V * np.sin(alpha) * np.cos(beta))
