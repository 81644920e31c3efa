"""Channel maps: TOML files saying which log field becomes which canonical channel.

Map file format (all keys but ``source`` optional)::

    [map]
    name = "ardupilot_bin"
    formats = ["dataflash"]          # readers this map fits
    extends = "ardupilot_bin"        # (user maps) start from a built-in map and override it

    [channels.q]
    source = ["IMU[0].GyrY", "IMU.GyrY", "SCALED_IMU.ygyro mrad/s"]   # first present wins;
                                            # a unit after a space applies to that source
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
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from pipeline.errors import FsidError
from pipeline.ingest.flightdata import CANONICAL_UNITS, Channel
from pipeline.ingest.readers.base import RawLog, Table

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

BUILTIN = {
    "dataflash": "ardupilot_bin",
    "tlog": "mavlink_tlog",
    "ulog": "px4_ulog",
    "mcap": "fsid_mcap",
    "mcap-ros2": "ros2",
    "csv": "canonical_csv",
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


def builtin_names() -> list[str]:
    """Names of the built-in maps (the TOML files shipped in this package)."""
    return sorted(p.name[:-5] for p in resources.files(__name__).iterdir() if p.name.endswith(".toml"))


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


def _rule(name: str, spec, origin: str, what: str = "") -> ChannelRule:
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
    return ChannelRule(
        name,
        sources,
        unit,
        float(spec.get("scale", 1.0)),
        float(spec.get("offset", 0.0)),
        float(spec.get("sign", 1.0)),
        spec.get("pwm"),
        spec.get("transform"),
        spec.get("component"),
        spec.get("scale_param"),
        spec.get("unless_param"),
        spec.get("derived"),
        _source_if(spec.get("source_if"), origin, name),
        None if fb is None else _rule(name, fb, origin, ".fallback"),
    )


def _parse(doc: dict, origin: str) -> ChannelMap:
    head = doc.get("map", {})
    chans = doc.get("channels", {})
    if not isinstance(chans, dict):
        raise FsidError(f"channel map {origin}: [channels] must be a table; see pipeline/maps/__init__.py")
    rules: dict[str, ChannelRule] = {}
    for name, spec in chans.items():
        rules[name] = _rule(name, spec, origin)
    return ChannelMap(
        str(head.get("name", Path(origin).stem)), rules, list(head.get("formats", [])), dict(head), origin
    )


def load_map(spec: str | Path | ChannelMap | None, fmt: str | None = None) -> ChannelMap:
    """Load a map: a built-in name, a TOML path, a ChannelMap, or None (built-in for ``fmt``).

    A user map with ``extends = "<builtin>"`` (or, for a known format, no ``extends`` and
    ``[map] override = true``) is merged over the built-in map.
    """
    if isinstance(spec, ChannelMap):
        return spec
    if spec is None:
        if fmt is None or fmt not in BUILTIN:
            raise FsidError(f"no built-in channel map for format '{fmt}'; pass --map FILE.toml")
        return load_map(BUILTIN[fmt])
    s = str(spec)
    if s in builtin_names():
        text = resources.files(__name__).joinpath(f"{s}.toml").read_text(encoding="utf-8")
        doc = tomllib.loads(text)
        own = _parse(doc, f"built-in map {s}")
        base = doc.get("map", {}).get("extends")
        if base:
            merged = load_map(base, fmt).merged(own)
            merged.name = own.name
            return merged
        return own
    path = Path(s)
    if not path.is_file():
        raise FsidError(f"channel map '{s}' not found: give a TOML file or one of {', '.join(builtin_names())}")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise FsidError(f"channel map {path}: not valid TOML ({exc}); fix the file") from None
    user = _parse(doc, str(path))
    base = doc.get("map", {}).get("extends")
    if base is None and doc.get("map", {}).get("override") and fmt in BUILTIN:
        base = BUILTIN[fmt]
    if base:
        return load_map(base, fmt).merged(user)
    return user


# ------------------------------------------------------------------ applying a map
def _split(source: str) -> tuple[str, str]:
    if "." not in source:
        return source, ""
    msg, fld = source.split(".", 1)
    return msg, fld


def _find_table(raw: RawLog, msg: str) -> Table | None:
    if msg in raw.tables:
        return raw.tables[msg]
    if msg.startswith("@"):  # by schema name (MCAP)
        schema = msg[1:]
        for tab in raw.tables.values():
            if tab.units.get("__schema__") == schema:
                return tab
        return None
    if msg.endswith("[0]"):  # instance 0 of a log that does not split instances
        return raw.tables.get(msg[:-3])
    if msg.endswith("]"):
        return None
    inst0 = f"{msg}[0]"
    return raw.tables.get(inst0)


def _lookup(raw: RawLog, source: str) -> tuple[Table, np.ndarray] | str:
    msg, fld = _split(source)
    tab = _find_table(raw, msg)
    if tab is None:
        return f"no {msg} messages"
    if len(tab) == 0:
        return f"{msg} has no samples"
    if fld not in tab:
        return f"{msg} has no field {fld}"
    return tab, np.asarray(tab[fld], dtype=np.float64)


def _param(params: dict, value, default: float) -> float:
    if isinstance(value, str):
        return float(params.get(value, default))
    if value is None:
        return default
    return float(value)


def _function_output(params: Mapping[str, float], fn: float) -> int | None:
    """The first servo output n with ``SERVOn_FUNCTION`` = fn, or None."""
    for k in range(1, 33):
        if params.get(f"SERVO{k}_FUNCTION") == float(fn):
            return k
    return None


def _servo_number(rule: ChannelRule, params: dict) -> int | None:
    """The servo output of a PWM rule: the one whose SERVOn_FUNCTION is the rule's
    ``function``; the rule's default ``channel`` only when the log has no SERVOn_FUNCTION
    parameters at all (with them, a missing function means no such output: on a tilt-rotor
    output 4 is a motor tilt, on a flying wing output 2 an elevon)."""
    cfg = dict(rule.pwm or {})
    fn = cfg.get("function")
    if fn is not None:
        n = _function_output(params, fn)
        if n is not None or any(k.startswith("SERVO") and k.endswith("_FUNCTION") for k in params):
            return n
    n = cfg.get("channel")
    return int(n) if n is not None else None


def _no_output(rule: ChannelRule) -> str:
    """Why a PWM rule has no servo output: the functions the log's SERVOn_FUNCTION lacks."""
    cfg = dict(rule.pwm or {})
    if cfg.get("function") is None:
        return f"no servo output configured for {rule.name}"
    wanted = [f"{cfg['function']:g}"] + ["/".join(f"{f:g}" for f in m.get("functions", ())) for m in cfg.get("mix", ())]
    return f"no servo output configured for {rule.name} (no SERVOn_FUNCTION = {' or '.join(wanted)})"


