"""The aircraft file: a real aircraft described by what its owner knows (docs/aircraft.md).

Tables (SI units; the unit is in each key's name):

- ``[geometry]`` S_m2, b_m, cbar_m; ``[mass]`` mass_kg, Ixx_kgm2, Iyy_kgm2, Izz_kgm2,
  Ixz_kgm2 (optional, 0);
- ``[propulsion]`` (optional) how throttle (0..1) becomes thrust: ``max_thrust_N`` or
  ``thrust_per_throttle_N`` (thrust = throttle x it), or a measured map ``throttle = [...]``
  with ``thrust_N = [...]`` (interpolated linearly);
- ``[servos]`` (optional) the surface deflection at full servo travel or at a normalised
  command of 1, per surface: ``de_travel_deg`` or ``de_deg_per_unit`` (the same thing), da,
  dr likewise;
- ``[sensors.airdata]`` / ``[sensors.imu]`` (optional) ``position_m = [x, y, z]`` from the CG;
- ``[signs]`` (optional) the control sign conventions of the logged de, da, dr (default
  DESIGN.md's: :data:`CONVENTIONS`);
- ``statically_unstable = true`` (optional, top level): a positive Cmalpha is no fault;
- ``stall_speed_mps`` (optional, top level): below it for most of a span the aircraft is
  on the ground or hovering (default 5 m/s: a micro aircraft flies slower);
- ``[apriori]`` (optional) ``Cmq = { value = -12.0, std = 4.0, source = "DATCOM" }`` (or
  ``rel_std``): for the plausibility check and, with ``fsid estimate --priors``, as priors.

A scenario truth set (scenarios/aircraft/*.toml, :mod:`sim.aircraft`) is an aircraft file
too: its ``[limits]`` are checked and its ``[derivatives]`` table, the simulated aircraft's
definition, declares each derivative's sign for the verdict. Neither is needed.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from estimators.validation.plausibility import load_apriori
from pipeline.errors import FsidError
from pipeline.ingest.constants import AircraftConstants
from sim.aircraft import ALL_DERIVATIVES

#: the template ``fsid aircraft init`` writes (every key, commented)
TEMPLATE = Path(__file__).with_name("aircraft_template.toml")

_REQUIRED = {"geometry": ("S_m2", "b_m", "cbar_m"), "mass": ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2")}
_OPTIONAL = {"geometry": (), "mass": ("Ixz_kgm2",)}
_PROPULSION = ("max_thrust_N", "thrust_per_throttle_N", "throttle", "thrust_N")
_SURFACES = ("de", "da", "dr")
_SERVO_KEYS = tuple(f"{a}_{s}" for a in _SURFACES for s in ("travel_deg", "deg_per_unit"))
_LIMIT_KEYS = tuple(f"{a}_deg" for a in _SURFACES)
_SENSORS = ("airdata", "imu")
#: surface -> (DESIGN.md's convention, the opposite): how ``[signs]`` names them
CONVENTIONS = {
    "de": ("trailing edge down positive", "trailing edge up positive"),
    "da": ("right trailing edge up positive", "right trailing edge down positive"),
    "dr": ("trailing edge left positive", "trailing edge right positive"),
}
_TOP = (
    "name",
    "description",
    "source",
    "statically_unstable",
    "stall_speed_mps",
    "geometry",
    "mass",
    "propulsion",
    "servos",
    "sensors",
    "signs",
    "apriori",
    "derivatives",
    "limits",
)


@dataclass(frozen=True)
class AircraftFile:
    """An aircraft file read and checked: ``constants`` (mass, geometry, thrust, a-priori
    values, sign conventions; sensor positions not yet resolved), ``name``, ``path``, the
    ``sensors`` positions it gives (name -> (x, y, z) m), ``servo_travel`` (surface -> (deg
    at full servo travel, the key that gave it)) and whether it is a scenario ``truth_set``."""

    constants: AircraftConstants
    name: str
    path: Path
    sensors: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    servo_travel: dict[str, tuple[float, str]] = field(default_factory=dict)
    truth_set: bool = False


def read_aircraft_file(path: str | Path) -> AircraftFile:
    """Read and check an aircraft file (module docstring); a bad file is one
    :class:`~pipeline.errors.FsidError` naming the file, the key and what to write."""
    path = Path(path)
    raw = _toml(path)
    where = _Where(path)
    for key in raw:
        if key not in _TOP:
            raise where.error(key, f"unknown key; allowed: {', '.join(_TOP)}")
    num = {sec: _numbers(raw, sec, _REQUIRED[sec], _OPTIONAL[sec], where) for sec in _REQUIRED}
    g, m = num["geometry"], num["mass"]
    max_thrust, table = _propulsion(raw.get("propulsion"), where)
    limits = _numbers(raw, "limits", (), _LIMIT_KEYS, where) if "limits" in raw else {}
    unstable = raw.get("statically_unstable", False)
    if not isinstance(unstable, bool):
        raise where.error("statically_unstable", f"must be true or false, got {unstable!r}")
    ixz = m.get("Ixz_kgm2", 0.0)
    if ixz * ixz >= m["Ixx_kgm2"] * m["Izz_kgm2"]:
        # the inertia tensor must be positive definite: Ixx Izz - Ixz^2 > 0 (the roll-yaw
        # equations divide by it)
        raise where.error(
            "mass.Ixz_kgm2",
            f"{ixz:g} kg m^2 with Ixx {m['Ixx_kgm2']:g} and Izz {m['Izz_kgm2']:g}: no body has "
            "Ixz^2 >= Ixx Izz; check the value and its units (a product of inertia is a few % of Ixx)",
        )
    stall = raw.get("stall_speed_mps")
    if stall is not None and not (_is_number(stall) and stall > 0):
        raise where.error("stall_speed_mps", f"must be a speed in m/s above 0, got {stall!r}")
    ac = AircraftConstants(
        mass=m["mass_kg"],
        Ixx=m["Ixx_kgm2"],
        Iyy=m["Iyy_kgm2"],
        Izz=m["Izz_kgm2"],
        Ixz=m.get("Ixz_kgm2", 0.0),
        S=g["S_m2"],
        b=g["b_m"],
        cbar=g["cbar_m"],
        # with a map, max_thrust is its thrust at full throttle (what "thrust known" asks)
        max_thrust=max_thrust if table is None else float(np.interp(1.0, *table)),
        thrust_table=table,
        apriori=_apriori(raw.get("apriori"), where),
        reversed_inputs=_signs(raw.get("signs"), where),
        unstable=unstable,
        derivatives=_derivatives(raw.get("derivatives"), where),
        stall_speed=None if stall is None else float(stall),
    )
    return AircraftFile(
        constants=ac,
        name=str(raw.get("name", path.stem)),
        path=path.resolve(),
        sensors=_sensor_positions(raw.get("sensors"), where),
        servo_travel=_servo_travel(raw.get("servos"), limits, where),
        truth_set="derivatives" in raw,
    )


@dataclass(frozen=True)
class _Where:
    """The file being read, for the errors' 'where'."""

    path: Path

    def error(self, key: str, why: str) -> FsidError:
        return FsidError(f"aircraft file {self.path}: {key}: {why} (see docs/aircraft.md, or fsid aircraft init)")


