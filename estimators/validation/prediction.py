"""Air-data-driven prediction: the proof of match for turbulence and for unstable aircraft.

The classic proof of match simulates the held-out maneuver open loop. That is only fair
in calm air and for a stable model: gusts move the aircraft in ways no deterministic
simulation can follow (the TRUE derivatives miss a 3-2-1-1 flown in light turbulence by
~4 deg/s on q), and an unstable model flown through the surface positions a stability
augmentation system commanded drifts away exponentially from any error in its state.

The gusts are not unknown, though: the air-data sensors measure them. The vane's alpha and
beta and the pitot's V are the AIR-RELATIVE states, gust included, and the aerodynamic
forces and moments depend on them. :func:`air_data_prediction` runs the identified model,
every parameter held fixed, as an extended Kalman filter that sees ONLY the air-data
outputs (V, alpha, beta among the model's measured states) with process noise on those
states and on the model's unmeasured states (disturbance states such as gust-filter
states, which only the process noise drives), none on the other measured states. The filter keeps the model's air-relative states on the measured ones (that
is where the gusts enter, and it anchors an unstable short period), while the inertial
responses - rates, attitudes, specific forces - are the model's own prediction: the
filter never sees them, and an error in any moment or force derivative shows there in
full (a moment derivative tens of percent off misses the pitch rate by several times what
the true derivatives miss it by). The air-data channels themselves are the filter's
one-step predictions and prove nothing; they are returned but must not be judged.

What the air data cannot see is the rotary turbulence (the gust gradient along the
airframe, a few deg/s rms on a small UAV in light turbulence), which acts through
the damping derivatives; its effect on the rates remains in the residuals and sets how
tight a band the true model can meet.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from estimators.errors import ModelDefinitionError
from estimators.filters.ekf import EKF
from estimators.filters.noise import default_process_noise, process_noise_matrix
from estimators.integrators import DEFAULT_INPUTS
from estimators.model import Model, Segment

__all__ = ["AIR_DATA", "DrivenPrediction", "air_data_prediction", "driving_states"]

#: canonical air-data channels (DESIGN.md section 3) that measure air-relative states
AIR_DATA = ("V", "alpha", "beta")


@dataclass
class DrivenPrediction:
    """predicted: (N, n_out) a-priori outputs on the segment's t; driven: the outputs the
    filter used (not to be judged); judged: the others; filtered: (N, n_states)
    a-posteriori states; process_noise: the F (n, n) used (state unit per sqrt(s))."""

    predicted: pd.DataFrame
    driven: list[str]
    judged: list[str]
    filtered: pd.DataFrame
    process_noise: np.ndarray


def driving_states(model: Model, channels: Sequence[str] = AIR_DATA) -> list[str]:
    """The model's states that are air-data channels and measured outputs, in state order."""
    return [s for s in model.states if s in channels and s in model.outputs]


def air_data_prediction(
    model: Model,
    segment: Segment,
    *,
    process_noise: Any = None,
    measurement_noise: Any = None,
    drive: Sequence[str] | None = None,
    integrator: str = "rk4",
    inputs: str = DEFAULT_INPUTS,
) -> DrivenPrediction:
    """Predict ``segment`` with the model driven by its measured air data (module doc).

    model: the identified model with its estimates as values; every parameter is held
        (per-segment ones, e.g. output biases, at their values: pass the fitted segments'
        mean, as sensor biases persist through a flight).
    process_noise: F of the identification ({state: std}, (n,) or (n, n); state unit per
        sqrt(s)); only its rows/columns of the driving and the unmeasured states are kept. None, or zero on
        every driving state: the data default of :func:`estimators.filters.noise.default_process_noise`.
    measurement_noise: R as :class:`~estimators.EKF` takes it ({output: std}, (n_out,) std
        or (n_out, n_out)); None: the data default (only the driving outputs' entries matter).
    drive: the states to drive (default :func:`driving_states`); each must be a measured
        output. Raises ModelDefinitionError when there is none (no air data in the model).
    """
    drive = list(drive) if drive is not None else driving_states(model)
    bad = [s for s in drive if s not in model.states or s not in model.outputs]
    if bad:
        raise ModelDefinitionError(f"drive {bad}: each must be a state that is also a measured output")
    if not drive:
        raise ModelDefinitionError(
            f"no air-data state to drive the prediction (states {model.states}, outputs "
            f"{model.outputs}; air data: {', '.join(AIR_DATA)}): use the simulation proof of match"
        )
    n = len(model.states)
    air = np.array([s in drive for s in model.states])
    keep = air | np.array([s not in model.outputs for s in model.states])
    F = process_noise_matrix(model, process_noise) if process_noise is not None else np.zeros((n, n))
    F = np.where(np.outer(keep, keep), F, 0.0)
    if not np.any(F[air][:, air]):
        F = np.diag(np.where(air, default_process_noise(model, [segment]), 0.0))
    z = np.where([o in drive for o in model.outputs], segment.z, np.nan)
    hidden = Segment(t=segment.t, u=segment.u, z=z, x0=segment.initial_state(model), name=segment.name)
    held = model.fixed([p.name for p in model.parameters])
    res = EKF(held, integrator=integrator, inputs=inputs, process_noise=F, measurement_noise=measurement_noise).fit(
        hidden
    )
    pred = res.predicted[0]
    return DrivenPrediction(
        predicted=pred,
        driven=[o for o in model.outputs if o in drive],
        judged=[o for o in model.outputs if o not in drive],
        filtered=res.extra["states"][0],
        process_noise=F,
    )
