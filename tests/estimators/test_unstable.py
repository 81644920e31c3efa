"""Unstable aircraft (statically unstable short period flown with a SAS loop): plain output
error reports divergence; stabilised OEM, eigenvalue transformation, equation decoupling,
FEM, EKF and UKF recover every free derivative within 3 std."""

import numpy as np
import pytest

from estimators import (
    EKF,
    UKF,
    EigenvalueTransformation,
    EquationDecoupling,
    FilterError,
    ModelDefinitionError,
    OutputError,
    SimulationDivergedError,
    StabilizedOutputError,
)
from estimators.output_error.stabilized import _linearisation
from estimators.process_noise_examples import UNSTABLE_SP_FREE, unstable_short_period_example


@pytest.fixture(scope="module")
def calm():
    return unstable_short_period_example(seed=1)


@pytest.fixture(scope="module")
def gusty():
    return unstable_short_period_example(seed=2, sigma_alpha=0.001, sigma_q=0.002)


def within(res, truth, k=3.0):
    assert set(UNSTABLE_SP_FREE) <= set(res.free_names)
    err = {n: abs(res.params[n] - truth[n]) / res.std[n] for n in UNSTABLE_SP_FREE}
    bad = {n: round(e, 2) for n, e in err.items() if not e < k}
    assert not bad, f"{res.method}: estimates outside {k} std of truth: {bad}"


def test_the_example_is_unstable_and_the_sas_keeps_it_flying(calm):
    A, _ = _linearisation(calm.truth_model, calm.segments, None)
    assert np.max(np.linalg.eigvals(A).real) > 0.5  # time to double < 1.4 s
    assert np.all(np.abs(calm.segments[0].z[:, 0]) < np.radians(5))  # closed loop stays small


def test_plain_output_error_reports_divergence_and_names_the_remedies(calm):
    with pytest.raises(SimulationDivergedError) as info:
        OutputError(calm.model).fit(calm.segments)
    msg = str(info.value)
    assert "diverged at t=" in msg
    for name in (
        "StabilizedOutputError",
        "EigenvalueTransformation",
        "EquationDecoupling",
        "FilterError",
        "EKF",
        "UKF",
    ):
        assert name in msg
    assert info.value.segment == 0 and info.value.time is not None


@pytest.mark.slow
def test_stabilized_output_error(calm):
    est = StabilizedOutputError(calm.model)
    res = est.fit(calm.segments)
    assert res.method == "oem-stabilized" and res.converged
    within(res, calm.truth)
    S = res.extra["S"]
    assert S.shape == (2, 4) and np.all(S[:, 2:] == 0)  # feeds back alpha and q only
    # the default S stabilises the linearised start model: A - S C has no unstable pole
    A, C = _linearisation(calm.model, calm.segments, None)
    assert np.max(np.linalg.eigvals(A).real) > 0
    assert np.max(np.linalg.eigvals(A - S @ C).real) < 0


@pytest.mark.slow
def test_eigenvalue_transformation(calm):
    res = EigenvalueTransformation(calm.model).fit(calm.segments)
    assert res.method == "oem-eigenvalue-transform" and res.converged
    assert res.extra["sigma"] > 0.5
    w = res.extra["weights"][0]
    assert w[0] == 1.0 and w[-1] < 1e-6
    within(res, calm.truth)
    assert "sandwich" in res.message


@pytest.mark.slow
def test_equation_decoupling(calm):
    res = EquationDecoupling(calm.model, states=["alpha"]).fit(calm.segments)
    assert res.method == "oem-decoupled" and res.converged
    assert res.extra["decoupled_states"] == ["alpha"]
    within(res, calm.truth)
    # std carry the noise of the fed-back measurements; the plain Cramér-Rao bounds are kept
    assert res.cov_of("crb").shape == (5, 5) and res.std_method == "propagated"
    assert set(res.covariances) == {"crb", "propagated"} and res.fit_cov_type == "crb"
    assert "measurement noise propagated" in res.message
    assert EquationDecoupling(calm.model, states=["alpha"], std="crb").fit(calm.segments).std_method == "crb"
    with pytest.raises(ModelDefinitionError, match="std must be one of"):
        StabilizedOutputError(calm.model, std="white")


def test_filter_error_on_unstable_aircraft_in_light_turbulence(gusty):
    res = FilterError(gusty.model, process_noise={"alpha": 0.003, "q": 0.003}).fit(gusty.segments)
    assert res.converged
    within(res, gusty.truth)


@pytest.mark.parametrize("cls", [EKF, UKF])
def test_kalman_filters_on_unstable_aircraft(calm, gusty, cls):
    for ex, q in ((calm, None), (gusty, {"alpha": 0.001, "q": 0.002})):
        res = cls(ex.model, measurement_noise=ex.noise_std, process_noise=q).fit(ex.segments)
        within(res, ex.truth)
