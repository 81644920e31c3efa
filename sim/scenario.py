"""Scenario files: trim condition, maneuvers, turbulence, sensors, duration, rates.

Every number carries its unit in its key (``airspeed_mps``, ``amplitude_deg``,
``pulse_s``...). A key whose name matches a known key except for the unit suffix is
reported as a wrong unit. Loading validates everything and raises
:class:`sim.ScenarioError` with one line naming the file, the key and the reason.
Trimmability is checked when the scenario is flown (``sim.fly``), also as ScenarioError.

Layout::

    name, description, aircraft (path relative to the scenario file), duration_s,
    rate_hz (truth and input sample rate, default 100), substeps (JSBSim steps per sample,
    default 2: inputs move linearly between samples), seed
    [trim]        altitude_m, airspeed_mps, flight_path_deg = 0, heading_deg = 0
    [schedule]    lead_s = 5, quiet_s = 10   (maneuvers without start_s are laid end to end)
    [[maneuver]]  name, axis (de|da|dr|throttle, or a list for multisine), shape
                  (doublet|3211|multistep|sweep|multisine), amplitude_deg (or amplitude
                  for throttle, fraction; a multisine takes one value or a list, one
                  per axis), start_s, pulse_s, levels, f0_hz, f1_hz,
                  length_s, sweep (linear|log), period_s, cycles
    [turbulence]  model (off|milspec|tustin), severity (light|moderate|severe),
                  windspeed_20ft_mps (optional override), seed (default: scenario seed),
                  axes (wind|aircraft, default wind: see Turbulence)
    [wind]        north_mps = 0, east_mps = 0   (steady mean wind, the velocity the air mass
                  moves with, NED; the trim airspeed is air-relative)
    [actuators]   lag_s = 0, pwm_servos = true (the autopilot commands whole microseconds
                  of servo PWM, as in an ArduPilot log's RCOU: every surface command is a
                  multiple of the aircraft's [servos] travel / 400 us, the throttle a
                  multiple of 1/1000; false = continuous commands)
    [sas]         k_alpha = 0, k_q_s = 0   (pitch SAS: de += k_alpha*(alpha-alpha_trim) + k_q_s*q)
    [sensors.<imu|airdata|attitude|baro|surfaces|gps>]  see sim.sensors.SENSOR_SCHEMA
    [validation]  rate_deg_s, accel_g, angle_deg   (proof-of-match bands)
    [validation_flight]  a second flight for the proof of match (:attr:`Scenario.validation`):
                  duration_s, turbulence ("off": calm air, the default, as proof-of-match
                  flights are flown; "same": this scenario's turbulence), seed (default:
                  the scenario's + 1), and its own [[validation_flight.maneuver]] tables;
                  trim, schedule, aircraft, sensors, actuators as above
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from sim.aircraft import Aircraft, load_aircraft
from sim.errors import ScenarioError
from sim.maneuvers import AXES, SHAPES, Maneuver, schroeder_multisine
from sim.sensors import SENSOR_SCHEMA, SensorSpec, sensor_spec

#: MIL-F-8785C: wind at 20 ft (m/s) and JSBSim probability-of-exceedance index per severity
SEVERITY = {"light": (15 * 0.514444, 3), "moderate": (30 * 0.514444, 4), "severe": (45 * 0.514444, 6)}
#: throttle PWM span (MIN 1000 - MAX 2000 us): the throttle command's resolution is 1/1000
THROTTLE_SPAN_US = 1000
#: the longest flight a scenario may ask for [s]: a day, far beyond any test flight, and a
#: bound on the memory a mistyped duration can ask for (the truth table is held whole)
MAX_DURATION_S = 86400.0


@dataclass(frozen=True)
class Turbulence:
    """Dryden turbulence settings. model: 'off', 'milspec' (JSBSim turb-type 3) or
    'tustin' (turb-type 4); wind at 20 ft in m/s; JSBSim probability-of-exceedance index.

    axes: how the gusts are oriented. 'wind' (default) is JSBSim's own: the gust components
    u, v and the rotary p, q (xi_u, xi_v, xi_p, xi_q of FGWinds) turned about the vertical
    by minus the mean-wind azimuth psiw (north-aligned when calm) into north-east-down,
    then into the body. The rotary gusts are built from the gusts' time histories along
    the flight path (q_g from w_g, r_g from v_g, p_g the spanwise one), so an aircraft not
    heading north feels its pitch gust as roll turbulence and a lateral gust that r_g does
    not follow. 'aircraft' keeps them in the aircraft's axes, as MIL-F-8785C defines them
    above 2000 ft: u along the heading, v_g and r_g, p_g and q_g paired whatever the
    heading. JSBSim has no switch for it and takes psiw from the mean wind, so the sim
    holds a mean wind of 1e-9 ft/s towards minus the heading.
    """

    model: str = "off"
    severity: str = "light"
    windspeed_20ft: float = 0.0
    poe_index: int = 0
    seed: int = 0
    axes: str = "wind"


@dataclass(frozen=True)
class Scenario:
    """A validated scenario. SI units (m, s, rad, m/s)."""

    name: str
    path: Path | None
    description: str
    aircraft: Aircraft
    duration: float  #: s
    rate_hz: float  #: truth sample rate, Hz (JSBSim integrates at rate_hz * substeps)
    seed: int
    altitude: float  #: trim altitude above sea level, m
    airspeed: float  #: trim true airspeed, m/s
    flight_path: float  #: trim flight-path angle, rad
    heading: float  #: rad
    maneuvers: tuple[Maneuver, ...]
    turbulence: Turbulence
    actuator_lag: float  #: s
    sas_k_alpha: float  #: rad/rad
    sas_k_q: float  #: rad/(rad/s)
    sensors: dict[str, SensorSpec] = field(default_factory=dict)
    substeps: int = 2  #: JSBSim integration steps per truth sample
    #: proof-of-match bands of the [validation] table: rate_deg_s (deg/s), accel_g (g),
    #: angle_deg (deg); defaults 1.5, 0.1, 1.5 (DESIGN.md section 8)
    pom_bands: dict = field(default_factory=lambda: {"rate_deg_s": 1.5, "accel_g": 0.1, "angle_deg": 1.5})
    #: steady mean wind (north, east) [m/s], the air mass's velocity over the ground
    wind: tuple[float, float] = (0.0, 0.0)
    #: whole-microsecond servo PWM commands (surfaces: the aircraft's Aircraft.travel /
    #: SERVO_SPAN_US; throttle: 1/THROTTLE_SPAN_US); False = continuous commands
    pwm_servos: bool = True
    raw: dict = field(default_factory=dict, repr=False)
    #: the [validation_flight]: a second flight (same aircraft, trim and sensors, its own
    #: maneuvers) whose maneuvers the proof of match is run on; the model is then fitted
    #: to every maneuver of this flight. None without the table.
    validation: Scenario | None = None

    def with_seed(self, seed: int) -> Scenario:
        """The same scenario with another seed (turbulence seed follows unless set apart;
        the validation flight keeps its offset from the scenario's seed)."""
        turb = self.turbulence
        if self.raw.get("turbulence", {}).get("seed") is None:
            turb = replace(turb, seed=int(seed))
        val = self.validation
        if val is not None:
            val = val.with_seed(val.seed - self.seed + int(seed))
        return replace(self, seed=int(seed), turbulence=turb, validation=val)


def _base(key: str) -> str:
    return key.rsplit("_", 1)[0] if "_" in key else key


class _Section:
    """Reads one TOML table, tracking which keys were used, and fails in one line."""

    def __init__(self, path: Path, where: str, table: Any, allowed: set[str]) -> None:
        self.path, self.where = path, where
        if not isinstance(table, dict):
            raise self.fail("", f"must be a table, got {type(table).__name__}")
        self.t = table
        for k in table:
            if k not in allowed:
                same = [a for a in allowed if _base(a) == _base(k) and "_" in k and "_" in a]
                if same:
                    raise self.fail(k, f"wrong unit; write it as {self._key(same[0])}")
                raise self.fail(k, f"unknown key; allowed: {', '.join(sorted(allowed))}")

    def _key(self, k: str) -> str:
        return f"{self.where}.{k}" if self.where and k else (self.where or k)

    def fail(self, key: str, why: str) -> ScenarioError:
        return ScenarioError(f"{self.path}: {self._key(key)}: {why}")

    def num(
        self,
        key: str,
        default: float | None = None,
        *,
        lo: float | None = None,
        hi: float | None = None,
        positive: bool = False,
    ) -> float:
        if key not in self.t:
            if default is None:
                raise self.fail(key, "missing field")
            return float(default)
        v = self.t[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            raise self.fail(key, f"must be a finite number, got {v!r}")
        if positive and not v > 0:
            raise self.fail(key, f"must be > 0, got {v}")
        if lo is not None and v < lo:
            raise self.fail(key, f"must be >= {lo}, got {v}")
        if hi is not None and v > hi:
            raise self.fail(key, f"must be <= {hi}, got {v}")
        return float(v)

    def pick(self, key: str, k: int, n: int, **limits) -> float:
        """Element k of a per-axis list of n numbers, or the one number given for all axes."""
        v = self.t.get(key)
        if not isinstance(v, list):
            return self.num(key, **limits)
        if len(v) != n:
            raise self.fail(key, f"a list needs one value per axis ({n}), got {len(v)}")
        return _Section(self.path, f"{self._key(key)}[{k}]", {"": v[k]}, {""}).num("", **limits)

    def text(self, key: str, default: str | None = None, choices: tuple[str, ...] | None = None) -> str:
        if key not in self.t:
            if default is None:
                raise self.fail(key, "missing field")
            return default
        v = self.t[key]
        if not isinstance(v, str):
            raise self.fail(key, f"must be a string, got {v!r}")
        if choices and v not in choices:
            raise self.fail(key, f"must be one of {', '.join(choices)}, got {v!r}")
        return v

    def integer(self, key: str, default: int | None = None) -> int:
        if key not in self.t:
            if default is None:
                raise self.fail(key, "missing field")
            return default
        v = self.t[key]
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise self.fail(key, f"must be a non-negative integer, got {v!r}")
        return int(v)


_TOP = {
    "name",
    "description",
    "aircraft",
    "duration_s",
    "rate_hz",
    "substeps",
    "seed",
    "trim",
    "schedule",
    "maneuver",
    "turbulence",
    "wind",
    "actuators",
    "sas",
    "sensors",
    "validation",
    "validation_flight",
}
_MAN = {
    "name",
    "axis",
    "shape",
    "amplitude_deg",
    "amplitude",
    "start_s",
    "pulse_s",
    "levels",
    "f0_hz",
    "f1_hz",
    "length_s",
    "sweep",
    "period_s",
    "cycles",
}


def _maneuver(path: Path, i: int, tab: Any, t_next: float) -> Maneuver:
    s = _Section(path, f"maneuver[{i}]", tab, _MAN)
    shape = s.text("shape", choices=SHAPES)
    name = s.text("name", f"{shape}_{i + 1}")
    axis_raw = s.t.get("axis")
    if axis_raw is None:
        raise s.fail("axis", "missing field")
    axes = tuple(axis_raw) if isinstance(axis_raw, list) else (axis_raw,)
    for a in axes:
        if a not in AXES:
            raise s.fail("axis", f"must be one of {', '.join(AXES)}, got {a!r}")
    if len(axes) != len(set(axes)) or (len(axes) > 1 and shape != "multisine"):
        raise s.fail("axis", "a list of distinct axes is allowed only for shape = 'multisine'")
    amps = []
    for k, a in enumerate(axes):
        if a == "throttle":
            if "amplitude_deg" in s.t and len(axes) == 1:
                raise s.fail("amplitude_deg", "wrong unit; the throttle amplitude is a fraction: write amplitude")
            amps.append(s.pick("amplitude", k, len(axes), lo=-1.0, hi=1.0))
        else:
            if "amplitude" in s.t and "amplitude_deg" not in s.t:
                raise s.fail("amplitude", "wrong unit; surface amplitudes are in degrees: write amplitude_deg")
            a = s.pick("amplitude_deg", k, len(axes), lo=-90.0, hi=90.0)
            if a == 0:
                raise s.fail("amplitude_deg", "must not be zero")
            amps.append(float(np.deg2rad(a)))
    start = s.num("start_s", t_next, lo=0.0)
    kw: dict[str, Any] = {}
    if shape in ("doublet", "3211", "multistep"):
        kw["pulse"] = s.num("pulse_s", positive=True)
        if shape == "multistep":
            lv = s.t.get("levels")
            if (
                not isinstance(lv, list)
                or not lv
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in lv)
            ):
                raise s.fail(
                    "levels", "missing field or not a list of numbers (step heights in units of the amplitude)"
                )
            kw["levels"] = tuple(float(x) for x in lv)
    elif shape == "sweep":
        kw["f0"] = s.num("f0_hz", positive=True)
        kw["f1"] = s.num("f1_hz", positive=True)
        kw["length"] = s.num("length_s", positive=True)
        kw["sweep"] = s.text("sweep", "linear", ("linear", "log"))
    else:
        kw["f0"] = s.num("f0_hz", positive=True)
        kw["f1"] = s.num("f1_hz", positive=True)
        kw["length"] = s.num("period_s", positive=True)
        kw["cycles"] = s.integer("cycles", 1) or 1
        try:
            kw["harmonics"], kw["phases"], kw["scale"] = schroeder_multisine(axes, kw["f0"], kw["f1"], kw["length"])
        except ValueError as exc:
            raise s.fail("f0_hz", str(exc)) from None
    for key in ("pulse_s", "levels", "f0_hz", "f1_hz", "length_s", "sweep", "period_s", "cycles"):
        used = {
            "doublet": {"pulse_s"},
            "3211": {"pulse_s"},
            "multistep": {"pulse_s", "levels"},
            "sweep": {"f0_hz", "f1_hz", "length_s", "sweep"},
            "multisine": {"f0_hz", "f1_hz", "period_s", "cycles"},
        }[shape]
        if key in s.t and key not in used:
            raise s.fail(key, f"not used by shape {shape!r}; allowed there: {', '.join(sorted(used))}")
    if kw.get("f1", 1.0) <= kw.get("f0", 0.0) and shape == "multisine":
        raise s.fail("f1_hz", "must be above f0_hz")
    return Maneuver(name=name, shape=shape, axes=axes, amplitude=tuple(amps), t_start=start, **kw)


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML file (and the aircraft truth set it names).

    Raises :class:`sim.ScenarioError` with one line for: an unreadable file, an unknown
    key, a missing field, a key with the wrong unit suffix, a value out of range,
    overlapping or too-late maneuvers. (An untrimmable condition is reported by
    :func:`sim.fly`.)
    """
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ScenarioError(
            f"{path}: scenario file not found; give a path to a .toml scenario (built-ins live in scenarios/)"
        ) from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{path}: not valid TOML ({exc})") from None
    return scenario_from_dict(raw, path)


def _maneuvers(top: _Section, path: Path, raw: dict, duration: float) -> list[Maneuver]:
    """The [schedule] and [[maneuver]] tables: maneuvers without a start laid end to end
    after lead_s with quiet_s between them; names unique, each inside the flight, none
    overlapping another on the same axis."""
    sch = _Section(path, "schedule", raw.get("schedule", {}), {"lead_s", "quiet_s"})
    lead, quiet = sch.num("lead_s", 5.0, lo=0.0), sch.num("quiet_s", 10.0, lo=0.0)
    mans_raw = raw.get("maneuver", [])
    if not isinstance(mans_raw, list):
        raise top.fail("maneuver", "must be an array of tables: write [[maneuver]]")
    mans: list[Maneuver] = []
    t_next = lead
    for i, m in enumerate(mans_raw):
        man = _maneuver(path, i, m, t_next)
        mans.append(man)
        t_next = man.t_end + quiet
    names = [m.name for m in mans]
    if len(set(names)) != len(names):
        raise top.fail("maneuver", f"maneuver names must be unique, got {names}")
    for i, m in enumerate(mans):
        if m.t_end > duration + 1e-9:
            raise top.fail(
                f"maneuver[{i}]",
                f"{m.name!r} ends at {m.t_end:.2f} s, after duration_s = {duration}; lengthen duration_s or shorten the schedule",
            )
        for o in mans[:i]:
            if set(m.axes) & set(o.axes) and m.t_start < o.t_end - 1e-9 and o.t_start < m.t_end - 1e-9:
                raise top.fail(f"maneuver[{i}]", f"{m.name!r} overlaps {o.name!r} on the same axis")
    return mans


def _turbulence_and_wind(path: Path, raw: dict, seed: int) -> tuple[Turbulence, tuple[float, float]]:
    """The [turbulence] and [wind] tables (a mean wind cannot go with turbulence in the
    aircraft's axes: it sets JSBSim's turbulence axes)."""
    tu = _Section(
        path, "turbulence", raw.get("turbulence", {}), {"model", "severity", "windspeed_20ft_mps", "seed", "axes"}
    )
    model = tu.text("model", "off", ("off", "milspec", "tustin"))
    sev = tu.text("severity", "light", tuple(SEVERITY))
    w20 = tu.num("windspeed_20ft_mps", SEVERITY[sev][0], lo=0.0, hi=60.0)
    turb = Turbulence(
        model=model,
        severity=sev,
        windspeed_20ft=w20 if model != "off" else 0.0,
        poe_index=SEVERITY[sev][1] if model != "off" else 0,
        seed=tu.integer("seed", seed),
        axes=tu.text("axes", "wind", ("wind", "aircraft")),
    )
    wsec = _Section(path, "wind", raw.get("wind", {}), {"north_mps", "east_mps"})
    wind = (wsec.num("north_mps", 0.0, lo=-60.0, hi=60.0), wsec.num("east_mps", 0.0, lo=-60.0, hi=60.0))
    if any(wind) and turb.model != "off" and turb.axes == "aircraft":
        raise wsec.fail(
            "",
            "a mean wind sets JSBSim's turbulence axes; it cannot go with [turbulence] axes = \"aircraft\" (drop one of them)",
        )
    return turb, wind


def scenario_from_dict(raw: dict, path: Path) -> Scenario:
    """Validate a parsed scenario; ``path`` is used for messages and relative aircraft paths."""
    top = _Section(path, "", raw, _TOP)
    ac_rel = top.text("aircraft")
    ac_path = (path.parent / ac_rel) if not Path(ac_rel).is_absolute() else Path(ac_rel)
    if not ac_path.exists():
        raise top.fail("aircraft", f"file {ac_path} not found (paths are relative to the scenario file)")
    aircraft = load_aircraft(ac_path)
    duration = top.num("duration_s", positive=True, hi=MAX_DURATION_S)
    rate = top.num("rate_hz", 100.0, lo=20.0, hi=1000.0)
    substeps = top.integer("substeps", 2)
    if not 1 <= substeps <= 20:
        raise top.fail("substeps", f"must be between 1 and 20, got {substeps}")
    seed = top.integer("seed", 0)
    if "trim" not in raw:
        raise top.fail("trim", "missing section")
    trim = _Section(path, "trim", raw["trim"], {"altitude_m", "airspeed_mps", "flight_path_deg", "heading_deg"})
    alt = trim.num("altitude_m", lo=10.0, hi=20000.0)
    tas = trim.num("airspeed_mps", positive=True, hi=300.0)
    gam = np.deg2rad(trim.num("flight_path_deg", 0.0, lo=-30.0, hi=30.0))
    hdg = np.deg2rad(trim.num("heading_deg", 0.0, lo=-360.0, hi=360.0))
    mans = _maneuvers(top, path, raw, duration)
    turb, wind = _turbulence_and_wind(path, raw, seed)
    act = _Section(path, "actuators", raw.get("actuators", {}), {"lag_s", "pwm_servos"})
    pwm = act.t.get("pwm_servos", True)
    if not isinstance(pwm, bool):
        raise act.fail("pwm_servos", f"must be true or false, got {pwm!r}")
    sas = _Section(path, "sas", raw.get("sas", {}), {"k_alpha", "k_q_s"})
    sens_sec = _Section(path, "sensors", raw.get("sensors", {}), set(SENSOR_SCHEMA))
    sensors = {}
    for name in SENSOR_SCHEMA:
        tab = sens_sec.t.get(name, {})
        sensors[name] = sensor_spec(name, _Section(path, f"sensors.{name}", tab, SENSOR_SCHEMA[name].keys()), rate)
    val = _Section(path, "validation", raw.get("validation", {}), {"rate_deg_s", "accel_g", "angle_deg"})
    bands = {
        "rate_deg_s": val.num("rate_deg_s", 1.5, positive=True, hi=90.0),
        "accel_g": val.num("accel_g", 0.1, positive=True, hi=10.0),
        "angle_deg": val.num("angle_deg", 1.5, positive=True, hi=90.0),
    }
    validation = _validation_flight(path, raw, seed) if "validation_flight" in raw else None
    return Scenario(
        name=top.text("name", path.stem),
        path=path.resolve() if path.exists() else path,
        description=top.text("description", ""),
        aircraft=aircraft,
        duration=duration,
        rate_hz=rate,
        seed=seed,
        altitude=alt,
        airspeed=tas,
        flight_path=float(gam),
        heading=float(hdg),
        maneuvers=tuple(mans),
        turbulence=turb,
        actuator_lag=act.num("lag_s", 0.0, lo=0.0, hi=1.0),
        sas_k_alpha=sas.num("k_alpha", 0.0),
        sas_k_q=sas.num("k_q_s", 0.0),
        sensors=sensors,
        substeps=substeps,
        pom_bands=bands,
        wind=wind,
        pwm_servos=pwm,
        raw=raw,
        validation=validation,
    )


#: turbulence of a validation flight: "off" (calm air) or "same" (the scenario's)
VALIDATION_TURBULENCE = ("off", "same")


def _validation_flight(path: Path, raw: dict, seed: int) -> Scenario:
    """The [validation_flight] table as a scenario of its own: the parent's aircraft, trim,
    schedule, wind, actuators, SAS, sensors and bands; its own duration, maneuvers, seed
    and turbulence. Errors name the table (``validation_flight.maneuver[0]...``)."""
    sec = _Section(
        path, "validation_flight", raw["validation_flight"], {"duration_s", "turbulence", "seed", "maneuver"}
    )
    turb = sec.text("turbulence", "off", VALIDATION_TURBULENCE)
    if not sec.t.get("maneuver"):
        raise sec.fail("maneuver", "a validation flight needs maneuvers: add [[validation_flight.maneuver]] tables")
    sub = {
        k: v
        for k, v in raw.items()
        if k not in ("validation_flight", "maneuver", "turbulence", "duration_s", "seed", "name")
    }
    sub.update(
        name=f"{raw.get('name', path.stem)}-validation",
        duration_s=sec.num("duration_s", positive=True, hi=MAX_DURATION_S),
        seed=sec.integer("seed", seed + 1),
        maneuver=sec.t["maneuver"],
    )
    if turb == "same" and "turbulence" in raw:
        sub["turbulence"] = {k: v for k, v in raw["turbulence"].items() if k != "seed"}
    try:
        return scenario_from_dict(sub, path)
    except ScenarioError as exc:
        msg = str(exc)
        head = f"{path}: "
        raise ScenarioError(head + "validation_flight." + msg[len(head) :] if msg.startswith(head) else msg) from None
