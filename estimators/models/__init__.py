"""Built-in aircraft models with the derivative names of DESIGN.md section 3.

Each builder takes the constants (mass, inertia, geometry, density, ...) from the caller
and returns an :class:`estimators.Model`; start values and which parameters are free are
arguments. The model functions are written so that numba compiles them.
"""

from estimators.models.lateral import lateral_directional
from estimators.models.longitudinal import LONGITUDINAL_DEFAULTS, longitudinal
from estimators.models.short_period import short_period
from estimators.models.sixdof import SIXDOF_DEFAULTS, sixdof

__all__ = ["longitudinal", "short_period", "lateral_directional", "sixdof", "LONGITUDINAL_DEFAULTS", "SIXDOF_DEFAULTS"]