def _mixed_outputs(rule: ChannelRule, params: Mapping[str, float]) -> tuple[list[int], list[float], list[float]] | None:
    """(outputs, functions, weights) of the first of the rule's ``pwm.mix`` entries whose
    every function is assigned to an output (SERVOn_FUNCTION), or None."""
    for mix in dict(rule.pwm or {}).get("mix", ()):
        fns, ws = list(mix.get("functions", ())), list(mix.get("weights", ()))
        ns = [_function_output(params, f) for f in fns]
        if fns and len(ws) == len(fns) and all(n is not None for n in ns):
            return ns, fns, ws
    return None


#: deflection (deg) at full servo travel assumed when neither the caller, the map nor the log
#: gives it
DEFAULT_TRAVEL_DEG = 30.0


def servo_travel(
    rule: ChannelRule, params: Mapping[str, float], given: tuple[float, str] | None = None
) -> tuple[float, str]:
    """(deg, where it came from) of a PWM surface channel's deflection at full servo travel:
    ``given`` (deg, origin), else the map's ``travel_deg`` (a number; or a log parameter's
    name, used when the log has it), else DEFAULT_TRAVEL_DEG with origin "assumed"."""
    if given is not None:
        return float(given[0]), given[1]
    v = dict(rule.pwm or {}).get("travel_deg")
    if isinstance(v, str):
        if v in params:
            return float(params[v]), f"log parameter {v}"
    elif v is not None:
        return float(v), "channel map"
    return DEFAULT_TRAVEL_DEG, "assumed"