def _toml(path: Path) -> dict[str, Any]:
    if path.is_dir():
        raise FsidError(f"aircraft file {path} is a directory; give the path of a .toml file")
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise FsidError(
            f"aircraft file {path} not found; check the path (fsid aircraft init {path} writes a template)"
        ) from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise FsidError(f"aircraft file {path}: not valid TOML ({exc})") from None


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _unit_hint(key: str, known: tuple[str, ...]) -> str:
    """'wrong unit; write it as sec.X' when ``key`` is a known quantity with another unit."""
    base = key.split("_")[0]
    same = [k for k in known if k.split("_")[0] == base]
    return f"wrong unit; write it as {same[0]}" if same else f"unknown key; allowed: {', '.join(known)}"


def _table(raw: Mapping[str, Any], sec: str, where: _Where, required: bool) -> dict[str, Any]:
    got = raw.get(sec)
    if got is None:
        if required:
            raise where.error(sec, "missing table")
        return {}
    if not isinstance(got, dict):
        raise where.error(sec, "must be a table")
    return got


def _numbers(
    raw: Mapping[str, Any], sec: str, required: tuple[str, ...], optional: tuple[str, ...], where: _Where
) -> dict[str, float]:
    """The numbers of table ``sec``: every ``required`` key, > 0 (Ixz any sign)."""
    got = _table(raw, sec, where, bool(required))
    known = required + optional
    out = {}
    for k, v in got.items():
        if k not in known:
            raise where.error(f"{sec}.{k}", _unit_hint(k, known))
        if not _is_number(v):
            raise where.error(f"{sec}.{k}", f"must be a number, got {v!r}")
        if k != "Ixz_kgm2" and not v > 0:
            raise where.error(f"{sec}.{k}", f"must be > 0, got {v!r}")
        out[k] = float(v)
    for k in required:
        if k not in out:
            raise where.error(f"{sec}.{k}", "missing; give it in SI units")
    return out


