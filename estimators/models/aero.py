"""The equations the built-in aircraft models share: the linear aerodynamic coefficients
of the longitudinal and lateral-directional derivatives, and the rigid body's roll and yaw
moment equations with the Ixz coupling. One home for each, compiled into every model that
calls them (numba inlines a ``register_jitable`` function into the caller's kernel).

``p`` holds the derivatives by name (per rad; the rates normalised), ``c`` the aircraft's
constants (inertias in kg m^2)."""

from __future__ import annotations

from numba.extending import register_jitable


@register_jitable
def longitudinal_coefficients(alpha, qhat, de, ahat, p):
    """(CL, CD, Cm) of angle of attack ``alpha`` [rad], pitch rate ``qhat`` = q cbar / 2V,
    elevator ``de`` [rad] and ``ahat`` = alphadot cbar / 2V (0 where the caller adds the
    alphadot terms itself); drag quadratic in alpha."""
    CL = p.CL0 + p.CLalpha * alpha + p.CLq * qhat + p.CLde * de + p.CLalphadot * ahat
    CD = p.CD0 + p.CDalpha * alpha + p.CDalpha2 * alpha * alpha + p.CDde * de
    Cm = p.Cm0 + p.Cmalpha * alpha + p.Cmq * qhat + p.Cmde * de + p.Cmalphadot * ahat
    return CL, CD, Cm


@register_jitable
def lateral_coefficients(beta, ph, rh, da, dr, p):
    """(CY, Cl, Cn) of sideslip ``beta`` [rad], roll and yaw rates ``ph`` = p b / 2V,
    ``rh`` = r b / 2V, aileron ``da`` and rudder ``dr`` [rad]."""
    CY = p.CY0 + p.CYbeta * beta + p.CYp * ph + p.CYr * rh + p.CYda * da + p.CYdr * dr
    Cl = p.Cl0 + p.Clbeta * beta + p.Clp * ph + p.Clr * rh + p.Clda * da + p.Cldr * dr
    Cn = p.Cn0 + p.Cnbeta * beta + p.Cnp * ph + p.Cnr * rh + p.Cnda * da + p.Cndr * dr
    return CY, Cl, Cn


@register_jitable
def roll_yaw_accelerations(Lm, Nm, pr, qr, rr, c):
    """(pdot, rdot) [rad/s^2] of the rigid body under rolling and yawing moments ``Lm``,
    ``Nm`` [N m] at body rates ``pr``, ``qr``, ``rr`` [rad/s]: the moment equations with the
    Ixz product of inertia and the gyroscopic terms in q."""
    gam = c.Ixx * c.Izz - c.Ixz * c.Ixz
    pdot = (
        c.Izz * Lm
        + c.Ixz * Nm
        + c.Ixz * (c.Ixx - c.Iyy + c.Izz) * pr * qr
        - (c.Izz * (c.Izz - c.Iyy) + c.Ixz * c.Ixz) * qr * rr
    ) / gam
    rdot = (
        c.Ixz * Lm
        + c.Ixx * Nm
        + (c.Ixx * (c.Ixx - c.Iyy) + c.Ixz * c.Ixz) * pr * qr
        - c.Ixz * (c.Ixx - c.Iyy + c.Izz) * qr * rr
    ) / gam
    return pdot, rdot
