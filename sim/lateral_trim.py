"""Trim of a laterally asymmetric aircraft: steady straight flight with aileron, rudder and bank.

A truth set with CYasym, Clasym or Cnasym (:attr:`sim.aircraft.Aircraft.asymmetric`) needs aileron
and rudder to hold its wings against the rolling and yawing moments, and a steady bank to
balance the side force that remains, as a real aircraft with rigging or propeller
asymmetry does. JSBSim's own full trim did not move the aileron and rudder of the
generated FCS (probe of jsbsim 1.3.3), so the lateral trim is solved here around JSBSim's
longitudinal trim: Newton's method on the bank angle and the aileron and rudder trim
commands (``fcs/roll-trim-cmd-norm``, ``fcs/yaw-trim-cmd-norm``) driving vdot, pdot and
rdot to zero, each evaluation a full longitudinal trim at that bank and those controls.
The sideslip stays at the initial condition's (zero, up to the bank's small coupling).
"""

from __future__ import annotations

import numpy as np

#: ft -> m
_FT = 0.3048
#: largest residual accepted: vdot (m/s^2), pdot, rdot (rad/s^2)
_TOLERANCE = 1e-6
#: finite-difference step of the Jacobian: bank (rad) and normalised commands
_STEP = 1e-4
_ITERATIONS = 10


def _residual(fdm, x: np.ndarray) -> np.ndarray:
    """(vdot m/s^2, pdot, rdot rad/s^2) after the longitudinal trim at bank x[0] (rad) and
    aileron, rudder trim commands x[1], x[2] (normalised)."""
    fdm["ic/phi-rad"] = float(x[0])
    fdm["fcs/roll-trim-cmd-norm"] = float(x[1])
    fdm["fcs/yaw-trim-cmd-norm"] = float(x[2])
    fdm.run_ic()
    fdm.do_trim(0)
    return np.array(
        [
            fdm["accelerations/vdot-ft_sec2"] * _FT,
            fdm["accelerations/pdot-rad_sec2"],
            fdm["accelerations/rdot-rad_sec2"],
        ]
    )


def trim_with_asymmetry(fdm) -> dict[str, float]:
    """Trim ``fdm`` (initial condition set, run_ic done) in steady straight flight with the
    bank and the aileron and rudder trim that zero the lateral accelerations; returns the
    bank, sideslip and the aileron, rudder deflections (rad) of the trim. Raises
    jsbsim.TrimFailureError when the longitudinal trim fails or the Newton iteration does
    not converge (a trim command beyond full deflection)."""
    import jsbsim

    x = np.zeros(3)
    for _ in range(_ITERATIONS):
        r = _residual(fdm, x)
        if np.max(np.abs(r)) < _TOLERANCE:
            break
        J = np.column_stack([(_residual(fdm, x + h) - r) / _STEP for h in np.eye(3) * _STEP])
        try:
            x = x - np.linalg.solve(J, r)
        except np.linalg.LinAlgError:
            raise jsbsim.TrimFailureError("lateral trim: singular Jacobian") from None
        if np.any(np.abs(x[1:]) > 1.0) or abs(x[0]) > np.deg2rad(45.0):
            raise jsbsim.TrimFailureError("lateral trim: beyond full aileron/rudder or 45 deg of bank")
    else:
        raise jsbsim.TrimFailureError("lateral trim did not converge")
    return {
        "phi": float(fdm["attitude/phi-rad"]),
        "beta": float(fdm["aero/beta-rad"]),
        "da": float(fdm["fcs/da-pos-rad"]),
        "dr": float(fdm["fcs/dr-pos-rad"]),
    }
