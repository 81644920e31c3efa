"""The channel-map format: TOML tables saying which log field becomes which canonical
channel, parsed into :class:`ChannelRule` and :class:`ChannelMap`.

Map file format (all keys but ``source`` optional)::

    [map]
    name = "ardupilot_bin"
    formats = ["dataflash"]          # readers this map fits
    extends = "ardupilot_bin"        # (user maps) start from a built-in map and override it

    [channels.q]
    source = ["IMU[0].GyrY", "IMU.GyrY", "SCALED_IMU.ygyro mrad/s"]   # first present wins;
                                            # a unit after a space applies to that source,
                                            # a leading "-" negates it ("-LOCAL_POSITION_NED.z m")
    unit = "rad/s"                          # unit of the *source* (converted to SI)
    scale = 1.0                             # si = to_si(unit)((raw * scale) + offset) * sign
    offset = 0.0
    sign = 1

    [channels.de]                            # servo PWM -> deflection (ArduPilot SERVOn_*)
    source = "RCOU.C2"
    unit = "pwm"
    pwm = { function = 19, channel = 2, travel_deg = 30.0 }

    [channels.alpha]                         # an autopilot's estimate, not a sensor:
    source = "AOA.AOA"                       # fsid estimate rebuilds it from the flight
    unit = "deg"                             # path (pipeline.conditioning.flow_angles) when it can
    derived = "ArduPilot's AHRS estimate (EKF velocity minus its wind), not a vane"

    [channels.da]                            # a VTOL (the log has VT_TYPE): its fixed-wing
    source = "actuator_controls_0.control[0]"  # controls are group 1
    source_if = { VT_TYPE = ["actuator_controls_1.control[0]"] }

    [channels.V.fallback]                    # tried when the rule above fills nothing
    source = ["CTUN.As", "CTUN.E2T"]         # (no airspeed sensor: the autopilot's estimate)
    transform = "product"
    derived = "ArduPilot's airspeed estimate, not a pitot"

    [channels.vn.fallback]                   # no EKF velocity: the GPS ground speed
    source = ["GPS.Spd", "GPS.GCrs"]         # along its course (deg)
    transform = "polar"
    component = "north"                      # (ve: "east")

    [channels.phi]                           # quaternion -> Euler angle (w, x, y, z order)
    source = ["vehicle_attitude.q[0]", "vehicle_attitude.q[1]", "vehicle_attitude.q[2]", "vehicle_attitude.q[3]"]
    transform = "quat_wxyz"
    component = "phi"

MESSAGE is the text before the first dot: a DataFlash/MAVLink message name (``IMU``,
``ATTITUDE``), a DataFlash instance (``IMU[1]``), a ULog topic (``sensor_combined``, multi
instance ``actuator_outputs[1]``), an MCAP topic (``/imu/data``), an MCAP schema prefixed
with ``@`` (``@sensor_msgs/msg/Imu``: the first topic with that schema), or ``csv`` for
column files. The field after the dot may be nested (``angular_velocity.x``) or indexed
(``q[0]``).

PWM calibration: ``pwm = {function = F}`` finds the output n whose ``SERVOn_FUNCTION``
parameter is F (ArduPilot: 4 aileron, 19 elevator, 21 rudder, 70 throttle); ``channel``
only when the log has no SERVOn_FUNCTION parameters. Mixed surfaces: ``mix = [{functions
= [77, 78], weights = [0.5, 0.5]}, ...]`` - when no output has F, the first entry whose
functions all have an output gives the channel as the weighted sum of those outputs'
deflections (ArduPilot elevons 77/78 = (elevator -/+ aileron) x MIXING_GAIN, V-tail 79/80
= (elevator +/- rudder) x MIXING_GAIN: the elevator is their mean, the aileron or rudder
half their difference). The pulse is normalised with the ``SERVOn_MIN/MAX/TRIM/REVERSED`` parameters
(or ``min``/``max``/``trim`` numbers in the map, default 1100/1900/1500): (pwm - trim) /
(max - trim) above trim, (pwm - trim) / (trim - min) below, negated when reversed, and
multiplied by the deflection at full travel: the caller's (``read_log(servo_travel=)``;
``fsid estimate`` passes the aircraft TOML's ``[servos]``), else the map's ``travel_deg``
(a number, or the name of a log parameter holding it, e.g. the simulator's
``FSID_TRAVEL_DE``), else DEFAULT_TRAVEL_DEG, assumed - and said in the channel's notes:
the control derivatives scale with it. ``throttle = true`` gives (pwm - min) / (max - min)
instead; ``normalised = true`` takes the source as the normalised -1..1 surface command
(PX4's actuator controls) and multiplies it by the same travel. PX4 1.14+ logs the
allocated surface commands instead (``actuator_servos.control[k]``): a source with ``{k}``
and ``torque = "R"|"P"|"Y"`` sums the control surfaces weighted by their
``CA_SV_CS{k}_TRQ_*`` coefficients over the coefficients' magnitudes (one elevator: its
command; elevons: their mean; ailerons: half their difference).

Sign conventions: canonical body axes are x forward, y right, z down (FRD); ROS uses
x forward, y left, z up (FLU) and ENU, which the ROS 2 map flips with ``sign = -1``.
Control surfaces: positive de = trailing edge down, positive da = right aileron trailing
edge up (roll right ... negative Cl), positive dr = trailing edge left. Altitude ``h`` is
positive up.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import FsidError
from pipeline.ingest.flightdata import CANONICAL_UNITS

#: source unit -> factor to SI (the canonical unit of the channel)
UNIT_FACTORS: dict[str, float] = {
    "m/s^2": 1.0,
    "m/s/s": 1.0,
    "mG": 9.80665e-3,
    "g": 9.80665,
    "cm/s^2": 0.01,
    "rad/s": 1.0,
    "deg/s": np.pi / 180,
    "mrad/s": 1e-3,
    "cdeg/s": np.pi / 18000,
    "rad/s^2": 1.0,
    "deg/s^2": np.pi / 180,
    "rad": 1.0,
    "deg": np.pi / 180,
    "cdeg": np.pi / 18000,
    "mrad": 1e-3,
    "m/s": 1.0,
    "cm/s": 0.01,
    "mm/s": 1e-3,
    "km/h": 1 / 3.6,
    "kt": 0.514444,
    "ft/s": 0.3048,
    "m": 1.0,
    "cm": 0.01,
    "mm": 1e-3,
    "ft": 0.3048,
    "km": 1000.0,
    "Pa": 1.0,
    "hPa": 100.0,
    "mbar": 100.0,
    "kPa": 1000.0,
    "kg/m^3": 1.0,
    "N": 1.0,
    "-": 1.0,
    "%": 0.01,
    "s": 1.0,
    "ms": 1e-3,
    "us": 1e-6,
    "pwm": 1.0,
}


@dataclass
class ChannelRule:
    """How to fill one canonical channel (see the module docstring)."""

    name: str
    sources: list[str]
    unit: str = ""
    scale: float = 1.0
    offset: float = 0.0
    sign: float = 1.0
    pwm: dict | None = None
    transform: str | None = None
    component: str | None = None
    scale_param: str | None = None  #: multiply by this log parameter (missing -> no channel)
    unless_param: str | None = None  #: product transform: skip the 2nd factor if param != 0
    derived: str | None = None  #: why it is no independent measurement (Channel.derived)
    #: {parameter: sources}: when the log has that parameter, those sources replace ``sources``
    source_if: dict[str, list[str]] = field(default_factory=dict)
    #: the rule to try when this one fills nothing (``[channels.NAME.fallback]``)
    fallback: ChannelRule | None = None

    def scaled(self, x: np.ndarray, unit: str | None = None) -> np.ndarray:
        """Logged values ``x`` in the canonical unit: (x scale + offset), converted from
        ``unit`` (default the rule's), times the sign."""
        return (x * self.scale + self.offset) * UNIT_FACTORS.get(unit or self.unit, 1.0) * self.sign

    def sources_for(self, params: Mapping[str, float]) -> list[str]:
        """The sources to try for a log with these parameters (``source_if``)."""
        for name, srcs in self.source_if.items():
            if name in params:
                return list(srcs)
        return list(self.sources)


@dataclass
class ChannelMap:
    """A parsed channel map: ``rules`` by canonical name plus the ``[map]`` header."""

    name: str
    rules: dict[str, ChannelRule] = field(default_factory=dict)
    formats: list[str] = field(default_factory=list)
    header: dict = field(default_factory=dict)
    origin: str = ""

    def merged(self, other: ChannelMap) -> ChannelMap:
        """A copy of self with ``other``'s rules added / overriding."""
        out = copy.deepcopy(self)
        out.rules.update(copy.deepcopy(other.rules))
        out.name = f"{self.name}+{other.name}"
        out.header = {**self.header, **other.header}
        return out


def _source_if(spec, origin: str, name: str) -> dict[str, list[str]]:
    if spec is None:
        return {}
    if not isinstance(spec, dict) or not all(isinstance(v, (str, list)) for v in spec.values()):
        raise FsidError(
            f"channel map {origin}: [channels.{name}] source_if must be a table {{PARAMETER = [\"MESSAGE.field\", ...]}}"
        )
    return {str(k): [v] if isinstance(v, str) else [str(x) for x in v] for k, v in spec.items()}


#: a rule's ``transform``s: quaternion to Euler angle, the product of two sources, a
#: speed along a course (``polar``, component north or east: GPS ground speed and course)
TRANSFORMS = (None, "quat_wxyz", "quat_xyzw", "product", "polar")


def finite_number(spec: Mapping, key: str, default: float, origin: str, where: str) -> float:
    """``spec[key]`` as a finite number (``default`` when absent); FsidError naming the map,
    the table and the value otherwise."""
    v = spec.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise FsidError(f"channel map {origin}: {where} {key} = {v!r} is not a finite number; give a number")
    return float(v)


def parse_rule(name: str, spec, origin: str, what: str = "") -> ChannelRule:
    """One ``[channels.NAME]`` table (``what``: ".fallback" for its fallback) as a rule."""
    where = f"[channels.{name}{what}]"
    if not isinstance(spec, dict) or "source" not in spec:
        raise FsidError(f"channel map {origin}: {where} needs a 'source' (\"MESSAGE.field\" or a list of them)")
    src = spec["source"]
    sources = [src] if isinstance(src, str) else [str(s) for s in src]
    unit = str(spec.get("unit", CANONICAL_UNITS.get(name, "-")))
    if unit not in UNIT_FACTORS:
        raise FsidError(
            f"channel map {origin}: {where} unit '{unit}' unknown; use one of {', '.join(sorted(UNIT_FACTORS))}"
        )
    for src_ in sources:
        parts = src_.split()
        if len(parts) > 1 and parts[1] not in UNIT_FACTORS:
            raise FsidError(f"channel map {origin}: {where} source '{src_}' has unknown unit '{parts[1]}'")
    if spec.get("transform") not in TRANSFORMS:
        raise FsidError(
            f"channel map {origin}: {where} transform '{spec.get('transform')}' "
            f"unknown; use one of {', '.join(t for t in TRANSFORMS if t)}"
        )
    fb = spec.get("fallback")
    if fb is not None and what:
        raise FsidError(f"channel map {origin}: {where} cannot have a fallback of its own")
    scale, offset, sign = (
        finite_number(spec, k, d, origin, where) for k, d in (("scale", 1.0), ("offset", 0.0), ("sign", 1.0))
    )
    if sign not in (1.0, -1.0):
        raise FsidError(f"channel map {origin}: {where} sign {sign:g}: give 1 or -1")
    return ChannelRule(
        name,
        sources,
        unit,
        scale,
        offset,
        sign,
        spec.get("pwm"),
        spec.get("transform"),
        spec.get("component"),
        spec.get("scale_param"),
        spec.get("unless_param"),
        spec.get("derived"),
        _source_if(spec.get("source_if"), origin, name),
        None if fb is None else parse_rule(name, fb, origin, ".fallback"),
    )


def parse_map(doc: dict, origin: str) -> ChannelMap:
    head = doc.get("map", {})
    chans = doc.get("channels", {})
    if not isinstance(chans, dict):
        raise FsidError(f"channel map {origin}: [channels] must be a table; see pipeline/ingest/maps/rules.py")
    rules: dict[str, ChannelRule] = {}
    for name, spec in chans.items():
        rules[name] = parse_rule(name, spec, origin)
    return ChannelMap(
        str(head.get("name", Path(origin).stem)), rules, list(head.get("formats", [])), dict(head), origin
    )
