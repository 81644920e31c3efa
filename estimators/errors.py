"""Typed failures of the estimators. Each message says what happened and what to do."""

from __future__ import annotations


class EstimationError(Exception):
    """Base class of every error the estimators raise on purpose."""

    exit_code = 3


class ModelDefinitionError(EstimationError, ValueError):
    """The model, its parameters or a segment are inconsistent (shapes, names, bounds)."""


class UnknownNameError(ModelDefinitionError, AttributeError):
    """f or g asked for a parameter or constant the model does not have (``p.CDx``); an
    AttributeError too, so ``hasattr`` and ``getattr(p, name, default)`` work."""


class DependentOutputsError(ModelDefinitionError):
    """A full innovation covariance was asked for while some measured outputs are exact
    functions of the others and the inputs: its determinant can be driven to zero, so it is
    not identifiable. ``outputs`` names them."""

    def __init__(self, message: str, *, outputs: list[str] | None = None) -> None:
        super().__init__(message)
        self.outputs = list(outputs or [])


class BoundsError(ModelDefinitionError):
    """A start value lies outside its parameter's bounds."""


class SimulationDivergedError(EstimationError, FloatingPointError):
    """The model simulation produced NaN/Inf or overflowed.

    Attributes: ``segment`` (index), ``time`` (s, first non-finite sample), ``state`` (name).
    """

    def __init__(
        self, message: str, *, segment: int | None = None, time: float | None = None, state: str | None = None
    ) -> None:
        super().__init__(message)
        self.segment, self.time, self.state = segment, time, state


class IdentifiabilityError(EstimationError, ArithmeticError):
    """The information matrix is singular: ``parameters`` lists those that cannot be
    identified from these data (no sensitivity, or a linear combination of others)."""

    def __init__(self, message: str, *, parameters: list[str] | None = None) -> None:
        super().__init__(message)
        self.parameters = list(parameters or [])


class ConvergenceError(EstimationError, RuntimeError):
    """The optimiser could not reduce the cost from the start values."""


#: what to try when a simulation runs away (output error's divergence messages)
DIVERGE_HINT = (
    "Check the units and signs of the start values, set bounds, start closer "
    "(e.g. from an equation-error fit, estimators.LeastSquares); for an unstable "
    "aircraft use a method that keeps the simulation bounded: StabilizedOutputError "
    "(stabilisation matrix S), EigenvalueTransformation (exp(-sigma t) weighting) "
    "or EquationDecoupling (measured states as pseudo-inputs), or the filter "
    "methods FilterError, EKF or UKF."
)