def _pwm(
    rule: ChannelRule, pwm: np.ndarray, params: dict, n: int | None, travel_deg: float = DEFAULT_TRAVEL_DEG
) -> tuple[np.ndarray, str]:
    """Servo output n's pulses (us) -> deflection (rad) or throttle (0..1), and the note of
    its calibration."""
    cfg = dict(rule.pwm or {})
    if cfg.get("normalised"):  # a -1..1 surface command (PX4 actuator controls)
        return pwm * np.radians(travel_deg), ""
    note = ""
    if n is not None:
        pre = f"SERVO{n}_"
        lo = _param(params, cfg.get("min", pre + "MIN"), 1100.0)
        hi = _param(params, cfg.get("max", pre + "MAX"), 1900.0)
        tr = _param(params, cfg.get("trim", pre + "TRIM"), 1500.0)
        rev = _param(params, cfg.get("reversed", pre + "REVERSED"), 0.0)
        note = f" (SERVO{n}: min {lo:g} trim {tr:g} max {hi:g}{' reversed' if rev else ''})"
    else:
        lo, hi, tr, rev = (
            float(cfg.get("min", 1100)),
            float(cfg.get("max", 1900)),
            float(cfg.get("trim", 1500)),
            float(cfg.get("reversed", 0)),
        )
    if cfg.get("throttle"):
        x = (pwm - lo) / max(hi - lo, 1e-9)
        return np.clip(x, 0.0, 1.0), note
    up = max(hi - tr, 1e-9)
    dn = max(tr - lo, 1e-9)
    x = np.where(pwm >= tr, (pwm - tr) / up, (pwm - tr) / dn)
    if rev:
        x = -x
    return x * np.radians(travel_deg), note


def _quat_euler(w, x, y, z, comp: str) -> np.ndarray:
    if comp == "phi":
        return np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    if comp == "theta":
        return np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    if comp == "psi":
        return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    raise FsidError(f"quaternion component '{comp}' unknown; use phi, theta or psi")


def apply_rule(raw: RawLog, rule: ChannelRule, travel_deg: float = DEFAULT_TRAVEL_DEG) -> Channel | str:
    """Fill one channel from the raw tables, or return why it cannot be filled.
    ``travel_deg``: a PWM surface's deflection at full servo travel (:func:`servo_travel`)."""
    if rule.scale_param:
        if rule.scale_param not in raw.params:
            return f"no parameter {rule.scale_param} in the log"
        got = _apply_rule(raw, rule, travel_deg)
        if isinstance(got, str):
            return got
        k = float(raw.params[rule.scale_param])
        return Channel(got.t, got.values * k, got.unit, f"{got.source} x {rule.scale_param} ({k:g})")
    return _apply_rule(raw, rule, travel_deg)


def _onto(t: np.ndarray, got: tuple[Table, np.ndarray], source: str) -> np.ndarray | str:
    """The values of a looked-up source ``got`` (its table, values) interpolated onto the
    times ``t`` (non-finite samples left out), or why not."""
    tb, vb = got
    tb_t = np.asarray(tb.t, dtype=float)
    ok = np.isfinite(tb_t) & np.isfinite(vb)
    if not ok.any():
        return f"{source} has no finite samples"
    order = np.argsort(tb_t[ok], kind="stable")
    return np.interp(t, tb_t[ok][order], np.asarray(vb, dtype=float)[ok][order])


