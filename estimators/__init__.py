"""estimators: system-identification numerics (numpy, scipy, numba).

Public API (DESIGN.md section 4)::

    from estimators import Model, Parameter, Segment, OutputError
    res = OutputError(model, integrator="rk4").fit([seg1, seg2], estimate_x0=False)
    res.params, res.std, res.corr, res.R, res.cost, res.summary()
"""
from estimators.errors import (BoundsError, ConvergenceError, EstimationError,
                               IdentifiabilityError, ModelDefinitionError,
                               SimulationDivergedError, UnknownNameError)
from estimators.equation_error import FourierRegression, LeastSquares, RecursiveLeastSquares
from estimators.fem import FilterError
from estimators.kalman import EKF, UKF
from estimators.model import Model, Parameter, Segment
from estimators.oem import OutputError
from estimators.results import EstimationResult
from estimators.stabilized import (EigenvalueTransformation, EquationDecoupling,
                                   StabilizedOutputError)
from estimators.simulation import simulate_outputs

__all__ = [
    "Model", "Parameter", "Segment", "OutputError", "EstimationResult", "simulate_outputs",
    "EstimationError", "ModelDefinitionError", "BoundsError", "SimulationDivergedError",
    "IdentifiabilityError", "ConvergenceError", "UnknownNameError",
    "LeastSquares", "RecursiveLeastSquares", "FourierRegression", "EKF", "UKF",
    "FilterError", "StabilizedOutputError", "EigenvalueTransformation", "EquationDecoupling",
]
