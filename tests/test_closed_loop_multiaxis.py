"""Closed loop on multiaxis_multisine_turbulence (issue 6): light aircraft at 67 m/s in light
Tustin turbulence, three simultaneous 3-axis multisines and an elevator sweep, air data on a
wing-tip boom (y = 3 m). scenario -> JSBSim -> flight.mcap/.bin -> ingest -> FEM / EKF / UKF
-> validation, truth known; flown once per module (~50 s).

The sensor-compatibility stage is skipped (``compat=False``, it takes ~2 min on this
flight): it applies no correction here anyway (air-data residuals 5-6 x their noise level in
the turbulence, so its estimates are not trusted and the data go to estimation as logged).

Both axes are fitted with the multi-axis models (pipeline.identify.multiaxis_problem): each
axis driven by the other axis' measured variables, air data at the boom's (x, y, z), and
for the filters the Dryden gust states - JSBSim's aerodynamics see p - p_turb, q - q_turb
(rotary turbulence 2.8 / 2.4 deg/s rms here), which a model of the gyro rates books on the
derivatives (JSBSim's own Cm regressed on the gyro q: Cmde -0.76, truth -1.122) - with
CLalphadot, Cmalphadot free (truth 1.7, -7.27; FEM 1.81 +- 0.64, -7.83 +- 0.54;
corr(Cmq, Cmalphadot) -0.32, corr(CLq, CLalphadot) -0.16, corr(Cmalpha, Cmalphadot) 0.69),
and the air density along the flight as an input (ISA at the measured altitude: the
phugoid moves it +-1.2 %; with the flight's mean density FEM CD0 was 9.6, CLalpha 3.6 std off).

Measured before this model (wings-level longitudinal model, linear lateral model): FEM
CL0 9.3, Cmde 9.5, Cm0 7.9, CLq 7.0 std off, EKF/UKF Cm0/Cmalpha/Cmde 30-40 std, lateral
FEM Clp 49, Clda 31, Clbeta 30 std, EKF/UKF Clp 330 std. Now (seed 31): longitudinal FEM
every derivative within 2.5 std; EKF/UKF all but CLq (4.2 std) within 3 (UKF Cmalpha 2.98,
not asserted); lateral FEM 11 of 15 within 3 std, Clp 5.9, Clda 5.6, Cnp 4.1, Cnda 3.5;
EKF/UKF Clp 31-32, Clda 17-18 std. What does not hold is a strict xfail with the measured
numbers.
"""
import json
from pathlib import Path

import pytest

from pipeline.run import run_scenario

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "multiaxis_multisine_turbulence.toml"
METHODS = ("fem", "ekf", "ukf")
LONG = ("CD0", "CDalpha", "CDalpha2", "CL0", "CLalpha", "CLq", "CLde", "Cm0", "Cmalpha", "Cmq",
        "Cmde", "CLalphadot", "Cmalphadot")
LAT = ("CYbeta", "CYp", "CYr", "CYda", "CYdr", "Clbeta", "Clp", "Clr", "Clda", "Cldr",
       "Cnbeta", "Cnp", "Cnr", "Cnda", "Cndr")
#: longitudinal derivatives measured more than 3 std from the truth (|error|/std, seed 31)
LONG_OFF = {"fem": {},
            "ekf": {"CLq": 4.2},
            "ukf": {"CLq": 4.2, "Cmalpha": 2.98}}


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("multiaxis")
    run_scenario(SCENARIO, out, methods=list(METHODS), quiet=True, compat=False)
    return json.loads((out / "report.json").read_text())


def _errors(rep, key, names):
    ps = rep["methods"][key]["parameters"]
    assert set(names) <= set(ps), sorted(set(names) - set(ps))
    return {n: round(abs(ps[n]["error_in_std"]), 2) for n in names}


@pytest.mark.parametrize("method", METHODS)
def test_longitudinal_multiaxis_model(report, method):
    m = report["methods"][f"longitudinal-{method}"]
    assert m["model"] == "longitudinal-measured" and m["converged"]
    errs = _errors(report, f"longitudinal-{method}", LONG)
    held = {n: e for n, e in errs.items() if n not in LONG_OFF[method]}
    assert max(held.values()) <= 3.0, f"{method}: |error|/std {errs}"
    # the moment derivatives, the aim of the multisines, all within 3 std except UKF Cmalpha
    assert all(errs[n] <= 3.0 for n in ("Cm0", "Cmq", "Cmde", "Cmalphadot")), errs
    if method == "fem":
        ps = m["parameters"]
        assert {"F_V", "F_alpha", "F_q_gi"} <= set(ps) and ps["F_q_gi"]["estimate"] > 0