def _apply_rule(raw: RawLog, rule: ChannelRule, travel_deg: float = DEFAULT_TRAVEL_DEG) -> Channel | str:
    if rule.transform in ("quat_wxyz", "quat_xyzw"):
        if len(rule.sources) != 4:
            return "quaternion transform needs 4 sources"
        got = [_lookup(raw, s) for s in rule.sources]
        for g in got:
            if isinstance(g, str):
                return g
        tabs = [g[0] for g in got]
        n = min(len(g[1]) for g in got)
        comps = [g[1][:n] for g in got]
        if rule.transform == "quat_xyzw":
            comps = [comps[3], comps[0], comps[1], comps[2]]
        vals = (_quat_euler(*comps, rule.component or "phi") + rule.offset) * rule.sign
        if rule.component in ("phi", "psi"):
            vals = (vals + np.pi) % (2 * np.pi) - np.pi
        return Channel(
            np.asarray(tabs[0].t[:n], float),
            vals,
            CANONICAL_UNITS.get(rule.name, "rad"),
            f"{rule.transform}({', '.join(rule.sources)}).{rule.component}",
        )
    if rule.transform == "product":  # sources[0] x sources[1] (interpolated onto sources[0])
        a = _lookup(raw, rule.sources[0])
        if isinstance(a, str):
            return a
        if len(rule.sources) < 2:
            return "product transform needs 2 sources"
        b = _lookup(raw, rule.sources[1])
        tab, va = a
        if rule.unless_param and float(raw.params.get(rule.unless_param, 0.0)) != 0.0:
            b = f"log parameter {rule.unless_param} says {rule.sources[0]} needs no factor"
        if isinstance(b, str):  # keep the first factor alone and say so
            vals = rule.scaled(va)
            return Channel(
                np.asarray(tab.t, float),
                vals,
                CANONICAL_UNITS.get(rule.name, rule.unit),
                f"{rule.sources[0]} (without {rule.sources[1]}: {b})",
            )
        f = _onto(tab.t, b, rule.sources[1])
        if isinstance(f, str):
            return f
        vals = rule.scaled(va * f)
        return Channel(
            np.asarray(tab.t, float),
            vals,
            CANONICAL_UNITS.get(rule.name, rule.unit),
            f"{rule.sources[0]} x {rule.sources[1]}",
        )
    if rule.transform == "polar":  # speed sources[0] along the course sources[1] [deg]
        if len(rule.sources) != 2 or rule.component not in ("north", "east"):
            return "polar transform needs 2 sources (speed, course in deg) and component north or east"
        a = _lookup(raw, rule.sources[0])
        if isinstance(a, str):
            return a
        tab, va = a
        b = _lookup(raw, rule.sources[1])
        if isinstance(b, str):
            return b
        # the course's cosine and sine interpolated (a course through 360 deg stays whole)
        c, sn = (_onto(tab.t, (b[0], fn(np.radians(b[1]))), rule.sources[1]) for fn in (np.cos, np.sin))
        if isinstance(c, str):
            return c
        trig = (c if rule.component == "north" else sn) / np.maximum(np.hypot(c, sn), 1e-9)
        vals = rule.scaled(va * trig)
        return Channel(
            np.asarray(tab.t, float),
            vals,
            CANONICAL_UNITS.get(rule.name, rule.unit),
            f"polar({rule.sources[0]}, {rule.sources[1]}).{rule.component}",
        )
    reasons = []
    for src in rule.sources_for(raw.params):
        # the servo output whose calibration applies (function or channel of the pwm block)
        n = _servo_number(rule, raw.params) if rule.pwm is not None else None
        if "{k}" in src:  # PX4 control surfaces k, weighted by their torque coefficients
            got = _torque_surface(raw, rule, src, travel_deg)
            if isinstance(got, Channel):
                return got
            reasons.append(got)
            continue
        if "{n}" in src:  # the source is that output's field
            if n is None:
                mixed = _mixed_outputs(rule, raw.params)
                if mixed is not None:
                    got = _mixed_surface(raw, rule, src, *mixed, travel_deg)
                    if isinstance(got, Channel):
                        return got
                    reasons.append(got)
                    continue
                reasons.append(_no_output(rule))
                continue
            src = src.replace("{n}", str(n))
        unit = rule.unit
        if " " in src.strip():  # "MSG.field unit": a unit for this source only
            src, unit = src.split()[0], src.split()[1]
        got = _lookup(raw, src)
        if isinstance(got, str):
            reasons.append(got)
            continue
        tab, raw_v = got
        note = f" [{unit}]" if unit != rule.unit else ""
        if rule.pwm is not None:
            vals, note = _pwm(rule, raw_v * rule.scale + rule.offset, raw.params, n, travel_deg)
            vals = vals * rule.sign
        else:
            vals = rule.scaled(raw_v, unit)
        notes = ""
        msg, fld = _split(src)
        logged = tab.units.get(fld)
        if (
            logged
            and unit in UNIT_FACTORS
            and logged in UNIT_FACTORS
            and UNIT_FACTORS[logged] != UNIT_FACTORS[unit]
            and rule.pwm is None
        ):
            notes = f"the log's unit metadata (FMTU) gives {src} in {logged} but the map reads it as {unit}; check the channel map"
        return Channel(
            np.asarray(tab.t, dtype=np.float64), vals, CANONICAL_UNITS.get(rule.name, rule.unit), src + note, notes
        )
    return "; ".join(dict.fromkeys(reasons))


