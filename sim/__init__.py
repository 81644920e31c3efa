"""Synthetic truth: JSBSim flies designed maneuvers through Dryden turbulence.

Public API (SI units throughout; see each docstring):

* :func:`load_scenario` (path) -> :class:`Scenario`
* :func:`load_aircraft` (path) -> :class:`Aircraft`
* :func:`fly` (scenario, seed=None, workdir=None, progress=None) -> :class:`SimResult`
* :class:`ScenarioError` (ValueError): a malformed or untrimmable scenario, one line.

Imports nothing else of the project (jsbsim, numpy, scipy, pandas only).
"""

from sim.aircraft import ALL_DERIVATIVES, DERIVATIVES, Aircraft, load_aircraft
from sim.errors import ScenarioError
from sim.flight import SimResult, fly
from sim.maneuvers import Maneuver
from sim.scenario import Scenario, load_scenario, scenario_from_dict
from sim.sensors import SensorSpec
from sim.truth import TRUTH_COLUMNS, TRUTH_UNITS
from sim.turbulence import dryden_parameters, dryden_psd

__all__ = [
    "ALL_DERIVATIVES",
    "DERIVATIVES",
    "Aircraft",
    "Maneuver",
    "Scenario",
    "ScenarioError",
    "SensorSpec",
    "SimResult",
    "TRUTH_COLUMNS",
    "TRUTH_UNITS",
    "dryden_parameters",
    "dryden_psd",
    "fly",
    "load_aircraft",
    "load_scenario",
    "scenario_from_dict",
]
