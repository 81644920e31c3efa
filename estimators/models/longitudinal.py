"""Nonlinear longitudinal point-mass-plus-pitch model in stability axes.

States  V (m/s), alpha (rad), theta (rad), q (rad/s)
Inputs  de (rad), thrust (N)
Outputs V, alpha, theta, q, qdot (rad/s^2), ax, az (m/s^2, body-axis specific force at the CG)

Aerodynamics (rates nondimensionalised with cbar/(2V)):
    CL = CL0 + CLalpha alpha + CLq q cbar/(2V) + CLde de
    CD = CD0 + CDalpha alpha + CDalpha2 alpha^2 + CDde de
    Cm = Cm0 + Cmalpha alpha + Cmq q cbar/(2V) + Cmde de
plus the optional CLalphadot, Cmalphadot terms (alphadot cbar/(2V); default 0 and held,
which leaves the model exactly as without them). alphadot appears on both sides of the
alpha equation through the lift; it is solved algebraically:
alphadot = alphadot_0 / (1 + qbar S CLalphadot cbar / (2 m V^2)), alphadot_0 the value
without the CLalphadot term.
Thrust acts at angle ``sigmaT`` (rad, up from body x) with its line ``zT`` (m) below the
CG. Wings level, no sideslip: flight-path angle gamma = theta - alpha.

Constants: m (kg), Iyy (kg m^2), S (m^2), cbar (m), rho (kg/m^3); optional g (m/s^2,
default 9.80665), sigmaT (rad, 0), zT (m, 0), and the sensor positions in body axes
from the CG (m, default 0): x_vane, z_vane (air data: V and alpha are observed there,
u + q z, w - q x) and x_imu, z_imu (accelerometer: ax + qdot z - q^2 x, az - qdot x - q^2 z).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
from numba.extending import register_jitable

from estimators.errors import ModelDefinitionError
from estimators.model import Model
from estimators.models._build import make_parameters, require_constants
from estimators.models.aero import longitudinal_coefficients

LONGITUDINAL_DEFAULTS: dict[str, float] = {
    "CD0": 0.03,
    "CDalpha": 0.2,
    "CDalpha2": 0.0,
    "CDde": 0.0,
    "CL0": 0.2,
    "CLalpha": 5.0,
    "CLq": 0.0,
    "CLde": 0.4,
    "Cm0": 0.0,
    "Cmalpha": -0.8,
    "Cmq": -15.0,
    "Cmde": -1.5,
    "CLalphadot": 0.0,
    "Cmalphadot": 0.0,
}
DEFAULT_FREE = ("CD0", "CDalpha", "CL0", "CLalpha", "CLde", "Cm0", "Cmalpha", "Cmq", "Cmde")


@register_jitable
def _loads(V, alpha, q, de, thrust, p, c, adot, rho):
    """Lift, drag (N), pitching moment (N m) and total thrust-axis terms; ``adot`` the
    angle-of-attack rate (rad/s) of the CLalphadot, Cmalphadot terms; ``rho`` the air
    density (kg/m^3)."""
    qbar = 0.5 * rho * V * V
    qhat = q * c.cbar / (2.0 * V)
    ahat = adot * c.cbar / (2.0 * V)
    CL, CD, Cm = longitudinal_coefficients(alpha, qhat, de, ahat, p)
    L = qbar * c.S * CL
    D = qbar * c.S * CD
    M = qbar * c.S * c.cbar * Cm + c.zT * thrust
    return L, D, M


@register_jitable
def _wings_level(V, alpha, theta, q, de, thrust, p, c):
    """(L, D, M, alphadot) of the wings-level equations, alphadot solved for the
    CLalphadot term (alphadot_0 / (1 + qbar S CLalphadot cbar / (2 m V^2)))."""
    L0, D0, M0 = _loads(V, alpha, q, de, thrust, p, c, 0.0, c.rho)
    gam = theta - alpha
    a0 = q + (-L0 - thrust * np.sin(alpha + c.sigmaT)) / (c.m * V) + c.g * np.cos(gam) / V
    k = 0.5 * c.rho * V * V * c.S * p.CLalphadot * c.cbar / (2.0 * V) / (c.m * V)
    adot = a0 / (1.0 + k)
    L, D, M = _loads(V, alpha, q, de, thrust, p, c, adot, c.rho)
    return L, D, M, adot


def f(x, u, p, c):
    V, alpha, theta, q = x
    de, thrust = u
    L, D, M, alphadot = _wings_level(V, alpha, theta, q, de, thrust, p, c)
    gam = theta - alpha
    Vdot = (thrust * np.cos(alpha + c.sigmaT) - D) / c.m - c.g * np.sin(gam)
    return Vdot, alphadot, q, M / c.Iyy


def g(x, u, p, c):
    V, alpha, theta, q = x
    de, thrust = u
    L, D, M, alphadot = _wings_level(V, alpha, theta, q, de, thrust, p, c)
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


def longitudinal(
    constants: Mapping[str, float],
    values: Mapping[str, float] | None = None,
    free: Iterable[str] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    output_biases: Iterable[str] = (),
    name: str = "longitudinal",
) -> Model:
    """The nonlinear longitudinal model.

    constants : m, Iyy, S, cbar, rho (SI); g, sigmaT, zT optional.
    values : start values by derivative name (defaults in ``LONGITUDINAL_DEFAULTS``).
    free : names to estimate (default CD0 CDalpha CL0 CLalpha CLde Cm0 Cmalpha Cmq Cmde;
        the others are held at their values).
    output_biases : outputs that get a per-segment bias ``bias_<output>[k]``.
    """
    c = require_constants(constants, ("m", "Iyy", "S", "cbar", "rho"), "longitudinal")
    for k, v in {
        "g": 9.80665,
        "sigmaT": 0.0,
        "zT": 0.0,
        "x_vane": 0.0,
        "z_vane": 0.0,
        "x_imu": 0.0,
        "z_imu": 0.0,
    }.items():
        c.setdefault(k, v)
    params = make_parameters(LONGITUDINAL_DEFAULTS, values, free, DEFAULT_FREE, bounds)
    return Model(
        states=["V", "alpha", "theta", "q"],
        inputs=["de", "thrust"],
        outputs=["V", "alpha", "theta", "q", "qdot", "ax", "az"],
        parameters=params,
        constants=c,
        f=f,
        g=g,
        output_biases=list(output_biases),
        name=name,
    )


# -- longitudinal model driven by the measured lateral-directional motion ---------------------
@register_jitable
def _measured_lateral(V, alpha, theta, q, de, thrust, beta, pr, rr, phi, ay, rho, p, c, qa):
    """(Vdot, alphadot, thetadot, qdot, L, D) of the longitudinal equations of the rigid
    body with sideslip, roll and yaw rate and bank angle taken as measured; alphadot solved
    for the CLalphadot term; ``qa`` the pitch rate the aerodynamics see (q minus the
    rotary gust)."""
    sa, ca = np.sin(alpha), np.cos(alpha)
    sb, cb = np.sin(beta), np.cos(beta)
    st, ct = np.sin(theta), np.cos(theta)
    sp, cp = np.sin(phi), np.cos(phi)
    L0, D0, M0 = _loads(V, alpha, qa, de, thrust, p, c, 0.0, rho)
    # alphadot = q - tan(beta) (p cos a + r sin a)
    #            + (g (cos a cos theta cos phi + sin a sin theta) + cos a fz - sin a fx) / (V cos b)
    a0 = (
        q
        - sb / cb * (pr * ca + rr * sa)
        + (c.g * (ca * ct * cp + sa * st) + (-L0 - thrust * np.sin(alpha + c.sigmaT)) / c.m) / (V * cb)
    )
    k = 0.5 * rho * V * V * c.S * p.CLalphadot * c.cbar / (2.0 * V) / (c.m * V * cb)
    adot = a0 / (1.0 + k)
    L, D, M = _loads(V, alpha, qa, de, thrust, p, c, adot, rho)
    # Vdot = g (-cos a cos b sin theta + sin b cos theta sin phi + sin a cos b cos theta cos phi)
    #        + cos b (cos a fx + sin a fz) + sin b fy, fy the measured lateral specific force
    Vdot = (
        c.g * (-ca * cb * st + sb * ct * sp + sa * cb * ct * cp)
        + cb * (thrust * np.cos(alpha + c.sigmaT) - D) / c.m
        + sb * ay
    )
    qdot = (M - (c.Ixx - c.Izz) * pr * rr - c.Ixz * (pr * pr - rr * rr)) / c.Iyy
    return Vdot, adot, q * cp - rr * sp, qdot, L, D


def f_measured(x, u, p, c):
    V, alpha, theta, q = x
    de, thrust, beta, pr, rr, phi, ay, rho = u
    Vd, ad, thd, qd, L, D = _measured_lateral(V, alpha, theta, q, de, thrust, beta, pr, rr, phi, ay, rho, p, c, q)
    return Vd, ad, thd, qd


def f_measured_gust(x, u, p, c):
    V, alpha, theta, q, alpha_k, agf, qgi = x
    de, thrust, beta, pr, rr, phi, ay, rho = u
    tau = 4.0 * c.b / (np.pi * V)
    ag = alpha - alpha_k  # gust angle of attack, -w_g / V
    dgf = (ag - agf) / tau
    Vd, ad, thd, qd, L, D = _measured_lateral(
        V, alpha, theta, q, de, thrust, beta, pr, rr, phi, ay, rho, p, c, q + dgf - qgi
    )
    # alpha (air-relative, driven by process noise) = alpha_k (the rigid body's) + alpha_g;
    # alpha_g decays with the Dryden time constant L_w / V; alpha_gf lags it by tau:
    # q_g = w_g'/V lagged + q_gi = -(alpha_g - alpha_gf) / tau + q_gi
    return Vd, ad - ag * V / c.L_w, thd, qd, ad, dgf, -qgi / tau


def g_measured(x, u, p, c):
    V, alpha, theta, q = x
    de, thrust, beta, pr, rr, phi, ay, rho = u
    return _measured_outputs(V, alpha, theta, q, de, thrust, beta, pr, rr, phi, ay, rho, p, c, q)


def g_measured_gust(x, u, p, c):
    V, alpha, theta, q, alpha_k, agf, qgi = x
    de, thrust, beta, pr, rr, phi, ay, rho = u
    dgf = (alpha - alpha_k - agf) * np.pi * V / (4.0 * c.b)
    Vm, am, thm, qm, qdm, axm, azm = _measured_outputs(
        V, alpha, theta, q, de, thrust, beta, pr, rr, phi, ay, rho, p, c, q + dgf - qgi
    )
    # an angle of attack rebuilt from the flight path (kin_angles = 1) is the rigid body's
    return Vm, am + c.kin_angles * (alpha_k - am), thm, qm, qdm, axm, azm


@register_jitable
def _measured_outputs(V, alpha, theta, q, de, thrust, beta, pr, rr, phi, ay, rho, p, c, qa):
    Vd, ad, thd, qd, L, D = _measured_lateral(V, alpha, theta, q, de, thrust, beta, pr, rr, phi, ay, rho, p, c, qa)
    sa, ca = np.sin(alpha), np.cos(alpha)
    cb = np.cos(beta)
    fx = (thrust * np.cos(c.sigmaT) + L * sa - D * ca) / c.m
    fz = (-thrust * np.sin(c.sigmaT) - L * ca - D * sa) / c.m
    # air data at (x_vane, y_vane, z_vane): velocity + omega x r (a wing-tip boom's vane
    # sees p y_vane / V in alpha)
    u_b = V * ca * cb + q * c.z_vane - rr * c.y_vane
    v_b = V * np.sin(beta) + rr * c.x_vane - pr * c.z_vane
    w_b = V * sa * cb + pr * c.y_vane - q * c.x_vane
    # accelerometer at (x_imu, 0, z_imu): f + omegadot x r + omega x (omega x r)
    xi, zi = c.x_imu, c.z_imu
    ax = fx + qd * zi - q * q * xi - rr * (rr * xi - pr * zi)
    az = fz - qd * xi + pr * (rr * xi - pr * zi) - q * q * zi
    return (np.sqrt(u_b * u_b + v_b * v_b + w_b * w_b), np.arctan2(w_b, u_b), theta, q, qd, ax, az)


def longitudinal_measured_lateral(
    constants: Mapping[str, float],
    values: Mapping[str, float] | None = None,
    free: Iterable[str] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    output_biases: Iterable[str] = (),
    name: str = "longitudinal-measured",
    rotary_gust: bool = False,
) -> Model:
    """Longitudinal model with the lateral-directional motion as measured inputs (the
    mirror of :func:`estimators.models.lateral.lateral_measured_longitudinal`).

    States V, alpha, theta, q; inputs de (rad), thrust (N), beta (rad), p, r (rad/s),
    phi (rad), ay (m/s^2, lateral specific force), rho (kg/m^3, air density along the
    flight: a phugoid's height change moves it by about a percent, enough to bias the
    drag and lift derivatives fitted with the mean density); outputs V, alpha, theta, q,
    qdot, ax, az.
    The rigid-body equations of V, alpha, theta, q with sideslip, bank angle and the
    roll/yaw rates in them (tan(beta)(p cos a + r sin a) in alphadot, g cos theta cos phi,
    thetadot = q cos phi - r sin phi, the inertia-coupling moment (Ixx - Izz) p r +
    Ixz (p^2 - r^2)): for maneuvers that move all axes at once, where the wings-level
    model books the bank angle's loss of lift and the yaw rate's pitch-attitude change on
    the derivatives. The air data sit at (x_vane, y_vane, z_vane) (a wing-tip boom at
    y_vane sees p y_vane / V in alpha), the accelerometer at (x_imu, 0, z_imu).
    Constants: m, Iyy, S, cbar, rho; optional Ixx, Izz, Ixz (0: no inertia coupling),
    g, sigmaT, zT, x_vane, y_vane, z_vane, x_imu, z_imu.

    rotary_gust : the vertical gust in the states (Dryden shaping filters), for the
        filters: states V, alpha, theta, q, alpha_k, alpha_gf, q_gi. ``alpha`` stays the
        air-relative angle of attack (aerodynamics, vane; the state process noise drives),
        ``alpha_k`` is the rigid body's part (its rate is the alphadot of the
        CLalphadot/Cmalphadot terms, as JSBSim's aero/alphadot-rad_sec), alpha_g = alpha -
        alpha_k = -w_g / V the gust's, which decays with time constant L_w / V (constant
        ``L_w``, default 533.4 m = 1750 ft). Constant ``kin_angles`` = 1 (default 0):
        the alpha output is alpha_k, for an angle of attack rebuilt from the flight path
        (no vane: from the inertial velocity and a known wind), which sees the body's
        motion against the mean wind and no gust. The pitch rate of the air mass (rotary gust,
        the gust gradient along the airframe) is q_g = -s / (1 + tau s) alpha_g + q_gi,
        tau = 4 b / (pi V) (lag state alpha_gf; constant ``b``, span, needed), the
        MIL-F-8785C form on the gust along the aircraft's z axis (JSBSim's Tustin
        turbulence applies it to the earth-vertical gust instead, which differs from it
        little at small bank angles); the rest, q_gi, is a first-order Markov
        process with time constant tau to be driven by its own process noise. The
        aerodynamics see q - q_g (CLq, Cmq), the gyro q. Without q_g the pitch damping
        of the gyro rate books the rotary gust on the derivatives (in turbulence, Cmq and
        Cmalpha come out well short of the truth)."""
    c = require_constants(constants, ("m", "Iyy", "S", "cbar", "rho"), "longitudinal (measured lateral)")
    for k, v in {
        "g": 9.80665,
        "sigmaT": 0.0,
        "zT": 0.0,
        "x_vane": 0.0,
        "y_vane": 0.0,
        "z_vane": 0.0,
        "x_imu": 0.0,
        "z_imu": 0.0,
        "Ixx": 0.0,
        "Izz": 0.0,
        "Ixz": 0.0,
        "kin_angles": 0.0,
    }.items():
        c.setdefault(k, v)
    if rotary_gust and not c.get("b"):
        raise ModelDefinitionError("rotary_gust needs the span b (m) among the constants")
    params = make_parameters(LONGITUDINAL_DEFAULTS, values, free, DEFAULT_FREE, bounds)
    c.setdefault("L_w", 533.4)
    return Model(
        states=(
            ["V", "alpha", "theta", "q", "alpha_k", "alpha_gf", "q_gi"] if rotary_gust else ["V", "alpha", "theta", "q"]
        ),
        inputs=["de", "thrust", "beta", "p", "r", "phi", "ay", "rho"],
        outputs=["V", "alpha", "theta", "q", "qdot", "ax", "az"],
        parameters=params,
        constants=c,
        f=f_measured_gust if rotary_gust else f_measured,
        g=g_measured_gust if rotary_gust else g_measured,
        output_biases=list(output_biases),
        name=name,
    )
