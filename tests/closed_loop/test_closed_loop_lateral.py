"""Closed loop on the lateral-directional axes through the real-log path (issue 6):
lateral_doublets_calm -> JSBSim -> flight.mcap/.bin -> ingest -> output error and equation
error -> validation, with the truth known. Aileron/rudder maneuvers only, so output error
fits the lateral model driven by the measured V, alpha, theta, q (no longitudinal
estimates to hold)."""

import json
from pathlib import Path

import pytest

from pipeline.cli import main
from pipeline.jobs.scenario import run_scenario
from pipeline.problems.lateral import LAT_FREE

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
LATERAL = LAT_FREE


@pytest.fixture(scope="module")
def lateral_out(tmp_path_factory):
    out = tmp_path_factory.mktemp("lateral")
    run_scenario(SCENARIOS / "lateral_doublets_calm.toml", out, methods=["oem", "ls"], quiet=True, figures=False)
    return out


@pytest.fixture(scope="module")
def lateral_run(lateral_out):
    return json.loads((lateral_out / "report.json").read_text())


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
    assert [s["name"] for s in pom["segments"]] == ["auto_da_4+auto_dr_2"]  # cross-controlled
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


def test_lateral_oem_derivatives_within_3_std(lateral_run):
    """Every derivative within 3 Cramer-Rao bounds of the truth. The pseudo-input V carries
    the pitot noise (0.3 m/s; each window's mean 0.02 m/s off, 0.1-0.2 % in dynamic
    pressure against bounds of 0.03-0.1 %), which output error would take as exact: Clda,
    Cldr, Cnp, Cnda, Cndr were 3.2-4.3 std off on seed 21 (Cnbeta 7.8 on seed 11). The
    model now has a per-maneuver correction dV[k] with the a-priori std sigma_V / sqrt(n)
    (pipeline.problems.lateral.with_airspeed_offsets), so the bounds include it: worst 2.55 std
    on seed 21 (Cndr; was 4.3); seeds 5, 7, 11, 3, 13, 17: 1.9, 1.9, 2.8, 3.2, 3.5, 2.3 (were
    3.0, 1.5, 7.8, 3.7, 7.0, 2.4): a constant dV[k] leaves the noise's fluctuation inside a
    window, so seeds 3 and 13 still exceed 3 std. The pseudo-inputs V and alpha are now the
    air data below 0.1 Hz blended with the integrated IMU above
    (lateral_problem(kinematic=True)): worst 1.99 std on seed 21 (CYda; the moment
    derivatives within 1.0), and the empirical / reported std of the moment derivatives
    over 16 seeds 0.84-1.44 against 1.36-2.09 with the air data alone
    (benchmarks/lateral_airspeed_mc.py)."""
    d = _derivs(lateral_run["methods"]["oem"])
    worst = {k: round(v["error_in_std"], 2) for k, v in d.items() if v["error_in_std"] > 3.0}
    assert not worst, f"derivatives more than 3 std from the truth: {worst}"


def test_lateral_ls_fits_the_outputs(lateral_run):
    """Equation error: the outputs are fitted (TIC < 0.1 with the initial states and biases
    fitted)."""
    m = lateral_run["methods"]["ls"]
    tic = _tic(m)
    assert max(tic.values()) < 0.1, tic


def test_lateral_ls_derivatives_and_proof_of_match(lateral_run):
    """Equation error within 3 std of every lateral derivative (0.02-1.2 % on seed 21) and
    the held-out maneuver matched. Was 12-18 % low: np.gradient of the raw rates smeared
    the roll response at the surface steps (5-7 % on the noise-free truth) and vane noise
    on the nearly collinear beta regressor (errors in variables, CYbeta -10 %, CYdr
    +15 %); see pipeline.problems.regressions.lateral_regressions. Seed 5 lands Clr, Cnr at 3.1, 3.6
    std (0.7 %)."""
    m = lateral_run["methods"]["ls"]
    d = _derivs(m)
    worst = {k: round(v["error_in_std"], 2) for k, v in d.items() if v["error_in_std"] > 3.0}
    assert not worst and m["validation"]["proof_of_match"]["all_pass"], worst


def test_lateral_oem_from_the_written_ardupilot_bin(lateral_out, tmp_path):
    """The same flight through ``fsid estimate flight.bin``: no vane in an ArduPilot log, so
    beta is rebuilt from the GPS velocity, the attitude and a fitted wind (zero mean
    sideslip per window, pipeline.conditioning.flow_angles); ailerons and rudder from RCOU PWM. Every
    lateral derivative within 3 std (seed 21: worst CYda 2.14, with the vane 1.99) and the
    held-out cross-controlled maneuver matched."""
    code = main(
        ["estimate", str(lateral_out / "flight.bin"), "--model", "lateral", "--out", str(tmp_path / "bin"), "--quiet"]
    )
    assert code == 0
    rep = json.loads((tmp_path / "bin" / "report.json").read_text())
    assert rep["meta"]["flow_angles"]["status"] == "reconstructed"
    assert rep["meta"]["servo_travel"]["da"] == {"deg": 30.0, "from": str(lateral_out / "truth.json")}
    m = rep["methods"]["oem"]
    assert m["converged"] and m["model"] == "lateral-measured"
    d = _derivs(m)
    assert set(d) == set(LATERAL)
    worst = {k: round(v["error_in_std"], 2) for k, v in d.items() if v["error_in_std"] > 3.0}
    assert not worst, worst
    assert m["validation"]["proof_of_match"]["all_pass"]
