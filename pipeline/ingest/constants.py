"""The aircraft's constants as the models need them, and the ISA troposphere.

:class:`AircraftConstants` is built from an aircraft description (an aircraft file,
:mod:`pipeline.ingest.aircraft_file`, or the ``truth.json`` of a simulated flight) by
:mod:`pipeline.ingest.aircraft`; the problem
builders read mass, inertia, geometry, thrust and sensor positions from it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimators.validation.plausibility import expected_signs
from pipeline.errors import FsidError


@dataclass
class AircraftConstants:
    """What the models need to know about the aircraft (SI units).

    mass (kg), Ixx Iyy Izz Ixz (kg m^2), S (m^2), b, cbar (m), max_thrust (N, thrust =
    throttle * max_thrust when the log has no thrust channel), sensor positions from the
    CG in body axes (m): ``airdata`` and ``imu`` as (x, y, z).

    What the owner knows beyond that (:mod:`pipeline.ingest.aircraft_file`):
    ``thrust_table`` (throttle 0..1, thrust N): a measured throttle-to-thrust map,
    interpolated linearly (:meth:`thrust`; ``max_thrust`` is then its thrust at full
    throttle); ``apriori``:
    derivative -> {value, std, source} (per rad), for the plausibility check and, asked
    for, as priors; ``reversed_inputs``: the surfaces (de, da, dr) whose positive
    deflection is the opposite of DESIGN.md's convention; ``unstable``: statically
    unstable in pitch (a positive Cmalpha no fault); ``derivatives``: a truth set's
    derivative table (a simulated aircraft), whose signs the sign check takes as declared;
    ``stall_speed`` (m/s): below it for most of a span the aircraft is on the ground or
    hovering (:func:`pipeline.conditioning.checks.airborne_speed`; default 5 m/s).
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
    thrust_table: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    apriori: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    reversed_inputs: tuple[str, ...] = ()
    unstable: bool = False
    derivatives: Mapping[str, float] = field(default_factory=dict)
    stall_speed: float | None = None

    def thrust(self, throttle: np.ndarray) -> np.ndarray | None:
        """Thrust (N) at ``throttle`` (0..1, any shape): the throttle-to-thrust table
        interpolated linearly (held at its ends), else throttle * max_thrust; None when
        neither is known."""
        if self.thrust_table is not None:
            return np.interp(np.asarray(throttle, dtype=float), *self.thrust_table)
        if self.max_thrust:
            return np.asarray(throttle, dtype=float) * self.max_thrust
        return None

    def expected_signs(self) -> dict[str, int]:
        """Derivative -> the sign (+1/-1) the verdict expects of it for this aircraft
        (:func:`estimators.validation.expected_signs`)."""
        return expected_signs(self.reversed_inputs, unstable=self.unstable, declared=self.derivatives)

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
            derivatives={k: float(v) for k, v in (truth.get("derivatives") or ac.get("derivatives") or {}).items()},
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
