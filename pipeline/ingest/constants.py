"""The aircraft's constants as the models need them, and the ISA troposphere.

:class:`AircraftConstants` is built from an aircraft description (an aircraft TOML or the
``truth.json`` of a simulated flight) by :mod:`pipeline.ingest.aircraft`; the problem
builders read mass, inertia, geometry, thrust and sensor positions from it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.errors import FsidError


@dataclass
class AircraftConstants:
    """What the models need to know about the aircraft (SI units).

    mass (kg), Ixx Iyy Izz Ixz (kg m^2), S (m^2), b, cbar (m), max_thrust (N, thrust =
    throttle * max_thrust when the log has no thrust channel), sensor positions from the
    CG in body axes (m): ``airdata`` and ``imu`` as (x, y, z).
    """

    mass: float
    Ixx: float
    Iyy: float
    Izz: float
    Ixz: float
    S: float
    b: float
    cbar: float
    max_thrust: float | None = None
    airdata: tuple[float, float, float] = (0.0, 0.0, 0.0)
    imu: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_truth(cls, truth: Mapping[str, Any]) -> AircraftConstants:
        """From a run's truth.json dictionary (aircraft + sensor positions)."""
        ac = truth["aircraft"]
        sensors = truth.get("sensors", {})

        def pos(name):
            s = sensors.get(name, {}) or {}
            return tuple(float(v) for v in s.get("position_m", s.get("position", (0, 0, 0))))

        g = ac.get("geometry", ac)
        m = ac.get("mass", ac)
        prop = ac.get("propulsion", ac)
        return cls(
            mass=_num(m, "mass_kg", "mass"),
            Ixx=_num(m, "Ixx_kgm2", "Ixx"),
            Iyy=_num(m, "Iyy_kgm2", "Iyy"),
            Izz=_num(m, "Izz_kgm2", "Izz"),
            Ixz=_num(m, "Ixz_kgm2", "Ixz"),
            S=_num(g, "S_m2", "S"),
            b=_num(g, "b_m", "b"),
            cbar=_num(g, "cbar_m", "cbar"),
            max_thrust=_num(prop, "max_thrust_N", "max_thrust", default=None),
            airdata=pos("airdata"),
            imu=pos("imu"),
        )

    @classmethod
    def from_aircraft(cls, aircraft: Any, sensors: Mapping[str, Sequence[float]] | None = None) -> AircraftConstants:
        """From a :class:`sim.Aircraft` (an aircraft TOML) and optional sensor positions."""
        d = aircraft.to_dict()
        return cls.from_truth(
            {"aircraft": d, "sensors": {k: {"position_m": list(v)} for k, v in (sensors or {}).items()}}
        )


def _num(d: Mapping[str, Any], *keys: str, default: Any = ...) -> Any:
    """The first of ``keys`` that ``d`` holds, as a float; ``default`` when none is there,
    else an error asking for the first key in the aircraft TOML."""
    for k in keys:
        if k in d and d[k] is not None:
            return float(d[k])
    if default is not ...:
        return default
    raise FsidError(f"aircraft description has no {keys[0]!r}: add it (SI units) to the aircraft TOML")


def isa_density(h: np.ndarray | float) -> np.ndarray:
    """ISA air density (kg/m^3) at geometric altitude h (m), troposphere."""
    T = 288.15 - 0.0065 * np.asarray(h, dtype=float)
    return 1.225 * (T / 288.15) ** 4.2559


def isa_altitude(rho: float) -> float:
    """The altitude (m) of the ISA troposphere where the air density is ``rho`` (kg/m^3):
    the inverse of :func:`isa_density`."""
    return float((1.0 - (max(rho, 1e-3) / 1.225) ** (1.0 / 4.2559)) * 288.15 / 0.0065)
