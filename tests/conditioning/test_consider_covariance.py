"""Consider covariance: uncertainty a fit held as exact (the sensor corrections applied
before it) added to the Cramér-Rao bound - EstimationResult.total_std, the table's
error in std, and the compatibility document's correction covariance."""

import numpy as np
import pandas as pd
import pytest
from _results import small_result

from pipeline.uncertainty.consider import correction_covariance


def _result(consider=None):
    return small_result(consider, "test")


def test_without_consider_total_std_is_the_crb():
    r = _result()
    assert r.consider_std is None
    pd.testing.assert_series_equal(r.total_std, r.std.rename("total_std"))
    tab = r.table({"a": -1.0, "b": 2.6})
    assert "total_std" not in tab and tab.loc["a", "error_in_std"] == pytest.approx(0.5 / 0.2)
    assert "std (total)" not in r.summary()


def test_consider_widens_the_std_and_the_error_uses_it():
    r = _result(np.array([[0.09, 0.0], [0.0, 0.16]]))  # consider std 0.3, 0.4
    assert r.consider_std["a"] == pytest.approx(0.3) and np.isnan(r.consider_std["c"])
    assert r.total_std["a"] == pytest.approx(np.hypot(0.2, 0.3))
    assert r.total_std["b"] == pytest.approx(0.5)
    assert r.std["b"] == pytest.approx(0.3)  # the CRB itself unchanged
    tab = r.table({"a": -1.0, "b": 2.6})
    assert tab.loc["b", "error_in_std"] == pytest.approx(0.6 / 0.5)
    assert tab.loc["a", "consider_std"] == pytest.approx(0.3)
    d = r.to_dict({"a": -1.0})
    assert d["parameters"]["a"]["total_std"] == pytest.approx(np.hypot(0.2, 0.3))
    assert "std (total)" in r.summary() and "consider: test" in r.summary()


def test_correction_covariance_from_the_document():
    doc = {
        "applied": {"bias_q": {"estimate": 0.01, "std": 0.002}, "scale_alpha": {"estimate": 0.08, "std": 0.005}},
        "applied_correlation": {"names": ["scale_alpha", "bias_q"], "matrix": [[1.0, -0.5], [-0.5, 1.0]]},
    }
    names, est, C = correction_covariance(doc)
    assert names == ["bias_q", "scale_alpha"] and list(est) == [0.01, 0.08]
    np.testing.assert_allclose(C, [[4e-6, -0.5 * 0.002 * 0.005], [-0.5 * 0.002 * 0.005, 2.5e-5]])
    # no correlation given: independent
    _, _, C = correction_covariance({"applied": doc["applied"]})
    np.testing.assert_allclose(C, np.diag([4e-6, 2.5e-5]))
    assert correction_covariance({"applied": {}})[0] == []


def _doc():
    return {
        "applied": {"bias_q": {"estimate": 0.01, "std": 0.002}, "scale_alpha": {"estimate": 0.08, "std": 0.005}},
        "applied_correlation": {"names": ["bias_q", "scale_alpha"], "matrix": [[1.0, 0.3], [0.3, 1.0]]},
    }


def test_propagate_builds_j_c_jt_from_the_refits():
    """The refit sees the data corrected with one correction moved by its std; a fit whose
    estimates move linearly with the corrections gets exactly J C J^T."""
    from pipeline.ingest.flightdata import Channel, FlightData
    from pipeline.uncertainty.consider import propagate

    t = np.arange(0.0, 1.0, 0.01)
    fd = FlightData({"q": Channel(t, np.zeros_like(t), "rad/s")}, {}, [])
    res = _result()
    Jtrue = np.array([[2.0, -1.0], [0.5, 4.0]])  # d(a, b) / d(bias_q, scale_alpha)
    est0 = np.array([0.01, 0.08])

    def refit(fd_j, starts):
        assert starts["m"] is not None
        c = np.array([fd_j.meta["compatibility"]["bias_q"], fd_j.meta["compatibility"]["scale_alpha"]])
        r = _result()
        values = r.values.copy()
        values[:2] += Jtrue @ (c - est0)
        return {"m": r.replace(values=values)}

    results = {"m": res}
    doc = propagate(fd, _doc(), results, refit)
    assert doc["methods"] == {"m": "propagated"} and doc["refits"] == 2
    _, _, C = correction_covariance(_doc())
    # the results are replaced, the fit's own left as it was
    assert res.consider_cov is None and results["m"] is not res
    np.testing.assert_allclose(results["m"].consider_cov, Jtrue @ C @ Jtrue.T, rtol=1e-6)
    assert results["m"].consider_source


def test_propagate_keeps_the_crb_when_a_refit_fails():
    from pipeline.ingest.flightdata import FlightData
    from pipeline.uncertainty.consider import propagate

    res = _result()

    def refit(fd_j, starts):
        raise RuntimeError("diverged")

    results = {"m": res}
    doc = propagate(FlightData({}, {}, []), _doc(), results, refit)
    assert doc["methods"]["m"].startswith("not propagated") and "diverged" in doc["methods"]["m"]
    assert results["m"] is res and res.consider_cov is None
    assert propagate(FlightData({}, {}, []), {"applied": {}}, {"m": res}, refit) == {}
