"""Verdicts no milder than the evidence: a derivative whose sign physics or the control sign
convention fixes, estimated on the wrong side of zero beyond k of its std, FAILs; so does
an estimate beyond k combined std of an a-priori value. Both on a real output-error fit of
the HFB-320-like example (estimators.datasets), one parameter moved where the test needs it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import estimators
from estimators import validation as V
from estimators.datasets import longitudinal_example
from pipeline.validation import refresh_plausibility, validate


@pytest.fixture(scope="module")
def fit():
    ex = longitudinal_example(0, segments=1)
    return estimators.OutputError(ex.model).fit(ex.segments)


def _moved(res, **values):
    """The same result with some estimates set (the fit's std kept)."""
    vals = res.values.copy()
    for name, v in values.items():
        vals[res.names.index(name)] = v
    return dataclasses.replace(res, values=vals)


def _sign_reasons(v):
    return [r for r, kind in zip(v["verdict"]["reasons"], v["verdict"]["reason_levels"]) if "wrong sign" in r]


def test_the_fit_itself_has_every_expected_sign(fit):
    v = validate(fit)
    signs = v["plausibility"]["signs"]
    assert set(signs) == {"CLalpha", "CLde", "Cmalpha", "Cmq", "Cmde"}
    assert not any(d["flag"] for d in signs.values()) and not _sign_reasons(v)
    assert signs["Cmq"]["expected"] == -1 and signs["Cmq"]["margin"] > 100  # -15.8 +- 0.10


def test_a_wrong_sign_beyond_its_std_fails(fit):
    """Cmq flipped to +15.8 (std 0.10): FAIL, the reason names Cmq, its value and std, the
    rule and how far beyond zero it lies; Cmde flipped too: a second reason."""
    cmq, sd = float(fit.params["Cmq"]), float(fit.std["Cmq"])
    v = validate(_moved(fit, Cmq=-cmq, Cmde=-float(fit.params["Cmde"])))
    assert v["verdict"]["level"] == "FAIL" and not v["verdict"]["ok"]
    reasons = _sign_reasons(v)
    assert len(reasons) == 2, v["verdict"]
    assert reasons[0].startswith(f"Cmq = {-cmq:.4g} +- {sd:.2g} has the wrong sign: Cmq < 0 (pitch damping)")
    assert f"lies {-cmq / sd:.1f} std beyond zero (more than 3)" in reasons[0]
    assert "Cmde" in reasons[1] and "elevator's sign convention" in reasons[1]
    d = v["plausibility"]["signs"]["Cmq"]
    assert d["flag"] and d["margin"] == pytest.approx(cmq / sd)


def test_a_near_zero_estimate_of_the_wrong_sign_does_not_fail(fit):
    """An estimate within k std of zero on the wrong side is not evidence of a wrong sign."""
    sd = float(fit.std["Cmq"])
    v = validate(_moved(fit, Cmq=2.5 * sd))
    assert not v["plausibility"]["signs"]["Cmq"]["flag"] and not _sign_reasons(v)
    v = validate(_moved(fit, Cmq=3.5 * sd))
    assert v["plausibility"]["signs"]["Cmq"]["flag"] and v["verdict"]["level"] == "FAIL"


def test_declared_stability_and_conventions_set_the_expected_signs(fit):
    """Cmalpha > 0 fails unless the aircraft is declared statically unstable; Cmde > 0 fails
    in DESIGN.md's elevator convention and passes with the elevator declared reversed,
    where Cmde < 0 fails instead."""
    flipped = _moved(fit, Cmalpha=-float(fit.params["Cmalpha"]), Cmde=-float(fit.params["Cmde"]))
    assert {"Cmalpha", "Cmde"} <= {r.split()[0] for r in _sign_reasons(validate(flipped))}
    declared = V.expected_signs(["de"], unstable=True)
    assert "Cmalpha" not in declared and declared["Cmde"] == 1 and declared["CLde"] == -1
    assert not _sign_reasons(validate(_moved(fit, Cmalpha=0.8, CLde=-0.39, Cmde=1.59), signs=declared))
    assert [r.split()[0] for r in _sign_reasons(validate(fit, signs=declared))] == ["CLde", "Cmde"]
    # a truth set's derivative table declares its own signs (a simulated aircraft)
    assert V.expected_signs(declared={"CYdr": -0.17, "Cmalpha": 0.155})["CYdr"] == -1
    assert V.expected_signs(declared={"Cmalpha": 0.155})["Cmalpha"] == 1


def test_an_apriori_value_beyond_the_combined_std_fails(fit):
    """|estimate - a priori| > 3 sqrt(std^2 + std_ap^2): FAIL naming both values; within it
    (2.5 combined std here): no reason."""
    cmq, sd = float(fit.params["Cmq"]), float(fit.std["Cmq"])
    sd_ap = 0.3
    comb = float(np.hypot(sd, sd_ap))
    far = validate(fit, apriori={"Cmq": {"value": cmq + 4.0 * comb, "std": sd_ap, "source": "DATCOM"}})
    assert far["verdict"]["level"] == "FAIL"
    (r,) = [r for r in far["verdict"]["reasons"] if "a-priori" in r]
    assert r == (
        f"Cmq = {cmq:.4g} +- {sd:.2g} disagrees with its a-priori value {cmq + 4.0 * comb:.4g} +- 0.3 "
        "by 4.0 combined std (more than 3)"
    )
    near = validate(fit, apriori={"Cmq": {"value": cmq - 2.5 * comb, "std": sd_ap}})
    assert near["plausibility"]["apriori"]["Cmq"]["z"] == pytest.approx(2.5)
    assert near["verdict"]["level"] == "PASS" and not near["verdict"]["reasons"], near["verdict"]


def test_the_checks_are_redone_when_the_std_grows(fit):
    """A consider covariance (what the fit held as exact) set after the validation widens
    the total std: the wrong sign within it no longer fails."""
    sd = float(fit.std["Cmq"])
    res = _moved(fit, Cmq=5.0 * sd)
    v = validate(res, apriori={"Cmq": {"value": -5.0 * sd, "std": 2.0 * sd}})
    assert v["verdict"]["level"] == "FAIL" and len(v["verdict"]["reasons"]) == 2
    cov = np.zeros((len(res.free_names),) * 2)
    cov[res.free_names.index("Cmq"), res.free_names.index("Cmq")] = (3.0 * sd) ** 2
    refresh_plausibility(v, dataclasses.replace(res, consider_cov=cov))
    assert v["plausibility"]["signs"]["Cmq"]["std"] == pytest.approx(np.sqrt(10.0) * sd)
    assert not v["verdict"]["reasons"], v["verdict"]
