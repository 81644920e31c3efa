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
every derivative within 1.3 std (2.5 before FEM's R came from the log's native samples,
pipeline.run.attach_logged_noise); EKF/UKF, their passes repeated until the estimates
settle (estimators.EKF passes="auto"), all but CLq 4.8-5.0, CL0 3.3-3.4, CLde 3.3-3.5 std
(EKF Cmalphadot 3.3) within 3 - one pass from the equation-error start had left only CLq
(4.2) off, a start-dependent result; lateral FEM 11 of 15 within 3 std, Clp 4.7, Clda 4.7,
Cnp 3.6, Cnda 3.3 (5.9, 5.6, 4.1, 3.5 with the grid's R); UKF all but Clp 6.5, Clda 3.6
within 3 std, EKF Clp 18.7, Clda 10.4, Clbeta 8.0 (8 passes each). The filters' roll gust
starts each segment with its stationary spread (estimators.EKF state_std default; at
1e-3 rad/s, as before, UKF Clp 24, Clda 14, Clbeta 11, EKF Clp 32, Clda 20, Clbeta 18; seed
33: EKF 8.0 -> 7.1, UKF 6.6 -> 6.8 worst, longitudinal unchanged within 0.1). What does
not hold is a strict xfail with the measured numbers.

What limits the lateral FEM (measured with scripts not kept in the repo): the roll gust.
Given JSBSim's own p_turb and r_turb as known inputs, the same FEM puts Clp at -0.494 and
Clda at 0.233 (truth -0.484, 0.229). On data simulated by the model itself (a first-order
p_g) an earlier ad-hoc run put Clp 0.5-2.4 std low (8 seeds), and with JSBSim's p_turb of
this seed 3.3 std low (seeds 32, 33: 1.5, 1.4); benchmarks/lateral_gust_filters_mc.py
(the pipeline's settings, the flight's logged noise levels) finds FEM's Clp unbiased there
(-0.33 empirical std) and within 2 std with this seed's p_turb. Other seeds of this flight: worst lateral FEM derivative 6.4 std (seed 32,
Cnr: the yaw gust) and 2.1 (seed 33).

JSBSim turns its gusts and rotary gusts by the mean-wind azimuth, not the heading, and this
flight turns through 80 deg: part of p_turb is then the pitch gust, and the body v_g is
partly JSBSim's u gust, which r_turb does not follow (corr(r_turb, r_g of the body v_g)
0.75 here, -0.12 on seed 32). With the turbulence in the aircraft's axes ([turbulence]
axes = "aircraft", tests/test_sim_turbulence_axes.py; corr 0.93): lateral FEM seed 31 Clp
5.0, Clda 4.9, Cnp 4.0, Cnda 4.0 (no change), seed 32 worst 3.3 (Cnr; was 6.4), seed 33
2.4; longitudinal FEM seed 31 within 1.8 std and its proof of match q 1.24 deg/s, theta
0.77 deg (4.85, 4.12 now), seed 33 CLde 4.0; EKF longitudinal seed 31 Cmq 3.9, Cmalphadot
5.3. The scenario keeps JSBSim's axes until those are sorted out.

What limits the lateral EKF/UKF is the parameter-in-the-state filter itself
(benchmarks/lateral_gust_filters_mc.py: data the lateral gust model makes on this flight's
inputs, 8 draws). With the model's own first-order roll gust, FEM is honest (empirical /
reported std 0.50-1.47, worst mean |error|/std 1.13) while EKF/UKF put Clp 2.4-2.5 std off
on average (bias 3.7-4 empirical std), the EKF given the true process noise 8.2 (Clbeta);
with JSBSim's p_turb of seed 31 as the gust (a first-order process, time constant 0.42 s,
like the model's) FEM stays within 2 std and EKF/UKF end Clbeta 6.7/4.8 std off.

Larger multisines (all after the measurement-noise change): at 4 deg on every axis every TIC
is below 0.1 (alpha 0.072, beta 0.061, ay 0.060) and the lateral FEM is within 2.6 std, but
the longitudinal FEM's Cm0, Cmde, Cmalphadot go to 3.5-3.9 std (Cmalphadot -8.64 for
-7.27) and EKF/UKF Clp stayed ~31 std (gust state started at 1e-3 rad/s); at [3.5, 3, 3] deg, Clp 3.3 and Cm0/Cmalphadot
3.4/3.7. The scenario keeps 1.5 deg until the longitudinal model holds at the larger
amplitude.
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
            "ekf": {"CLq": 4.84, "CL0": 3.3, "CLde": 3.3, "Cmalphadot": 3.28},
            "ukf": {"CLq": 5.0, "CL0": 3.42, "CLde": 3.51}}


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
    # those measured beyond 3 std have not grown
    assert all(errs[n] <= 1.2 * v for n, v in LONG_OFF[method].items()), errs
    # the moment derivatives, the aim of the multisines, within 3 std (EKF Cmalphadot 3.3)
    assert all(errs[n] <= 3.0 for n in ("Cm0", "Cmq", "Cmde")), errs
    if method == "fem":
        ps = m["parameters"]
        assert {"F_V", "F_alpha", "F_q_gi"} <= set(ps) and ps["F_q_gi"]["estimate"] > 0


