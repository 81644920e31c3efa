"""Linear lateral-directional model (perturbations from wings-level trim).

States  beta (rad), p, r (rad/s), phi (rad); inputs da, dr (rad);
outputs beta, p, r, phi, ay (m/s^2), pdot, rdot (rad/s^2).
With qbar = rho V^2 / 2, phat = p b / (2V), rhat = r b / (2V):

    CY = CY0 + CYbeta beta + CYp phat + CYr rhat + CYda da + CYdr dr        (likewise Cl, Cn)
    betadot = qbar S / (m V) CY + p sin(alpha0) - r cos(alpha0) + g cos(theta0) / V phi
    Ixx pdot - Ixz rdot = qbar S b Cl,   Izz rdot - Ixz pdot = qbar S b Cn
    phidot = p + tan(theta0) r,          ay = qbar S CY / m

Constants: m, Ixx, Izz, Ixz (kg m^2), S, b (m), rho, V (m/s); alpha0, theta0 (rad, trim,
default 0), g; sensor positions from the CG (m, default 0): x_vane, z_vane (beta observed
as beta + (r x - p z)/V) and x_imu, z_imu (ay + rdot x - pdot z).

CY0, Cl0, Cn0 (start 0, held unless freed) are the trim-asymmetry terms: the coefficients
at zero states and zero inputs. With inputs measured from the trim (the pipeline's
convention) they are the aircraft's own asymmetry plus what its trimmed aileron and
rudder produce, which a steady bank or sideslip balances; without them the model can only
start from a balanced wings-level trim, and drifts in bank from any other.
Which of them can be free alongside output biases: :func:`trim_terms`.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
from numba.extending import register_jitable

from estimators.errors import ModelDefinitionError
from estimators.model import Model, Parameter
from estimators.models._build import make_parameters, require_constants
from estimators.models.aero import lateral_coefficients, roll_yaw_accelerations

DEFAULTS = {
    "CY0": 0.0,
    "Cl0": 0.0,
    "Cn0": 0.0,
    "CYbeta": -0.5,
    "CYp": 0.0,
    "CYr": 0.0,
    "CYda": 0.0,
    "CYdr": 0.15,
    "Clbeta": -0.08,
    "Clp": -0.45,
    "Clr": 0.1,
    "Clda": 0.15,
    "Cldr": 0.01,
    "Cnbeta": 0.08,
    "Cnp": -0.05,
    "Cnr": -0.15,
    "Cnda": -0.01,
    "Cndr": -0.07,
}
DEFAULT_FREE = ("CYbeta", "CYdr", "Clbeta", "Clp", "Clr", "Clda", "Cldr", "Cnbeta", "Cnp", "Cnr", "Cnda", "Cndr")
#: the trim-asymmetry terms (constant side force, rolling and yawing moment coefficients)
TRIM_TERMS = ("CY0", "Cl0", "Cn0")


def trim_terms(beta_bias: bool, rate_biases: bool, ay_bias: bool = False) -> tuple[str, ...]:
    """The trim-asymmetry terms identifiable alongside per-segment initial states and
    output biases: CY0, Cl0, Cn0 less one per free bias that can carry a steady offset.

    ``ay_bias`` (counted with ``rate_biases`` only, in the 6-DoF fit whose sideslip has no
    bias): a lateral-accelerometer bias and a yaw-gyro bias together hold a wings-level
    flat turn, a steady yaw rate the gyro bias hides with the side force the accelerometer
    bias hides, which is what CY0 would otherwise carry: CY0 is dropped first.

    Why: a steady state of the model with a constant sideslip offset (read by the vane
    with its bias, ``beta_bias``) or a constant yaw rate with the roll rate that keeps the
    bank (read by the gyros with theirs, ``rate_biases``: a yaw-rate bias, the roll rate's
    share being tan(theta) of it) changes no output beyond those biases, while it shifts the constant force and moments; each such offset makes one
    combination of (CY0, Cl0, Cn0) unidentifiable. The terms kept are CY0 first (the side
    force that a steady bank balances: a trim the sideslip and rate offsets cannot
    imitate), then Cl0, then Cn0; the dropped ones are carried by those offsets (a
    wings-level trim in a steady sideslip is a vane bias to this model)."""
    terms = TRIM_TERMS[1:] if ay_bias and rate_biases else TRIM_TERMS
    return terms[: len(terms) - int(beta_bias) - int(rate_biases)]


@register_jitable
def _moments(beta, pr, rr, da, dr, p, c):
    qbar = 0.5 * c.rho * c.V * c.V
    ph = pr * c.b / (2.0 * c.V)
    rh = rr * c.b / (2.0 * c.V)
    CY, Cl, Cn = lateral_coefficients(beta, ph, rh, da, dr, p)
    L = qbar * c.S * c.b * Cl
    N = qbar * c.S * c.b * Cn
    det = c.Ixx * c.Izz - c.Ixz * c.Ixz
    pdot = (c.Izz * L + c.Ixz * N) / det
    rdot = (c.Ixz * L + c.Ixx * N) / det
    return qbar * c.S * CY, pdot, rdot


def f(x, u, p, c):
    beta, pr, rr, phi = x
    da, dr = u
    Y, pdot, rdot = _moments(beta, pr, rr, da, dr, p, c)
    betadot = Y / (c.m * c.V) + pr * np.sin(c.alpha0) - rr * np.cos(c.alpha0) + c.g * np.cos(c.theta0) / c.V * phi
    return betadot, pdot, rdot, pr + np.tan(c.theta0) * rr


def g(x, u, p, c):
    beta, pr, rr, phi = x
    da, dr = u
    Y, pdot, rdot = _moments(beta, pr, rr, da, dr, p, c)
    # sensors away from the CG (linearised): vane at (x_vane, z_vane), IMU at (x_imu, z_imu)
    beta_s = beta + (rr * c.x_vane - pr * c.z_vane) / c.V
    ay_s = Y / c.m + rdot * c.x_imu - pdot * c.z_imu
    return beta_s, pr, rr, phi, ay_s, pdot, rdot


def lateral_directional(
    constants: Mapping[str, float],
    values: Mapping[str, float] | None = None,
    free: Iterable[str] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    output_biases: Iterable[str] = (),
    name: str = "lateral",
) -> Model:
    """The linear lateral-directional model; see the module docstring."""
    c = require_constants(constants, ("m", "Ixx", "Izz", "Ixz", "S", "b", "rho", "V"), "lateral-directional")
    for k, v in {
        "g": 9.80665,
        "alpha0": 0.0,
        "theta0": 0.0,
        "x_vane": 0.0,
        "z_vane": 0.0,
        "x_imu": 0.0,
        "z_imu": 0.0,
    }.items():
        c.setdefault(k, v)
    return Model(
        states=["beta", "p", "r", "phi"],
        inputs=["da", "dr"],
        outputs=["beta", "p", "r", "phi", "ay", "pdot", "rdot"],
        parameters=make_parameters(DEFAULTS, values, free, DEFAULT_FREE, bounds),
        constants=c,
        f=f,
        g=g,
        output_biases=list(output_biases),
        name=name,
    )


# -- lateral-directional model driven by the measured longitudinal motion ---------------------
@register_jitable
def _measured_dynamics(beta, pr, rr, phi, da, dr, V, alpha, theta, qr, p, c, pa, ra):
    """(betadot, pdot, rdot, phidot, fy) of the lateral-directional equations with the
    longitudinal variables V, alpha, theta, q taken as measured; ``pa``, ``ra`` the roll
    and yaw rates the aerodynamics see (p, r minus the rotary gusts)."""
    qbar = 0.5 * c.rho * V * V
    ph = pa * c.b / (2.0 * V)
    rh = ra * c.b / (2.0 * V)
    CY, Cl, Cn = lateral_coefficients(beta, ph, rh, da, dr, p)
    qS = qbar * c.S
    fy = qS * CY / c.m
    Lm = qS * c.b * Cl
    Nm = qS * c.b * Cn
    pdot, rdot = roll_yaw_accelerations(Lm, Nm, pr, qr, rr, c)
    # vdot = p w - r u + g cos(theta) sin(phi) + fy with v = V sin(beta), u = V cos(alpha)
    # cos(beta), w = V sin(alpha) cos(beta); the term in Vdot sin(beta) is left out
    betadot = pr * np.sin(alpha) - rr * np.cos(alpha) + (c.g * np.cos(theta) * np.sin(phi) + fy) / (V * np.cos(beta))
    phidot = pr + np.tan(theta) * (qr * np.sin(phi) + rr * np.cos(phi))
    return betadot, pdot, rdot, phidot, fy


def f_measured(x, u, p, c):
    beta, pr, rr, phi = x
    da, dr, V, alpha, theta, qr = u
    bd, pd, rd, phid, fy = _measured_dynamics(beta, pr, rr, phi, da, dr, V, alpha, theta, qr, p, c, pr, rr)
    return bd, pd, rd, phid


def f_measured_gust(x, u, p, c):
    beta, pr, rr, phi, pg, beta_k, bgf = x
    da, dr, V, alpha, theta, qr = u
    bg = beta - beta_k  # gust sideslip, -v_g / V
    dgf = (bg - bgf) * np.pi * V / (4.0 * c.b)
    bd, pd, rd, phid, fy = _measured_dynamics(beta, pr, rr, phi, da, dr, V, alpha, theta, qr, p, c, pr - pg, rr + dgf)
    # roll gust: first-order Markov, time constant tau_pg (s; Dryden 4 b / (pi V)); beta
    # (air-relative, driven by process noise) = beta_k (the rigid body's) + beta_g, beta_g
    # decaying with L_v / V, beta_gf lagging it by 4 b / (pi V): yaw gust r_g = -dgf
    return bd - bg * V / c.L_v, pd, rd, phid, -pg / p.tau_pg, bd, dgf


def g_measured_gust(x, u, p, c):
    beta, pr, rr, phi, pg, beta_k, bgf = x
    da, dr, V, alpha, theta, qr = u
    dgf = (beta - beta_k - bgf) * np.pi * V / (4.0 * c.b)
    bm, pm, rm, phim, aym = _measured_outputs(beta, pr, rr, phi, da, dr, V, alpha, theta, qr, p, c, pr - pg, rr + dgf)
    # a sideslip rebuilt from the flight path (kin_angles = 1) is the rigid body's
    return bm + c.kin_angles * (beta_k - bm), pm, rm, phim, aym


def g_measured(x, u, p, c):
    beta, pr, rr, phi = x
    da, dr, V, alpha, theta, qr = u
    return _measured_outputs(beta, pr, rr, phi, da, dr, V, alpha, theta, qr, p, c, pr, rr)


@register_jitable
def _measured_outputs(beta, pr, rr, phi, da, dr, V, alpha, theta, qr, p, c, pa, ra):
    bd, pd, rd, phid, fy = _measured_dynamics(beta, pr, rr, phi, da, dr, V, alpha, theta, qr, p, c, pa, ra)
    # vane at (x_vane, z_vane): v + r x - p z over V; accelerometer at (x_imu, z_imu):
    # fy + rdot x - pdot z + q (p x + r z)
    beta_s = beta + (rr * c.x_vane - pr * c.z_vane) / V
    ay_s = fy + rd * c.x_imu - pd * c.z_imu + qr * (pr * c.x_imu + rr * c.z_imu)
    return beta_s, pr, rr, phi, ay_s


def lateral_measured_longitudinal(
    constants: Mapping[str, float],
    values: Mapping[str, float] | None = None,
    free: Iterable[str] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    output_biases: Iterable[str] = (),
    name: str = "lateral-measured",
    rotary_gust: bool = False,
) -> Model:
    """Lateral-directional model with the longitudinal motion as measured inputs.

    States beta, p, r, phi; inputs da, dr (rad), V (m/s), alpha, theta (rad), q (rad/s);
    outputs beta, p, r, phi, ay. Unlike :func:`lateral_directional` the dynamic pressure,
    the rate normalisation b/2V, the kinematic coupling (p sin alpha - r cos alpha, g
    cos theta sin phi / V, tan theta (q sin phi + r cos phi)) and the gyroscopic moments
    follow the measured airspeed, angle of attack, pitch attitude and pitch rate instead
    of being frozen at trim, and bank angles are not small. No longitudinal derivative is
    needed (the usual way to fit one axis of a flight whose other axis moves: the measured
    variables of the other axis enter as pseudo-inputs). Constants: m, Ixx, Iyy, Izz, Ixz,
    S, b, rho; optional g, x_vane, z_vane, x_imu, z_imu.

    rotary_gust : add the state ``p_g`` (rad/s), the roll rate of the air mass (Dryden
        rotary turbulence, the spanwise gradient of the vertical gust), a first-order
        Markov process with time constant ``tau_pg`` (s, a parameter: start 4 b / (pi V),
        the Dryden value, or ``values["tau_pg"]``; free when named in ``free``), to be
        driven by process noise (the filters); the aerodynamics see p - p_g (CYp, Clp,
        Cnp), the gyro p. Without it the roll damping of the gyro rate books the gust on
        the roll derivatives (in turbulence, Clp and Clbeta come out a fraction of the
        truth). Also the lateral gust in the
        states (states beta_k, beta_gf): ``beta`` stays the air-relative sideslip (the
        state process noise drives), beta_k the rigid body's part, beta_g = beta - beta_k
        = -v_g / V decays with L_v / V (constant ``L_v``, default 533.4 m), and the yaw
        rate of the air mass r_g = -s / (1 + tau s) beta_g (tau = 4 b / (pi V); the
        MIL-F-8785C form, which JSBSim's r_turb follows approximately) enters the aerodynamics as r - r_g
        (CYr, Clr, Cnr). Constant ``kin_angles`` = 1 (default 0): the beta output is
        beta_k, for a sideslip rebuilt from the flight path (no vane: from the inertial
        velocity and a known wind), which sees no gust."""
    c = require_constants(
        constants, ("m", "Ixx", "Iyy", "Izz", "Ixz", "S", "b", "rho"), "lateral-directional (measured longitudinal)"
    )
    for k, v in {
        "g": 9.80665,
        "x_vane": 0.0,
        "z_vane": 0.0,
        "x_imu": 0.0,
        "z_imu": 0.0,
        "L_v": 533.4,
        "kin_angles": 0.0,
    }.items():
        c.setdefault(k, v)
    gust_free = rotary_gust and "tau_pg" in set(free or ())
    tau0 = dict(values or {}).get("tau_pg", 4.0 * c["b"] / (np.pi * 30.0))
    params = make_parameters(
        DEFAULTS,
        {k: v for k, v in (values or {}).items() if k != "tau_pg"},
        None if free is None else [f for f in free if f != "tau_pg"],
        DEFAULT_FREE,
        bounds,
    )
    if rotary_gust:
        params.append(Parameter("tau_pg", float(tau0), gust_free, (0.02, 5.0)))
    return Model(
        states=["beta", "p", "r", "phi"] + (["p_g", "beta_k", "beta_gf"] if rotary_gust else []),
        inputs=["da", "dr", "V", "alpha", "theta", "q"],
        outputs=["beta", "p", "r", "phi", "ay"],
        parameters=params,
        constants=c,
        f=f_measured_gust if rotary_gust else f_measured,
        g=g_measured_gust if rotary_gust else g_measured,
        output_biases=list(output_biases),
        name=name,
    )


# -- per-segment airspeed correction of the pseudo-input V ------------------------------------
#: input order of the lateral-measured model (the wrappers below rebuild this tuple)
_MEASURED_INPUTS = ["da", "dr", "V", "alpha", "theta", "q"]
_OFFSET_FG: dict = {}


def _offset_fg(f0, g0):
    """(f, g) of a lateral-measured model with V + p.dV in place of the input V; cached per
    (f0, g0) so that models built again share one compiled kernel."""
    key = (f0, g0)
    if key not in _OFFSET_FG:
        fj = register_jitable(f0)

        def f_dv(x, u, p, c):
            da, dr, V, alpha, theta, qr = u
            return fj(x, (da, dr, V + p.dV, alpha, theta, qr), p, c)

        def g_dv(x, u, p, c):
            da, dr, V, alpha, theta, qr = u
            return g0(x, (da, dr, V + p.dV, alpha, theta, qr), p, c)

        _OFFSET_FG[key] = (f_dv, g_dv)
    return _OFFSET_FG[key]


def with_airspeed_offset(model: Model) -> Model:
    """The model of :func:`lateral_measured_longitudinal` with a per-segment airspeed
    correction ``dV[k]`` (m/s, start 0, free): the dynamics see V + dV[k] wherever the
    pseudo-input V enters (dynamic pressure, b/2V, g/V, the vane's lever arm).

    What it is for: the measured airspeed is an input, and output error takes inputs as
    exact. The pitot noise that survives the pseudo-input low-pass moves each window's mean
    airspeed by sigma_V / sqrt(n) (n pitot samples in the window), which scales every
    moment of that window and can move the derivatives by several of their Cramer-Rao
    bounds. With dV[k] free and an a-priori penalty N(0, that std) on it
    (OutputError(priors=...)) the bounds carry that uncertainty through the
    correlations. The data alone hardly determine dV (a common change of all dV[k] is
    nearly a common scale of all derivatives): fit it with the priors."""
    if list(model.inputs) != _MEASURED_INPUTS:
        raise ModelDefinitionError(f"with_airspeed_offset needs the inputs {_MEASURED_INPUTS}, not {model.inputs}")
    f_dv, g_dv = _offset_fg(model.f, model.g)
    return Model(
        states=list(model.states),
        inputs=list(model.inputs),
        outputs=list(model.outputs),
        parameters=list(model.parameters) + [Parameter("dV", 0.0, True, per_segment=True, unit="m/s")],
        constants=dict(model.constants),
        f=f_dv,
        g=g_dv,
        output_biases=list(model.output_biases),
        name=model.name,
    )