def _propulsion(raw: Any, where: _Where) -> tuple[float | None, tuple[tuple[float, ...], tuple[float, ...]] | None]:
    """(thrust per unit throttle N or None, (throttle, thrust N) table or None)."""
    if raw is None:
        return None, None
    got = _table({"propulsion": raw}, "propulsion", where, True)
    for k in got:
        if k not in _PROPULSION:
            raise where.error(f"propulsion.{k}", _unit_hint(k, _PROPULSION))
    lin = [k for k in ("max_thrust_N", "thrust_per_throttle_N") if k in got]
    if len(lin) == 2 and got[lin[0]] != got[lin[1]]:
        raise where.error("propulsion", "max_thrust_N and thrust_per_throttle_N are the same quantity: give one")
    scale = None
    if lin and "throttle" in got:
        raise where.error("propulsion", f"give {lin[0]} or the throttle/thrust_N map, not both")
    if lin:
        v = got[lin[0]]
        if not _is_number(v) or not v > 0:
            raise where.error(f"propulsion.{lin[0]}", f"must be a thrust in N, > 0, got {v!r}")
        scale = float(v)
    if ("throttle" in got) != ("thrust_N" in got):
        raise where.error("propulsion", "a throttle-to-thrust map needs both throttle = [...] and thrust_N = [...]")
    if "throttle" not in got:
        return scale, None
    thr, thrust = got["throttle"], got["thrust_N"]
    ok = isinstance(thr, list) and isinstance(thrust, list) and len(thr) == len(thrust) >= 2
    if not ok or not all(_is_number(x) for x in [*thr, *thrust]):
        raise where.error("propulsion", "throttle and thrust_N must be lists of numbers of the same length (>= 2)")
    x = np.asarray(thr, dtype=float)
    if not (np.all(np.diff(x) > 0) and x[0] >= 0 and x[-1] <= 1):
        raise where.error("propulsion.throttle", f"must rise strictly within 0..1, got {thr}")
    return scale, (tuple(x.tolist()), tuple(float(v) for v in thrust))


def _servo_travel(raw: Any, limits: Mapping[str, float], where: _Where) -> dict[str, tuple[float, str]]:
    """Surface -> (deflection (deg) at full servo travel / a normalised command of 1, key)."""
    if raw is None:
        return {}
    got = _table({"servos": raw}, "servos", where, True)
    out: dict[str, tuple[float, str]] = {}
    for k, v in got.items():
        if k not in _SERVO_KEYS:
            raise where.error(f"servos.{k}", _unit_hint(k, _SERVO_KEYS))
        if not _is_number(v) or not 0 < v <= 90:
            raise where.error(f"servos.{k}", f"must be a deflection in deg, 0 < x <= 90, got {v!r}")
        axis = k.split("_")[0]
        if axis in out and out[axis][0] != float(v):
            raise where.error(f"servos.{k}", f"{axis}_travel_deg and {axis}_deg_per_unit are the same: give one")
        lim = limits.get(f"{axis}_deg")
        if lim is not None and v < lim - 1e-9:
            raise where.error(
                f"servos.{k}",
                f"{v:g} deg is less than the surface limit limits.{axis}_deg ({lim:g}): full travel must reach it",
            )
        out[axis] = (float(v), k)
    return out


