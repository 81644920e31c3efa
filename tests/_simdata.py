"""Flown datasets shared by the sim and writer tests: each flown once per test session."""

from __future__ import annotations

import atexit
import functools
import shutil
import tempfile
from pathlib import Path

import sim

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"


def scenario(name: str) -> sim.Scenario:
    return sim.load_scenario(SCENARIOS / f"{name}.toml")


def custom(raw: dict, name: str = "custom") -> sim.Scenario:
    """A scenario from a dict; aircraft paths are relative to scenarios/."""
    return sim.scenario_from_dict(raw, SCENARIOS / f"{name}.toml")


@functools.cache
def flown(name: str, seed: int | None = None) -> sim.SimResult:
    """The built-in scenario ``name`` flown once (optionally with another seed)."""
    return sim.fly(scenario(name), seed=seed)


@functools.cache
def quiet_flight(
    aircraft: str, altitude: float, airspeed: float, duration: float = 30.0, pwm_servos: bool = True
) -> sim.SimResult:
    """Calm air, no inputs: for trim-hold checks. ``pwm_servos``: the scenario's
    [actuators] pwm_servos (False: continuous commands)."""
    raw = {
        "aircraft": f"aircraft/{aircraft}.toml",
        "duration_s": duration,
        "trim": {"altitude_m": altitude, "airspeed_mps": airspeed},
    }
    if not pwm_servos:
        raw["actuators"] = {"pwm_servos": False}
    return sim.fly(custom(raw))


@functools.cache
def turbulence_10min() -> sim.SimResult:
    """Light aircraft, 10 minutes of Tustin-form Dryden turbulence at 1500 m (above
    2000 ft, where MIL-F-8785C intensity and scale length do not depend on altitude),
    no inputs, vanes sampled at 100 Hz."""
    return sim.fly(
        custom(
            {
                "aircraft": "aircraft/light_aircraft.toml",
                "duration_s": 600.0,
                "seed": 1,
                "trim": {"altitude_m": 1500.0, "airspeed_mps": 67.0},
                "turbulence": {"model": "tustin", "severity": "light"},
                "sensors": {"airdata": {"rate_hz": 100.0}},
            },
            "turbulence_10min",
        )
    )


_TMP: list[str] = []


@functools.cache
def written(name: str, seed: int | None = None) -> Path:
    """flight.mcap, flight.bin and truth.json of ``flown(name, seed)`` in a temp folder."""
    from pipeline.outputs.writers import write_dataflash, write_mcap, write_truth_json

    d = Path(tempfile.mkdtemp(prefix=f"fsid-{name}-"))
    _TMP.append(str(d))
    r = flown(name, seed)
    write_mcap(d / "flight.mcap", r)
    write_dataflash(d / "flight.bin", r)
    write_truth_json(d / "truth.json", r)
    return d


@atexit.register
def _cleanup() -> None:
    for d in _TMP:
        shutil.rmtree(d, ignore_errors=True)
