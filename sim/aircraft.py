"""Aircraft truth sets: geometry, mass, inertia, thrust model and aerodynamic derivatives.

A truth set is a TOML file. Every quantity carries its unit in the key name (``S_m2``, ``mass_kg``, ``Ixx_kgm2``...). Derivatives use the DESIGN.md names
and are per radian; rate derivatives are nondimensionalised with c/(2V) (pitch) and
b/(2V) (roll, yaw), alphadot likewise with c/(2V).

Aerodynamic model (exactly what the generated JSBSim aircraft evaluates)::

    CL = CL0 + CLalpha*alpha + CLalpha2*alpha**2 + CLq*q_a*c/(2V) + CLalphadot*alphadot*c/(2V) + CLde*de
    CD = CD0 + CDalpha*alpha + CDalpha2*alpha**2 + CDde*de
    Cm = Cm0 + Cmalpha*alpha + Cmq*q_a*c/(2V) + Cmalphadot*alphadot*c/(2V) + Cmde*de
    CY = CYasym + CYbeta*beta + CYp*p_a*b/(2V) + CYr*r_a*b/(2V) + CYda*da + CYdr*dr
    Cl = Clasym + Clbeta*beta + Clp*p_a*b/(2V) + Clr*r_a*b/(2V) + Clda*da + Cldr*dr
    Cn = Cnasym + Cnbeta*beta + Cnp*p_a*b/(2V) + Cnr*r_a*b/(2V) + Cnda*da + Cndr*dr

CL, CD act in stability axes (lift normal to, drag against the projection of the airspeed
on the symmetry plane; JSBSim ``<axis name="Z|X" frame="STABILITY">``), CY along body y;
Cl, Cm, Cn are body-axis moments about the CG (the aerodynamic reference point is the
CG). With beta = 0 stability and wind axes coincide. p_a, q_a, r_a are the
aerodynamic rates (body rates minus turbulence rates). CYasym, Clasym, Cnasym (optional,
default 0) are a lateral asymmetry (rigging, propeller torque and swirl): a truth set with
any of them is trimmed with aileron and rudder offsets and a steady bank
(:attr:`Aircraft.asymmetric`). They are named apart from the lateral models' trim terms
CY0, Cl0, Cn0, a different quantity: those are taken with the controls relative to their
trim, so they hold the trim's side force and moments, not the aircraft's constants.
Thrust = throttle * max_thrust_N along body x through the CG, independent of airspeed and density.

Optional tables: ``[sensors.airdata|imu] position_m = [x, y, z]`` (m from the CG, body
axes; read by ``fsid estimate``) and ``[servos] de_travel_deg, da_travel_deg,
dr_travel_deg``: the surface deflection at full servo travel (PWM MAX - TRIM, and
TRIM - MIN), default SERVO_TRAVEL_DEG. The simulator's servos take whole microseconds of
it; ``fsid estimate`` decodes a log's servo PWM (ArduPilot RCOU, MAVLink
SERVO_OUTPUT_RAW) with it, and the control derivatives scale with it.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim.errors import ScenarioError

#: derivative names per force/moment coefficient, in DESIGN.md order
DERIVATIVES: dict[str, tuple[str, ...]] = {
    "CL": ("CL0", "CLalpha", "CLalpha2", "CLq", "CLalphadot", "CLde"),
    "CD": ("CD0", "CDalpha", "CDalpha2", "CDde"),
    "Cm": ("Cm0", "Cmalpha", "Cmq", "Cmalphadot", "Cmde"),
    "CY": ("CYasym", "CYbeta", "CYp", "CYr", "CYda", "CYdr"),
    "Cl": ("Clasym", "Clbeta", "Clp", "Clr", "Clda", "Cldr"),
    "Cn": ("Cnasym", "Cnbeta", "Cnp", "Cnr", "Cnda", "Cndr"),
}
ALL_DERIVATIVES: tuple[str, ...] = tuple(n for names in DERIVATIVES.values() for n in names)
#: derivatives that may be omitted (taken as zero)
OPTIONAL_DERIVATIVES = {
    "CLalphadot",
    "Cmalphadot",
    "CDalpha2",
    "CLalpha2",
    "CDde",
    "CYp",
    "CYr",
    "CLq",
    "CYasym",
    "Clasym",
    "Cnasym",
}
#: the lateral asymmetry coefficients (optional; any non-zero one asks for a lateral trim too)
ASYMMETRY = ("CYasym", "Clasym", "Cnasym")

#: regressor of each derivative, as a function of a truth table (columns named as in
#: DESIGN.md section 3 plus p_aero, q_aero, r_aero, alphadot); c2v = c/(2V), b2v = b/(2V)
_REGRESSOR = {
    "0": lambda d, c2v, b2v: np.ones_like(d["alpha"]),
    "asym": lambda d, c2v, b2v: np.ones_like(d["alpha"]),
    "alpha": lambda d, c2v, b2v: d["alpha"],
    "alpha2": lambda d, c2v, b2v: d["alpha"] ** 2,
    "q": lambda d, c2v, b2v: d["q_aero"] * c2v,
    "alphadot": lambda d, c2v, b2v: d["alphadot"] * c2v,
    "beta": lambda d, c2v, b2v: d["beta"],
    "p": lambda d, c2v, b2v: d["p_aero"] * b2v,
    "r": lambda d, c2v, b2v: d["r_aero"] * b2v,
    "de": lambda d, c2v, b2v: d["de"],
    "da": lambda d, c2v, b2v: d["da"],
    "dr": lambda d, c2v, b2v: d["dr"],
}


def regressor_key(name: str) -> str:
    """The state/input a derivative multiplies: ``Cmq`` -> ``q``, ``CDalpha2`` -> ``alpha2``."""
    for coef in DERIVATIVES:
        if name.startswith(coef) and name in DERIVATIVES[coef]:
            return name[len(coef) :]
    raise KeyError(name)


@dataclass(frozen=True)
class Aircraft:
    """A truth set. SI units: m, m^2, kg, kg m^2, N, rad."""

    name: str
    path: Path
    S: float  #: wing area, m^2
    b: float  #: span, m
    cbar: float  #: mean aerodynamic chord, m
    mass: float  #: kg
    Ixx: float  #: kg m^2
    Iyy: float
    Izz: float
    Ixz: float  #: product of inertia, kg m^2 (positive = int(x z dm), body axes)
    max_thrust: float  #: N, thrust = throttle * max_thrust along body x
    limits: dict[str, float]  #: surface deflection limits, rad: de, da, dr
    derivatives: dict[str, float]  #: every name of ALL_DERIVATIVES, per rad
    description: str = ""
    source: str = ""
    raw: dict = field(default_factory=dict, repr=False)
    #: optional sensor positions from the CG, body axes, m: ``airdata`` (vane/boom), ``imu``
    #: (``[sensors.<name>] position_m``; read by ``fsid estimate``, the simulator takes the
    #: scenario's ``[sensors]``)
    sensors: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    #: deflection at full servo travel (PWM MAX - TRIM and TRIM - MIN), rad, of the surfaces
    #: the ``[servos]`` table gives (``de_travel_deg``...): how an autopilot's servo PWM maps
    #: to the surface. The simulator's servos take whole microseconds of it (``travel``);
    #: ``fsid estimate`` decodes a log's servo PWM with it
    servo_travel: dict[str, float] = field(default_factory=dict)

    def travel(self, axis: str) -> float:
        """Deflection at full servo travel of surface ``axis`` (de, da, dr), rad: the
        ``[servos]`` value, else SERVO_TRAVEL_DEG."""
        return self.servo_travel.get(axis, float(np.deg2rad(SERVO_TRAVEL_DEG)))

    @property
    def asymmetric(self) -> bool:
        """Whether the truth set has a lateral asymmetry (CYasym, Clasym or Cnasym non-zero): it then
        needs aileron and rudder to trim, and a steady bank to balance the side force."""
        return any(self.derivatives[n] != 0.0 for n in ASYMMETRY)

    def coefficients(self, d) -> dict[str, np.ndarray]:
        """Evaluate the truth formula on a table ``d`` (mapping of column -> array, shape (N,)).

        ``d`` needs V, alpha, beta, alphadot, p_aero, q_aero, r_aero, de, da, dr.
        Returns CL, CD, Cm, CY, Cl, Cn as arrays of shape (N,).
        """
        V = np.asarray(d["V"], dtype=float)
        c2v = self.cbar / (2.0 * V)
        b2v = self.b / (2.0 * V)
        out = {}
        for coef, names in DERIVATIVES.items():
            total = np.zeros_like(V)
            for n in names:
                total = total + self.derivatives[n] * np.asarray(_REGRESSOR[regressor_key(n)](d, c2v, b2v))
            out[coef] = total
        return out

    def to_dict(self) -> dict:
        """JSON-ready description (SI units, radians)."""
        return {
            "name": self.name,
            "description": self.description,
            "source": self.source,
            "geometry": {"S_m2": self.S, "b_m": self.b, "cbar_m": self.cbar},
            "mass": {
                "mass_kg": self.mass,
                "Ixx_kgm2": self.Ixx,
                "Iyy_kgm2": self.Iyy,
                "Izz_kgm2": self.Izz,
                "Ixz_kgm2": self.Ixz,
            },
            "propulsion": {
                "max_thrust_N": self.max_thrust,
                "model": "thrust = throttle * max_thrust_N, body x axis through the CG",
            },
            "limits_rad": dict(self.limits),
            "servo_travel_rad": dict(self.servo_travel),
            "derivatives": dict(self.derivatives),
        }


_SECTIONS = {
    "geometry": {"S_m2", "b_m", "cbar_m"},
    "mass": {"mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2", "Ixz_kgm2"},
    "propulsion": {"max_thrust_N"},
    "limits": {"de_deg", "da_deg", "dr_deg"},
}
_TOP = {"name", "description", "source", "derivatives", "sensors", "servos"} | set(_SECTIONS)
#: default deflection (deg) at full servo travel, PWM MAX - TRIM = SERVO_SPAN_US microseconds
SERVO_TRAVEL_DEG = 30.0
SERVO_SPAN_US = 400
#: optional ``[servos]`` keys (deg): the deflection at full servo travel per surface
_SERVOS = {"de_travel_deg", "da_travel_deg", "dr_travel_deg"}


def _servo_travel(path: Path, raw, limits: dict[str, float]) -> dict[str, float]:
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise _fail(path, "servos", "must be a table of de_travel_deg, da_travel_deg, dr_travel_deg")
    out = {}
    for k, v in raw.items():
        if k not in _SERVOS:
            hint = _unit_hint(_SERVOS, k)
            raise _fail(
                path,
                f"servos.{k}",
                f"wrong unit; write it as servos.{hint}"
                if hint
                else f"unknown key; allowed: {', '.join(sorted(_SERVOS))}",
            )
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not 0 < v <= 90:
            raise _fail(path, f"servos.{k}", f"must be a deflection in deg, 0 < x <= 90, got {v!r}")
        axis = k.split("_")[0]
        if np.deg2rad(v) < limits[axis] - 1e-12:
            raise _fail(
                path,
                f"servos.{k}",
                f"{v:g} deg is less than the surface limit limits.{axis}_deg "
                f"({np.rad2deg(limits[axis]):.3g} deg): full servo travel must reach it",
            )
        out[axis] = float(np.deg2rad(v))
    return out


#: optional ``[sensors.<name>]`` tables of an aircraft file and their keys
_SENSORS = {"airdata": {"position_m"}, "imu": {"position_m"}}


def _sensor_positions(path: Path, raw) -> dict[str, tuple[float, float, float]]:
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise _fail(path, "sensors", "must be a table of [sensors.airdata] / [sensors.imu]")
    out = {}
    for name, tab in raw.items():
        if name not in _SENSORS:
            raise _fail(path, f"sensors.{name}", f"unknown sensor; allowed: {', '.join(sorted(_SENSORS))}")
        if not isinstance(tab, dict):
            raise _fail(path, f"sensors.{name}", "must be a table with position_m = [x, y, z]")
        for k in tab:
            if k not in _SENSORS[name]:
                raise _fail(path, f"sensors.{name}.{k}", f"unknown key; allowed: {', '.join(sorted(_SENSORS[name]))}")
        v = tab.get("position_m")
        if v is None:
            continue
        if (
            not isinstance(v, list)
            or len(v) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        ):
            raise _fail(
                path, f"sensors.{name}.position_m", f"must be [x, y, z] in m from the CG (body axes), got {v!r}"
            )
        out[name] = tuple(float(x) for x in v)
    return out


def _fail(path: Path, key: str, why: str) -> ScenarioError:
    return ScenarioError(f"{path}: {key}: {why}")


def _unit_hint(known: set[str], key: str) -> str | None:
    base = key.split("_")[0]
    for k in known:
        if k.split("_")[0] == base and k != key:
            return k
    return None


def load_aircraft(path: str | Path) -> Aircraft:
    """Read and validate an aircraft truth set TOML file.

    Raises :class:`sim.ScenarioError` (one line) for an unknown key, a missing field, a
    key with the wrong unit suffix, or a non-physical value.
    """
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ScenarioError(
            f"{path}: aircraft file not found; check the path or the scenario's 'aircraft' key"
        ) from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML ({exc})") from None
    for key in raw:
        if key not in _TOP:
            raise _fail(path, key, f"unknown key; allowed: {', '.join(sorted(_TOP))}")
    vals: dict[str, dict[str, float]] = {}
    for sec, keys in _SECTIONS.items():
        if sec not in raw:
            raise _fail(path, sec, "missing section")
        got = raw[sec]
        if not isinstance(got, dict):
            raise _fail(path, sec, "must be a table")
        for k, v in got.items():
            if k not in keys:
                hint = _unit_hint(keys, k)
                if hint:
                    raise _fail(path, f"{sec}.{k}", f"wrong unit; write it as {sec}.{hint}")
                raise _fail(path, f"{sec}.{k}", f"unknown key; allowed: {', '.join(sorted(keys))}")
            if not isinstance(v, (int, float)) or isinstance(v, bool):
                raise _fail(path, f"{sec}.{k}", f"must be a number, got {v!r}")
        for k in keys:
            if k not in got:
                raise _fail(path, f"{sec}.{k}", "missing field")
        vals[sec] = {k: float(v) for k, v in got.items()}
    for sec, k in [
        ("geometry", "S_m2"),
        ("geometry", "b_m"),
        ("geometry", "cbar_m"),
        ("mass", "mass_kg"),
        ("mass", "Ixx_kgm2"),
        ("mass", "Iyy_kgm2"),
        ("mass", "Izz_kgm2"),
        ("propulsion", "max_thrust_N"),
        ("limits", "de_deg"),
        ("limits", "da_deg"),
        ("limits", "dr_deg"),
    ]:
        if not vals[sec][k] > 0:
            raise _fail(path, f"{sec}.{k}", f"must be > 0, got {vals[sec][k]}")
    der = raw.get("derivatives")
    if not isinstance(der, dict):
        raise _fail(path, "derivatives", "missing section")
    for k, v in der.items():
        if k not in ALL_DERIVATIVES:
            raise _fail(path, f"derivatives.{k}", "unknown derivative; use the DESIGN.md names (e.g. Cmq, CLalpha)")
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise _fail(path, f"derivatives.{k}", f"must be a number (per radian), got {v!r}")
    for k in ALL_DERIVATIVES:
        if k not in der and k not in OPTIONAL_DERIVATIVES:
            raise _fail(path, f"derivatives.{k}", "missing field")
    derivs = {k: float(der.get(k, 0.0)) for k in ALL_DERIVATIVES}
    g, m = vals["geometry"], vals["mass"]
    limits = {a: float(np.deg2rad(vals["limits"][f"{a}_deg"])) for a in ("de", "da", "dr")}
    return Aircraft(
        name=str(raw.get("name", path.stem)),
        path=path.resolve(),
        S=g["S_m2"],
        b=g["b_m"],
        cbar=g["cbar_m"],
        mass=m["mass_kg"],
        Ixx=m["Ixx_kgm2"],
        Iyy=m["Iyy_kgm2"],
        Izz=m["Izz_kgm2"],
        Ixz=m["Ixz_kgm2"],
        max_thrust=vals["propulsion"]["max_thrust_N"],
        limits=limits,
        derivatives=derivs,
        description=str(raw.get("description", "")),
        source=str(raw.get("source", "")),
        raw=raw,
        sensors=_sensor_positions(path, raw.get("sensors")),
        servo_travel=_servo_travel(path, raw.get("servos"), limits),
    )
