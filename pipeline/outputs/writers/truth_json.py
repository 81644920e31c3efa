"""``truth.json``: what the synthetic flight really was (derivatives, trim, sensor errors, seed)."""

from __future__ import annotations

import json
import os

import numpy as np

from pipeline.paths import atomic_write_text


def _clean(x):
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    return x


def truth_dict(result) -> dict:
    """JSON-ready truth of a :class:`sim.SimResult` (SI units, radians).

    Keys: scenario, seed, aircraft (geometry, mass, thrust model, derivatives), trim,
    maneuvers [{name, axis, t_start, t_end}], sensors (error parameters applied),
    turbulence, wind (steady NED, m/s), sas, versions, units.
    """
    s = result.scenario
    m = result.meta
    return _clean(
        {
            "format": "fsid-truth/1",
            "scenario": {
                "name": s.name,
                "description": s.description,
                "path": str(s.path) if s.path else None,
                "duration_s": s.duration,
                "rate_hz": s.rate_hz,
                "trim_request": {
                    "altitude_m": s.altitude,
                    "airspeed_mps": s.airspeed,
                    "flight_path_rad": s.flight_path,
                    "heading_rad": s.heading,
                },
            },
            "seed": m["seed"],
            "aircraft": result.aircraft.to_dict(),
            "derivatives": dict(result.aircraft.derivatives),
            "trim": result.trim,
            "maneuvers": [{"name": n, "axis": a, "t_start": t0, "t_end": t1} for n, a, t0, t1 in result.maneuvers],
            "sensors": m["sensors"],
            "turbulence": m["turbulence"],
            "wind": m.get("wind"),
            "sas": m.get("sas"),
            "actuator_lag_s": m.get("actuator_lag_s"),
            "servo": m.get("servo"),
            "versions": m["versions"],
            "units": {
                "angles": "rad",
                "rates": "rad/s",
                "lengths": "m",
                "speeds": "m/s",
                "mass": "kg",
                "inertia": "kg m^2",
                "force": "N",
                "time": "s",
                "truth_columns": m.get("truth_units"),
            },
        }
    )


def write_truth_json(path: str | os.PathLike, result) -> None:
    """Write :func:`truth_dict` of ``result`` to ``path`` (atomic, sorted keys, 2-space indent)."""
    atomic_write_text(path, json.dumps(truth_dict(result), indent=2, sort_keys=True) + "\n")