def _sensor_positions(raw: Any, where: _Where) -> dict[str, tuple[float, float, float]]:
    if raw is None:
        return {}
    got = _table({"sensors": raw}, "sensors", where, True)
    out = {}
    for name, tab in got.items():
        if name not in _SENSORS:
            raise where.error(f"sensors.{name}", f"unknown sensor; allowed: {', '.join(_SENSORS)}")
        if not isinstance(tab, dict) or set(tab) - {"position_m"}:
            raise where.error(f"sensors.{name}", "must be a table with position_m = [x, y, z] only")
        v = tab.get("position_m")
        if v is None:
            continue
        if not isinstance(v, list) or len(v) != 3 or not all(_is_number(x) for x in v):
            raise where.error(
                f"sensors.{name}.position_m", f"must be [x, y, z] in m from the CG (body axes), got {v!r}"
            )
        out[name] = tuple(float(x) for x in v)
    return out


def _signs(raw: Any, where: _Where) -> tuple[str, ...]:
    """The surfaces whose declared convention is the opposite of DESIGN.md's."""
    if raw is None:
        return ()
    got = _table({"signs": raw}, "signs", where, True)
    flipped = []
    for k, v in got.items():
        if k not in CONVENTIONS:
            raise where.error(f"signs.{k}", f"unknown surface; allowed: {', '.join(CONVENTIONS)}")
        said = " ".join(str(v).lower().replace("-", " ").split())
        if said not in CONVENTIONS[k]:
            raise where.error(f"signs.{k}", f"{v!r}: write {' or '.join(repr(c) for c in CONVENTIONS[k])}")
        if said == CONVENTIONS[k][1]:
            flipped.append(k)
    return tuple(flipped)


def _apriori(raw: Any, where: _Where) -> dict[str, dict[str, Any]]:
    """Derivative -> {value, std, source} (:func:`estimators.validation.load_apriori`)."""
    if raw is None:
        return {}
    got = _table({"apriori": raw}, "apriori", where, True)
    for k, v in got.items():
        if k not in ALL_DERIVATIVES:
            raise where.error(
                f"apriori.{k}",
                "unknown derivative; use fsid's names (e.g. Cmq, CLalpha; the table in docs/aircraft.md)",
            )
        if isinstance(v, dict) and not all(_is_number(v[x]) for x in ("value", "std", "rel_std") if x in v):
            raise where.error(f"apriori.{k}", f"value and std must be numbers (per rad), got {v!r}")
    try:
        df = load_apriori(got)
    except (ValueError, TypeError) as exc:
        raise where.error("apriori", f"{exc}; e.g. Cmq = {{ value = -12.0, std = 4.0 }}") from None
    for n, r in df.iterrows():
        if not r["std"] > 0:
            raise where.error(f"apriori.{n}", f"std must be > 0 (the value's uncertainty), got {r['std']!r}")
    return {n: {"value": float(r["value"]), "std": float(r["std"]), "source": r["source"]} for n, r in df.iterrows()}


def _derivatives(raw: Any, where: _Where) -> dict[str, float]:
    """A truth set's derivative table (per rad), any subset of the DESIGN.md names."""
    if raw is None:
        return {}
    got = _table({"derivatives": raw}, "derivatives", where, True)
    for k, v in got.items():
        if k not in ALL_DERIVATIVES:
            raise where.error(
                f"derivatives.{k}",
                "unknown derivative; use fsid's names (e.g. Cmq, CLalpha; the table in docs/aircraft.md)",
            )
        if not _is_number(v):
            raise where.error(f"derivatives.{k}", f"must be a number (per radian), got {v!r}")
    return {k: float(v) for k, v in got.items()}