@pytest.mark.parametrize("method", [
    "fem", *(pytest.param(m, marks=pytest.mark.xfail(strict=True, reason=(
        "measured CLq 6.6-6.8 for 3.9, 4.2 std (EKF, UKF: process noise fixed at the "
        "turbulence level, not estimated as in FEM)"))) for m in ("ekf", "ukf"))])
def test_longitudinal_all_within_3_std(report, method):
    errs = _errors(report, f"longitudinal-{method}", LONG)
    assert max(errs.values()) <= 3.0, errs


def _tic(rep, key):
    return {k: d["TIC"] for k, d in rep["methods"][key]["validation"]["fit"]["per_output"].items()}


@pytest.mark.parametrize("method", METHODS)
def test_tic_below_0_1_except_air_data_angles(report, method):
    lon, lat = _tic(report, f"longitudinal-{method}"), _tic(report, f"lateral-{method}")
    assert set(lon) == {"V", "alpha", "theta", "q", "ax", "az"}
    assert set(lat) == {"beta", "p", "r", "phi", "ay"}
    assert max(v for k, v in lon.items() if k != "alpha") < 0.1, lon
    assert max(v for k, v in lat.items() if k not in ("beta", "ay")) < 0.1, lat


@pytest.mark.xfail(strict=True, reason="TIC alpha 0.143, beta 0.129, ay 0.131 (all methods): "
                   "residuals at the sensor noise (FEM alpha residual std 0.0043 rad, vane "
                   "noise 0.0038 rad) on signals only ~4x the noise (alpha std 0.015 rad)")
@pytest.mark.parametrize("method", METHODS)
def test_tic_below_0_1_every_output(report, method):
    tic = {**_tic(report, f"longitudinal-{method}"), **_tic(report, f"lateral-{method}")}
    assert max(tic.values()) < 0.1, tic


def test_lateral_fem_gust_model(report):
    """The lateral FEM with the gust states: every derivative within 8 std (was up to 49),
    all but Clp, Clda, Cnp, Cnda within 3 std."""
    m = report["methods"]["lateral-fem"]
    assert m["model"] == "lateral-measured" and m["converged"]
    errs = _errors(report, "lateral-fem", LAT)
    assert max(errs.values()) < 8.0, errs
    held = {n: e for n, e in errs.items() if n not in ("Clp", "Clda", "Cnp", "Cnda")}
    assert max(held.values()) <= 3.0, errs
    assert 0.05 < m["parameters"]["tau_pg"]["estimate"] < 1.0


@pytest.mark.xfail(strict=True, reason="lateral |error|/std > 3 (seed 31): FEM Clp 5.9 (-0.338 "
                   "for -0.484), Clda 5.6 (0.170 for 0.229), Cnp 4.1, Cnda 3.5; EKF Clp 32, Clda "
                   "18, Clbeta 9.7; UKF Clp 31, Clda 17, Clbeta 9.6 - the roll derivatives 30 % "
                   "low together: the roll gust (p_turb 2.8 deg/s rms; its spectrum is not the "
                   "first-order Dryden one, autocorrelation time ~0.5 s, estimated tau_pg 0.33 s) "
                   "and the roll response to it are barely separable (corr(Clp, F_p_g) 0.94)")
@pytest.mark.parametrize("method", METHODS)
def test_lateral_all_within_3_std(report, method):
    errs = _errors(report, f"lateral-{method}", LAT)
    assert max(errs.values()) <= 3.0, errs


@pytest.mark.xfail(strict=True, reason="proof of match on the held-out multisine_c fails for "
                   "every method: FEM theta 3.9 deg, q 4.7 deg/s (bands 1.5), p 6.3 deg/s, phi "
                   "7.2 deg - and the TRUE derivatives miss by as much (q 4.9, theta 3.9, p 6.2, "
                   "phi 6.8; benchmarks/pom_floor.py: identified/true 0.96-1.06): the rotary "
                   "turbulence JSBSim adds (2.4-2.8 deg/s rms) is in no air-data channel and "
                   "stays in the predicted rates, so the bands are below what this flight allows")
@pytest.mark.parametrize("method", METHODS)
def test_proof_of_match(report, method):
    for axis in ("longitudinal", "lateral"):
        pm = report["methods"][f"{axis}-{method}"]["validation"]["proof_of_match"]
        errs = {c: round(d["max_abs_error_display"], 2)
                for c, d in pm["segments"][0]["channels"].items()}
        assert pm["all_pass"], f"{axis} {method}: {errs}"
