"""Closed loop on the lateral-directional axes through the real-log path (issue 6):
lateral_doublets_calm -> JSBSim -> flight.mcap/.bin -> ingest -> output error and equation
error -> validation, with the truth known. Aileron/rudder maneuvers only, so output error
fits the lateral model driven by the measured V, alpha, theta, q (no longitudinal
estimates to hold)."""
import json
from pathlib import Path

import pytest

from pipeline.run import run_scenario

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
LATERAL = ("CYbeta", "CYp", "CYr", "CYda", "CYdr", "Clbeta", "Clp", "Clr", "Clda", "Cldr",
           "Cnbeta", "Cnp", "Cnr", "Cnda", "Cndr")


@pytest.fixture(scope="module")
def lateral_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("lateral")
    run_scenario(SCENARIOS / "lateral_doublets_calm.toml", out, methods=["oem", "ls"], quiet=True)
    return json.loads((out / "report.json").read_text())


def _derivs(m):
    return {k: v for k, v in m["parameters"].items() if k in LATERAL and v.get("truth") is not None}


def _tic(m):
    return {k: round(d["TIC"], 3) for k, d in m["validation"]["fit"]["per_output"].items()}


def test_lateral_oem_fit_and_proof_of_match(lateral_run):
    m = lateral_run["methods"]["oem"]
    assert m["converged"] and m["model"] == "lateral-measured"
    assert set(_derivs(m)) == set(LATERAL)
    tic = _tic(m)
    assert set(tic) == {"beta", "p", "r", "phi", "ay"}
    assert max(tic.values()) < 0.1, tic
    pom = m["validation"]["proof_of_match"]
    assert [s["name"] for s in pom["segments"]] == ["auto_da_4+auto_dr_2"]   # cross-controlled
    assert pom["all_pass"], pom


def test_lateral_oem_derivatives_close_to_the_truth(lateral_run):
    """What output error does achieve: every lateral derivative within 5 std and 5 % (or
    0.02 absolute for the zero-truth ones) of the truth; the stiff ones within 1 %."""
    d = _derivs(lateral_run["methods"]["oem"])
    far = {k: round(v["error_in_std"], 2) for k, v in d.items() if v["error_in_std"] > 5.0}
    assert not far, far
    for k, v in d.items():
        tol = 0.05 * abs(v["truth"]) if v["truth"] else 0.02
        assert abs(v["estimate"] - v["truth"]) < tol, (k, v)
    for k in ("CYbeta", "Clbeta", "Clp", "Clda", "Cldr", "Cnbeta", "Cnr", "Cnda", "Cndr"):
        assert abs(d[k]["estimate"] / d[k]["truth"] - 1) < 0.01, (k, d[k])


@pytest.mark.xfail(strict=True, reason=(
    "measured on seed 21: Clda 3.8, Cldr 3.2, Cnp 4.3, Cnda 4.1, Cndr 4.2 std from the truth "
    "(0.3-1 % relative; 4.6 % on Cnp); CY*, Clbeta, Clp, Clr, Cnbeta, Cnr within 2.2 std. A "
    "noise-free flight of the same maneuvers fits every derivative within 0.1 % (0.3 % on "
    "Cndr), seed 5 lands all within 3.0 std with the same signs, and Morelli-Klein bounds "
    "are 1.3x the Cramer-Rao ones: a ~1 % noise-driven bias on the aileron/rudder yaw "
    "derivatives that is not explained yet"))
def test_lateral_oem_derivatives_within_3_std(lateral_run):
    d = _derivs(lateral_run["methods"]["oem"])
    worst = {k: round(v["error_in_std"], 2) for k, v in d.items() if v["error_in_std"] > 3.0}
    assert not worst, f"derivatives more than 3 std from the truth: {worst}"


def test_lateral_ls_fits_the_outputs(lateral_run):
    """Equation error: the outputs are fitted (TIC < 0.1 with the initial states and biases
    fitted), but see the two gaps below."""
    m = lateral_run["methods"]["ls"]
    tic = _tic(m)
    assert max(tic.values()) < 0.1, tic


@pytest.mark.xfail(strict=True, reason=(
    "measured: equation error (OLS on the linear-model regressions at the mean airspeed, "
    "rates differentiated) puts every Cl and Cn derivative 12-18 % below the truth "
    "(Clbeta 24, Cldr 20, Cnbeta 22, Clp 18 std; CYbeta 15 std) and misses the held-out "
    "maneuver on p and r by 4.3 and 4.1 deg/s (tolerance 1.5)"))
def test_lateral_ls_derivatives_and_proof_of_match(lateral_run):
    m = lateral_run["methods"]["ls"]
    d = _derivs(m)
    worst = {k: round(v["error_in_std"], 2) for k, v in d.items() if v["error_in_std"] > 3.0}
    assert not worst and m["validation"]["proof_of_match"]["all_pass"], worst