@pytest.mark.parametrize("method", [
    "fem", *(pytest.param(m, marks=pytest.mark.xfail(strict=True, reason=(
        "measured (seed 31) CLq 4.8, 5.0, CL0 3.3, 3.4, CLde 3.3, 3.5 std, EKF Cmalphadot 3.3 (EKF, "
        "UKF: process noise fixed at twice the turbulence level, not estimated as in FEM)"))) for m in ("ekf", "ukf"))])
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


@pytest.mark.xfail(strict=True, reason="lateral |error|/std > 3 (seed 31): FEM Clp 4.7 (-0.369 "
                   "for -0.484), Clda 4.7 (0.179 for 0.229), Cnp 3.6, Cnda 3.3; EKF Clp 18.7, "
                   "Clda 10.4, Clbeta 8.0; UKF Clp 6.5, Clda 3.6 (8 passes; the methods' "
                   "cross-check flags the EKF) - the roll derivatives low "
                   "together: the roll gust (p_turb 2.8 deg/s rms, time constant ~0.44 s, "
                   "estimated tau_pg 0.36 s) and the roll response to it are barely separable "
                   "(corr(Clp, F_p_g) 0.94); with JSBSim's p_turb given, Clp -0.494, Clda 0.233; "
                   "EKF/UKF miss Clbeta by 6.7/4.8 std on data their own model makes with that "
                   "p_turb (benchmarks/lateral_gust_filters_mc.py; see the module docstring)")
@pytest.mark.parametrize("method", METHODS)
def test_lateral_all_within_3_std(report, method):
    errs = _errors(report, f"lateral-{method}", LAT)
    assert max(errs.values()) <= 3.0, errs


def test_methods_cross_check_finds_what_the_truth_finds(report):
    """Without the truth, the run's methods check each other (pipeline.validate.
    cross_check_methods): the lateral EKF disagrees with FEM by more than 3 combined std
    (seed 31: CYbeta, CYp, CYda, Clbeta, Clr 3.1-3.2) and with the UKF (Clbeta 4.5, Clp 4.6,
    Clr 4.4), and every pair flagged holds a method that the truth check puts more than 3
    std off (benchmarks/lateral_gust_filters_mc.py: the parameter-in-the-state filters
    are biased on this model even on data it makes itself)."""
    ag = report["agreement"]
    flagged = {(r["parameter"], r["method_a"], r["method_b"])
               for axis in ("longitudinal", "lateral") for r in ag[axis]["table"] if r["flag"]}
    assert {("Clbeta", "lateral-fem", "lateral-ekf"), ("Clp", "lateral-ekf", "lateral-ukf"),
            ("Clbeta", "lateral-ekf", "lateral-ukf")} <= flagged, flagged
    for name, a, b in flagged:
        errs = [report["methods"][k]["parameters"][name]["error_in_std"] for k in (a, b)]
        assert max(abs(e) for e in errs) > 3.0, (name, a, b, errs)
    notes = report["methods"]["lateral-ekf"]["verdict"]["notes"]
    assert any(n.startswith("disagrees with lateral-fem") and "Clbeta" in n for n in notes), notes
    assert any(n.startswith("disagrees with lateral-ukf") and "Clp" in n for n in notes), notes


@pytest.mark.xfail(strict=True, reason="proof of match on the held-out multisine_c fails for "
                   "every method: FEM theta 4.1 deg, q 4.9 deg/s (bands 1.5), p 6.3 deg/s, phi "
                   "6.9 deg - and the TRUE derivatives miss by as much (q 4.9, theta 3.9, p 6.2, "
                   "phi 6.8; benchmarks/pom_floor.py: identified/true 0.96-1.06): the rotary "
                   "turbulence JSBSim adds (2.4-2.8 deg/s rms) is in no air-data channel and "
                   "stays in the predicted rates, so the bands are below what this flight allows "
                   "(with the turbulence in the aircraft's axes the longitudinal part passes: q "
                   "1.24, theta 0.77; p and phi do not)")
@pytest.mark.parametrize("method", METHODS)
def test_proof_of_match(report, method):
    for axis in ("longitudinal", "lateral"):
        pm = report["methods"][f"{axis}-{method}"]["validation"]["proof_of_match"]
        errs = {c: round(d["max_abs_error_display"], 2)
                for c, d in pm["segments"][0]["channels"].items()}
        assert pm["all_pass"], f"{axis} {method}: {errs}"
