"""estimators: system-identification numerics (numpy, scipy, numba).

Public API (DESIGN.md section 4)::

    from estimators import Model, Parameter, Segment, OutputError
    res = OutputError(model, integrator="rk4").fit([seg1, seg2], estimate_x0=False)
    res.params, res.std, res.corr, res.R, res.cost, res.summary()

The names below are imported from their modules on first use (PEP 562), so
``from estimators import OutputError`` loads output error and what it needs, not the
filters, the stabilised methods and scipy.signal with them: a fresh process reaches its
first fit sooner.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from estimators.errors import (
    BoundsError,
    ConvergenceError,
    DependentOutputsError,
    EstimationError,
    IdentifiabilityError,
    ModelDefinitionError,
    SimulationDivergedError,
    UnknownNameError,
)

#: public name -> the module that defines it
_LAZY = {
    "FourierRegression": "estimators.equation_error",
    "LeastSquares": "estimators.equation_error",
    "RecursiveLeastSquares": "estimators.equation_error",
    "FilterError": "estimators.filters.filter_error",
    "EKF": "estimators.filters.ekf",
    "UKF": "estimators.filters.ukf",
    "Model": "estimators.model",
    "Parameter": "estimators.model",
    "Segment": "estimators.model",
    "OutputError": "estimators.output_error.oem",
    "EstimationResult": "estimators.results",
    "EigenvalueTransformation": "estimators.output_error.stabilized",
    "EquationDecoupling": "estimators.output_error.stabilized",
    "StabilizedOutputError": "estimators.output_error.stabilized",
    "simulate_outputs": "estimators.simulation",
    "fourier_transform": "estimators.frequency.transform",
    "frequency_response": "estimators.frequency.response",
    "FrequencyResponse": "estimators.frequency.response",
    "TransferFunction": "estimators.frequency.transfer",
    "loes_parameters": "estimators.frequency.transfer",
    "FrequencyOutputError": "estimators.frequency.output_error",
    "StepwiseRegression": "estimators.structure",
    "OrthogonalFunctions": "estimators.structure",
}

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs
    from estimators.equation_error import FourierRegression, LeastSquares, RecursiveLeastSquares
    from estimators.filters.ekf import EKF
    from estimators.filters.filter_error import FilterError
    from estimators.filters.ukf import UKF
    from estimators.frequency.output_error import FrequencyOutputError
    from estimators.frequency.response import FrequencyResponse, frequency_response
    from estimators.frequency.transfer import TransferFunction, loes_parameters
    from estimators.frequency.transform import fourier_transform
    from estimators.model import Model, Parameter, Segment
    from estimators.output_error.oem import OutputError
    from estimators.output_error.stabilized import EigenvalueTransformation, EquationDecoupling, StabilizedOutputError
    from estimators.results import EstimationResult
    from estimators.simulation import simulate_outputs
    from estimators.structure import OrthogonalFunctions, StepwiseRegression

__all__ = [
    "Model",
    "Parameter",
    "Segment",
    "OutputError",
    "EstimationResult",
    "simulate_outputs",
    "EstimationError",
    "ModelDefinitionError",
    "BoundsError",
    "SimulationDivergedError",
    "IdentifiabilityError",
    "ConvergenceError",
    "DependentOutputsError",
    "UnknownNameError",
    "LeastSquares",
    "RecursiveLeastSquares",
    "FourierRegression",
    "EKF",
    "UKF",
    "FilterError",
    "StabilizedOutputError",
    "EigenvalueTransformation",
    "EquationDecoupling",
    "fourier_transform",
    "frequency_response",
    "FrequencyResponse",
    "TransferFunction",
    "loes_parameters",
    "FrequencyOutputError",
    "StepwiseRegression",
    "OrthogonalFunctions",
]


def __getattr__(name: str) -> Any:
    """A public name imported from its module on first use (then kept as an attribute);
    a submodule (``estimators.filters.filter_error``) imported on first attribute access."""
    mod = _LAZY.get(name)
    if mod is not None:
        value = getattr(importlib.import_module(mod), name)
        globals()[name] = value
        return value
    if not name.startswith("_"):
        try:
            return importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as e:
            if e.name != f"{__name__}.{name}":
                raise
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
