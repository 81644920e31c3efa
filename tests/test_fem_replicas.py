"""Filter error on simulated replicas of the reference software's two filter-error cases
(:mod:`estimators.replicas`): from the reference's start values and default options it
recovers the truth (the reference's estimates) within 3 std, process noise included, and
fails, if at all, only with a typed EstimationError. The scatter over seeds against the
reported std is benchmarks/fem_replicas.py's."""

import numpy as np
import pytest

from estimators import EstimationError, FilterError
from estimators.replicas import HFB320_F_START, LATERAL_F_START, hfb320_replica, lateral_replica

CASES = {"hfb320": (hfb320_replica, HFB320_F_START), "lateral": (lateral_replica, LATERAL_F_START)}


def _truth(ex):
    return {**ex.truth, **{f"F_{s}": ex.process_noise[i, i] for i, s in enumerate(ex.model.states)}}


@pytest.mark.parametrize("case", list(CASES))
def test_replica_recovers_truth(case):
    make, f_start = CASES[case]
    ex = make(0)
    res = FilterError(ex.model, process_noise=f_start).fit(ex.segments)
    assert res.converged, res.message
    assert not any(n.startswith("G_") for n in res.names)  # R is not a parameter
    off = {n: abs(res.params[n] - v) / res.std[n] for n, v in _truth(ex).items()}
    assert max(off.values()) < 3.0, {n: round(v, 2) for n, v in off.items() if v >= 3.0}
    # the process noise moved from its start to the truth: F_V from 0.02 to 0.36 m/s/sqrt(s)
    f_name = "F_V" if case == "hfb320" else "F_p"
    assert abs(res.params[f_name] - f_start[f_name[2:]]) > 5 * res.std[f_name]
    # R is the innovations' covariance at the estimates
    E = np.concatenate([r.to_numpy() for r in res.residuals])
    np.testing.assert_allclose(np.diag(res.extra["innovation_cov"][0]), np.mean(E**2, axis=0), rtol=0.02)
    assert np.all(np.diag(res.extra["measurement_noise"]) >= 0.0)


@pytest.mark.parametrize("case", list(CASES))
def test_replica_from_a_hostile_start_fails_typed_or_fits(case):
    """A process-noise start 20x the truth and a measurement-noise start 100x too small:
    a result, or an EstimationError - never a numpy or scipy exception."""
    make, f_start = CASES[case]
    ex = make(3)
    F = {s: 20 * ex.process_noise[i, i] for i, s in enumerate(ex.model.states)}
    try:
        res = FilterError(ex.model, process_noise=F, measurement_noise=ex.noise_std / 100).fit(ex.segments)
    except EstimationError:
        return
    assert np.all(np.isfinite(res.params.to_numpy()))


def test_diagonal_R_is_the_reference_option():
    ex = hfb320_replica(0)
    full = FilterError(ex.model, process_noise=HFB320_F_START).fit(ex.segments)
    diag = FilterError(ex.model, process_noise=HFB320_F_START, full_R=False).fit(ex.segments)
    R = diag.extra["innovation_cov"][0]
    assert np.all(R == np.diag(np.diag(R))) and np.any(
        full.extra["innovation_cov"][0] != np.diag(np.diag(full.extra["innovation_cov"][0]))
    )
    # the derivatives agree; the process noise of the diagonal R makes up for the
    # correlations it ignores
    d = max(abs(full.params[n] - diag.params[n]) / full.std[n] for n in ex.truth)
    assert d < 2.0
