"""EstimationResult does not change after its fit: later stages make new results, and
every covariance stays a view chosen by name (statsmodels' cov_type)."""

import dataclasses

import numpy as np
import pytest
from _results import small_result


def test_a_result_cannot_be_changed_in_place():
    r = small_result()
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.cov = np.eye(2)
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.consider_cov = np.eye(2)


def test_covariances_are_views_chosen_by_name():
    r = small_result()
    assert r.cov_type == r.std_method == r.fit_cov_type == "crb" and list(r.covariances) == ["crb"]
    wide = r.with_cov(4.0 * r.cov, "crb|scatter", note="widened")
    # the original keeps its covariance; the new one reports the wider and keeps the bound
    np.testing.assert_allclose(r.std[["a", "b"]], [0.2, 0.3])
    np.testing.assert_allclose(wide.std[["a", "b"]], [0.4, 0.6])
    np.testing.assert_allclose(wide.std_of("crb")[["a", "b"]], [0.2, 0.3])
    assert wide.fit_cov_type == "crb" and wide.std_method == "crb|scatter" and wide.message == "widened"
    assert np.isnan(wide.std["c"])  # fixed
    back = wide.with_cov_type("crb")
    np.testing.assert_allclose(back.cov, r.cov)
    with pytest.raises(KeyError, match="no covariance 'sandwich'"):
        r.cov_of("sandwich")


def test_consider_parts_add_up_in_new_results_and_total_is_a_view():
    r = small_result()
    one = r.with_consider(np.diag([0.05, 0.0]), "sensor corrections")
    two = one.with_consider(np.diag([0.04, 0.07]), "wind")
    assert r.consider_cov is None and one.consider_source == "sensor corrections"
    assert two.consider_source == "sensor corrections; wind"
    np.testing.assert_allclose(two.total_std[["a", "b"]], [np.sqrt(0.04 + 0.09), np.sqrt(0.09 + 0.07)])
    np.testing.assert_allclose(np.sqrt(np.diag(two.cov_of("total"))), two.total_std[["a", "b"]])
    assert two.with_extra(note=1).extra == {"note": 1} and two.extra == {}
