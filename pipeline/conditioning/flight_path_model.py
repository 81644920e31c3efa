"""The kinematic model of flight path reconstruction (the data-compatibility check,
:mod:`pipeline.conditioning.compatibility`).

The model integrates the measured specific forces and body rates (corrected by biases and
scale factors) into the body velocity, attitude and altitude, and predicts what the
air-data boom, attitude reference, barometer and GPS should have measured.

States   x = u v w [m/s, body axes, air-relative = inertial in calm air], phi theta psi [rad], h [m]
Inputs   ax ay az [m/s^2] (IMU, moved to the CG with the known IMU position), p q r [rad/s]
Outputs  V alpha beta (at the boom position, delayed by ``delay_air``), phi theta psi, h, vn ve vd

The states are air-relative; the inertial velocity the GPS / navigation filter logs is
theirs plus a steady horizontal wind ``wind_n``, ``wind_e`` [m/s], one for the flight.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numba.extending import register_jitable

from estimators import Model, Parameter
from pipeline.errors import FsidError

G0 = 9.80665
STATES = ["u", "v", "w", "phi", "theta", "psi", "h"]
INPUTS = ["ax", "ay", "az", "p", "q", "r"]
#: model inputs: the IMU channels plus angular accelerations [rad/s^2] differentiated from the
#: gyros (used only for the boom velocity derivative in the delay term)
MODEL_INPUTS = INPUTS + ["pdot", "qdot", "rdot"]
ALL_OUTPUTS = ["V", "alpha", "beta", "phi", "theta", "psi", "h", "vn", "ve", "vd"]
IMU_PARAMS = [f"bias_{c}" for c in INPUTS] + [f"scale_{c}" for c in INPUTS]
AIR_PARAMS = ["bias_V", "scale_V", "bias_alpha", "scale_alpha", "bias_beta", "scale_beta", "delay_air"]
#: the steady wind (m/s, NED) between the air-relative states and vn, ve
WIND_PARAMS = ["wind_n", "wind_e"]
#: estimated by default: IMU biases, air-data biases and scale factors, air-data delay
DEFAULT_ESTIMATE = tuple([f"bias_{c}" for c in INPUTS] + AIR_PARAMS)
#: initial std of each parameter for the EKF (SI units)
PARAM_STD = {
    **{f"bias_{c}": 0.5 for c in ("ax", "ay", "az")},
    **{f"bias_{c}": 0.05 for c in ("p", "q", "r")},
    **{f"scale_{c}": 0.1 for c in INPUTS + ["V", "alpha", "beta"]},
    "bias_V": 2.0,
    "bias_alpha": 0.05,
    "bias_beta": 0.05,
    "delay_air": 0.02,
    "wind_n": 10.0,
    "wind_e": 10.0,
}
#: parameter -> its unit (for reports)
UNITS = {
    **{f"bias_{c}": "m/s^2" for c in ("ax", "ay", "az")},
    **{f"bias_{c}": "rad/s" for c in ("p", "q", "r")},
    **{f"scale_{c}": "-" for c in INPUTS + ["V", "alpha", "beta"]},
    "bias_V": "m/s",
    "bias_alpha": "rad",
    "bias_beta": "rad",
    "delay_air": "s",
}


@register_jitable
def _body_kinematics(x, u, p, c):
    """Corrected IMU rates and the body-axis velocity derivatives (m/s^2): the measured
    specific forces and rates with bias and scale factor removed drive u, v, w."""
    uu, vv, ww, phi, theta, psi, h = x
    axm, aym, azm, pm, qm, rm, pd, qd, rd = u
    ax = (axm - p.bias_ax) / (1.0 + p.scale_ax)
    ay = (aym - p.bias_ay) / (1.0 + p.scale_ay)
    az = (azm - p.bias_az) / (1.0 + p.scale_az)
    pr = (pm - p.bias_p) / (1.0 + p.scale_p)
    qr = (qm - p.bias_q) / (1.0 + p.scale_q)
    rr = (rm - p.bias_r) / (1.0 + p.scale_r)
    sph, cph = np.sin(phi), np.cos(phi)
    sth, cth = np.sin(theta), np.cos(theta)
    udot = rr * vv - qr * ww - c.g * sth + ax
    vdot = pr * ww - rr * uu + c.g * cth * sph + ay
    wdot = qr * uu - pr * vv + c.g * cth * cph + az
    return pr, qr, rr, udot, vdot, wdot


def _f(x, u, p, c):
    uu, vv, ww, phi, theta, psi, h = x
    pr, qr, rr, udot, vdot, wdot = _body_kinematics(x, u, p, c)
    sph, cph = np.sin(phi), np.cos(phi)
    sth, cth = np.sin(theta), np.cos(theta)
    phidot = pr + np.tan(theta) * (qr * sph + rr * cph)
    thetadot = qr * cph - rr * sph
    psidot = (qr * sph + rr * cph) / cth
    hdot = uu * sth - vv * sph * cth - ww * cph * cth
    return udot, vdot, wdot, phidot, thetadot, psidot, hdot


def _g(x, u, p, c):
    uu, vv, ww, phi, theta, psi, h = x
    axm, aym, azm, pm, qm, rm, pd, qd, rd = u
    pr, qr, rr, udot, vdot, wdot = _body_kinematics(x, u, p, c)
    sph, cph = np.sin(phi), np.cos(phi)
    sth, cth = np.sin(theta), np.cos(theta)
    sps, cps = np.sin(psi), np.cos(psi)
    # velocity at the boom: v + omega x r_boom
    ub = uu + qr * c.zb - rr * c.yb
    vb = vv + rr * c.xb - pr * c.zb
    wb = ww + pr * c.yb - qr * c.xb
    ubd = udot + qd * c.zb - rd * c.yb
    vbd = vdot + rd * c.xb - pd * c.zb
    wbd = wdot + pd * c.yb - qd * c.xb
    V = np.sqrt(ub * ub + vb * vb + wb * wb)
    alpha = np.arctan2(wb, ub)
    beta = np.arcsin(vb / V)
    Vdot = (ub * ubd + vb * vbd + wb * wbd) / V
    alphadot = (ub * wbd - wb * ubd) / (ub * ub + wb * wb)
    betadot = (vbd * V - vb * Vdot) / (V * np.sqrt(ub * ub + wb * wb))
    Vm = (1.0 + p.scale_V) * (V - p.delay_air * Vdot) + p.bias_V
    am = (1.0 + p.scale_alpha) * (alpha - p.delay_air * alphadot) + p.bias_alpha
    bm = (1.0 + p.scale_beta) * (beta - p.delay_air * betadot) + p.bias_beta
    # NED inertial velocity: air-relative plus the steady wind
    vn = cth * cps * uu + (sph * sth * cps - cph * sps) * vv + (cph * sth * cps + sph * sps) * ww + p.wind_n
    ve = cth * sps * uu + (sph * sth * sps + cph * cps) * vv + (cph * sth * sps - sph * cps) * ww + p.wind_e
    vd = -sth * uu + sph * cth * vv + cph * cth * ww
    return Vm, am, bm, phi, theta, psi, h, vn, ve, vd


def kinematic_model(
    outputs: Sequence[str] = ALL_OUTPUTS,
    estimate: Sequence[str] = DEFAULT_ESTIMATE,
    boom_position: Sequence[float] = (0.0, 0.0, 0.0),
    start: Mapping[str, float] | None = None,
    wind: bool | tuple[float, float] = False,
):
    """The flight-path-reconstruction model as an ``estimators.Model``.

    outputs : subset of ALL_OUTPUTS the data have; estimate : free parameter names;
    boom_position : air-data boom position from the CG, body axes [m]; wind : True: estimate
    the steady wind (wind_n, wind_e, one for the flight) when vn/ve are among the outputs;
    (north, east) m/s: hold it there; False: calm air.
    """
    names = IMU_PARAMS + AIR_PARAMS
    bad = [e for e in estimate if e not in names]
    if bad:
        raise FsidError(f"unknown compatibility parameter(s) {bad}; choose from {names}")
    start = dict(start or {})
    params = []
    for n in names:
        lo, hi = (-0.5, 0.5) if n.startswith("scale") else (-0.2, 0.5) if n == "delay_air" else (-np.inf, np.inf)
        params.append(
            Parameter(n, float(start.get(n, 0.0)), free=n in estimate, bounds=(lo, hi), unit=UNITS.get(n, ""))
        )
    held = tuple(wind) if isinstance(wind, (tuple, list)) else (0.0, 0.0)
    free = wind is True and any(c in outputs for c in ("vn", "ve"))
    params += [Parameter(n, float(start.get(n, w0)), free=free, unit="m/s") for n, w0 in zip(WIND_PARAMS, held)]
    xb, yb, zb = (float(v) for v in boom_position)
    model = Model(
        states=STATES,
        inputs=MODEL_INPUTS,
        outputs=list(ALL_OUTPUTS),
        parameters=params,
        constants={"g": G0, "xb": xb, "yb": yb, "zb": zb},
        f=_f,
        g=_g,
        name="flight_path_reconstruction",
    )
    if list(outputs) != list(ALL_OUTPUTS):
        model = model.select_outputs(list(outputs))
    return model