#: PX4 control-allocation torque axes of a surface channel (``pwm.torque``)
TORQUE_AXES = ("R", "P", "Y")


def _torque_surface(raw: RawLog, rule: ChannelRule, src: str, travel_deg: float) -> Channel | str:
    """A surface channel from PX4's allocated servo commands (``actuator_servos.control[k]``,
    -1..1, source written with ``{k}``): the control surfaces k = 0..CA_SV_CS_COUNT-1
    weighted by their torque coefficients on the rule's axis (``pwm.torque``:
    CA_SV_CS{k}_TRQ_R / _P / _Y) over the sum of the coefficients' magnitudes - one
    elevator gives its own command, two elevons their mean, two ailerons half their
    difference, as the torque the allocation meant - times the travel, then the sign."""
    axis = str(dict(rule.pwm or {}).get("torque", "")).upper()
    if axis not in TORQUE_AXES:
        return f"pwm.torque must be one of {', '.join(TORQUE_AXES)}, not {axis!r}"
    params = raw.params
    if "CA_SV_CS_COUNT" not in params:
        return "no CA_SV_CS_COUNT parameter (no PX4 control allocation)"
    ks = range(int(params["CA_SV_CS_COUNT"]))
    trq = np.array([float(params.get(f"CA_SV_CS{k}_TRQ_{axis}", 0.0)) for k in ks])
    if not np.any(trq != 0.0):
        return f"no control surface with a torque on {axis} (CA_SV_CS*_TRQ_{axis} all 0)"
    w = trq / np.sum(np.abs(trq))
    used = [(k, wk) for k, wk in zip(ks, w) if wk != 0.0]
    got = _weighted_sum(
        raw, [(src.replace("{k}", str(k)), wk, k) for k, wk in used], lambda k, v: (v * rule.scale + rule.offset, "")
    )
    if isinstance(got, str):
        return got
    t0, total, _ = got
    name = src.split(".")[0]
    return Channel(
        t0,
        total * np.radians(travel_deg) * rule.sign,
        CANONICAL_UNITS.get(rule.name, "rad"),
        f"{name} by CA_SV_CS*_TRQ_{axis}: " + " ".join(f"{wk:+.3g} x control[{k}]" for k, wk in used),
    )


def _mixed_surface(
    raw: RawLog,
    rule: ChannelRule,
    src: str,
    outputs: Sequence[int],
    functions: Sequence[float],
    weights: Sequence[float],
    travel_deg: float,
) -> Channel | str:
    """A surface channel from mixed servos (``pwm.mix``): sum of weight x deflection of each
    output, each calibrated with its own SERVOn_MIN/MAX/TRIM/REVERSED and the channel's
    travel, on the first output's time base; then the rule's sign."""
    srcs = [src.split()[0].replace("{n}", str(n)) for n in outputs]
    got = _weighted_sum(
        raw,
        list(zip(srcs, weights, outputs)),
        lambda n, v: _pwm(rule, v * rule.scale + rule.offset, raw.params, n, travel_deg),
    )
    if isinstance(got, str):
        return got
    t0, total, notes = got
    fns = "/".join(f"{f:g}" for f in functions)
    return Channel(
        t0,
        total * rule.sign,
        CANONICAL_UNITS.get(rule.name, "rad"),
        f"mix of SERVOn_FUNCTION {fns}: "
        + " ".join(f"{w:+g} x {s_}{note}" for s_, w, note in zip(srcs, weights, notes)),
    )


