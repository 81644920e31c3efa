"""Where ``fsid estimate`` gets the aircraft constants and the sensor positions from.

Aircraft (mass, inertia, geometry, thrust, a-priori values, sign conventions):
``--aircraft A.toml``, an aircraft file (:mod:`pipeline.ingest.aircraft_file`,
docs/aircraft.md); without it, the
``truth.json`` that ``fsid run`` / ``fsid simulate`` write next to the log (a simulated
flight); a user model needs neither (its constants are in the model).

Sensor positions from the CG (body axes, m), per sensor (``airdata`` = vane/boom, ``imu``),
first found wins:

1. the aircraft TOML's ``[sensors.airdata] position_m = [x, y, z]`` / ``[sensors.imu]``;
2. ``truth.json`` next to the log (the simulated sensors' mounting positions);
3. the log's autopilot parameters: ArduPilot ``INS_POS1_X/Y/Z``, PX4 ``EKF2_IMU_POS_X/Y/Z``
   (IMU only; neither autopilot records an air-data vane position);
4. zeros, with a printed note (the vane assumed at the CG).

Servo travel (the surface deflection at full servo travel, to decode servo PWM or PX4's
normalised surface commands; :func:`servo_travel_for`): the aircraft TOML's ``[servos]``,
else the ``truth.json`` next to the log, else the log (the simulator's ``FSID_TRAVEL_*``
parameters), else 30 deg assumed, with a data-quality warning - the control derivatives
scale with it.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pipeline.errors import FsidError
from pipeline.ingest.aircraft_file import read_aircraft_file
from pipeline.ingest.constants import AircraftConstants

#: autopilot parameters holding the IMU position from the CG (body axes, m)
IMU_PARAMS = (("INS_POS1_X", "INS_POS1_Y", "INS_POS1_Z"), ("EKF2_IMU_POS_X", "EKF2_IMU_POS_Y", "EKF2_IMU_POS_Z"))
SENSOR_WORDS = {"airdata": "air-data vane/boom", "imu": "IMU"}


def truth_next_to(log: str | Path) -> tuple[Path, dict] | None:
    """(path, document) of a ``truth.json`` from ``fsid run``/``fsid simulate`` next to the
    log, or None."""
    p = Path(log).resolve().parent / "truth.json"
    if not p.is_file():
        return None
    try:
        doc = json.loads(p.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or "aircraft" not in doc:
        return None
    return p, doc


def load_aircraft_toml(path: str | Path) -> tuple[AircraftConstants, str, dict]:
    """(constants without sensor positions, aircraft name, sensor positions the file gives)
    of an aircraft file (:func:`pipeline.ingest.aircraft_file.read_aircraft_file`)."""
    af = read_aircraft_file(path)
    return af.constants, af.name, dict(af.sensors)


def params_imu_position(params: Mapping[str, float]) -> tuple[tuple[float, float, float], str] | None:
    for names in IMU_PARAMS:
        if all(n in params for n in names):
            return tuple(float(params[n]) for n in names), "/".join(names)
    return None


def resolve_sensor_positions(
    ac: AircraftConstants, toml_sensors: Mapping[str, Any], truth: tuple[Path, dict] | None, params: Mapping[str, float]
) -> tuple[AircraftConstants, dict[str, str]]:
    """The constants with ``airdata``/``imu`` filled by the precedence of the module
    docstring; returns (constants, sensor -> where its position came from)."""
    pos, src = {}, {}
    tsens = (truth[1].get("sensors") or {}) if truth else {}
    for name in ("airdata", "imu"):
        if name in toml_sensors:
            pos[name], src[name] = tuple(float(v) for v in toml_sensors[name]), "aircraft TOML"
            continue
        t = tsens.get(name) or {}
        if "position_m" in t:
            pos[name], src[name] = tuple(float(v) for v in t["position_m"]), f"{truth[0]}"
            continue
        if name == "imu":
            got = params_imu_position(params)
            if got:
                pos[name], src[name] = got[0], f"log parameters {got[1]}"
                continue
        pos[name], src[name] = (0.0, 0.0, 0.0), "none"
    return dataclasses.replace(ac, **pos), src


def servo_travel_for(log: str | Path, aircraft: str | Path | None) -> dict[str, tuple[float, str]]:
    """Surface -> (deg at full servo travel, origin) from the aircraft TOML's ``[servos]``
    or, without ``aircraft``, the truth.json next to the log; {} when neither gives it
    (the channel map and the log decide, :func:`pipeline.ingest.maps.servo_travel`)."""
    if aircraft is not None:
        travel = read_aircraft_file(aircraft).servo_travel
        return {a: (deg, f"aircraft TOML [servos] {key}") for a, (deg, key) in travel.items()}
    truth = truth_next_to(log)
    travel = ((truth[1].get("servo") or {}).get("travel_deg") or {}) if truth else {}
    return {a: (float(v), f"{truth[0]}") for a, v in travel.items()} if isinstance(travel, dict) else {}


def aircraft_for_log(
    log: str | Path, aircraft: str | Path | None, fd: Any, *, required: bool, say=print
) -> tuple[AircraftConstants | None, str | None, dict | None]:
    """Aircraft constants (with sensor positions) for a log: (constants or None, aircraft
    name, truth.json document when one sits next to the log). ``required``: a built-in
    model needs an aircraft: without ``--aircraft`` and without truth.json, one clear
    error. ``say`` prints the notes (where the aircraft and positions came from)."""
    truth = truth_next_to(log)
    if aircraft is not None:
        ac, name, toml_sensors = load_aircraft_toml(aircraft)
    elif truth is not None:
        ac = AircraftConstants.from_truth(truth[1])
        name = (truth[1].get("aircraft") or {}).get("name", "?")
        toml_sensors = {}
        say(f"note: no --aircraft: using aircraft {name!r} from {truth[0]} next to the log (a simulated flight)")
    elif required:
        raise FsidError(
            f"the built-in models need the aircraft's mass, inertia and geometry: give "
            f"--aircraft A.toml (see scenarios/aircraft/) for {log}, or fit your own "
            "model with --model path/to/file.py:name"
        )
    else:
        return None, None, None
    ac, src = resolve_sensor_positions(ac, toml_sensors, truth, fd.params if fd is not None else {})
    for s in ("airdata", "imu"):
        p = getattr(ac, s)
        if src[s] == "none":
            say(
                f"note: no {SENSOR_WORDS[s]} position known (aircraft TOML [sensors.{s}] "
                f"position_m, truth.json or log parameters): {SENSOR_WORDS[s]} assumed at the CG"
            )
        else:
            say(f"note: {SENSOR_WORDS[s]} at ({p[0]:g}, {p[1]:g}, {p[2]:g}) m from the CG (from {src[s]})")
    return ac, name, truth[1] if truth else None