def _weighted_sum(
    raw: RawLog, terms: Sequence[tuple[str, float, object]], convert
) -> tuple[np.ndarray, np.ndarray, list[str]] | str:
    """(t, sum of weight x values, notes) over ``terms`` (source, weight, key), each
    source's values passed through ``convert(key, values) -> (values, note)``, on the first
    source's time base (the others interpolated onto it); or why a source is missing."""
    total, notes, t0 = None, [], None
    for source, w, key in terms:
        got = _lookup(raw, source)
        if isinstance(got, str):
            return got
        tab, raw_v = got
        vals, note = convert(key, raw_v)
        t = np.asarray(tab.t, dtype=np.float64)
        if t0 is None:
            t0, total = t, np.zeros(len(t))
        elif t.shape != t0.shape or not np.array_equal(t, t0):
            vals = np.interp(t0, t, vals)
        total = total + w * vals
        notes.append(note)
    return t0, total, notes


def plain_map_toml(fd, name: str, formats: Sequence[str], drop: Sequence[str] = ()) -> str:
    """The TOML of a map that reads ``fd``'s channels straight from the sources they came
    from (one plain source each, in the channel's SI unit), without those in ``drop``: for
    channels a reader fills by name (the product's own MCAP), e.g. the same log without its
    vanes. Transforms, PWM and scale rules are not reproduced: use it on plain sources."""
    lines = ["[map]", f'name = "{name}"', f"formats = {list(formats)!r}".replace("'", '"'), ""]
    for k in fd.names:
        if k not in drop:
            lines += [f"[channels.{k}]", f'source = ["{fd[k].source}"]', f'unit = "{fd[k].unit}"', ""]
    return "\n".join(lines)


def apply_map(
    raw: RawLog, cmap: ChannelMap, servo_travel_deg: Mapping[str, tuple[float, str]] | None = None
) -> tuple[dict[str, Channel], dict[str, str], dict[str, dict]]:
    """All channels of ``cmap`` that the log can fill, for the others the reason, and for
    the surfaces decoded from servo PWM their deflection at full travel ({"deg", "from"}).
    ``servo_travel_deg``: channel -> (deg, origin) given by the caller (:func:`servo_travel`);
    an assumed travel is also in the channel's notes (a data-quality warning)."""
    chans: dict[str, Channel] = {}
    why: dict[str, str] = {}
    travels: dict[str, dict] = {}
    rules = dict(cmap.rules)
    if cmap.header.get("canonical"):  # every canonical column of every table, SI units
        for tname, tab in raw.tables.items():
            for f in tab.fields:
                if f in CANONICAL_UNITS and f != "t" and f not in rules:
                    rules[f] = ChannelRule(f, [f"{tname}.{f}"], CANONICAL_UNITS[f])
    for name, rule in rules.items():
        surface = rule.pwm is not None and not dict(rule.pwm).get("throttle")
        deg, origin = (
            servo_travel(rule, raw.params, (servo_travel_deg or {}).get(name)) if surface else (DEFAULT_TRAVEL_DEG, "")
        )
        got, used = apply_rule(raw, rule, deg), rule
        if isinstance(got, str) and rule.fallback is not None:
            first, alt = got, apply_rule(raw, rule.fallback, deg)
            if isinstance(alt, str):
                got = f"{first}; fallback {', '.join(rule.fallback.sources)}: {alt}"
            else:
                got, used = alt, rule.fallback
                got.notes = "; ".join(
                    filter(
                        None,
                        [
                            got.notes,
                            (
                                f"from the fallback {got.source} ({', '.join(rule.sources)}: {first})"
                                + (f": {used.derived}" if used.derived else "")
                            ),
                        ],
                    )
                )
        if isinstance(got, str):
            why[name] = got
            continue
        got.derived = used.derived or ""
        if surface:
            travels[name] = {"deg": deg, "from": origin}
            if origin == "assumed":
                got.notes = "; ".join(
                    filter(
                        None,
                        [
                            got.notes,
                            (
                                f"deflection from the servo command with {deg:g} deg at full servo travel assumed "
                                f"(the control derivatives scale with it): give the aircraft TOML's "
                                f"[servos] {name}_travel_deg"
                            ),
                        ],
                    )
                )
        chans[name] = got
    return chans, why, travels
