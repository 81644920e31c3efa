"""Closed loop on multiaxis_multisine_turbulence (issue 6): light aircraft at 67 m/s in light
Tustin turbulence, three simultaneous 3-axis multisines and an elevator sweep, air data on a
wing-tip boom (y = 3 m). scenario -> JSBSim -> flight.mcap/.bin -> ingest -> FEM / EKF / UKF
-> validation on a second, calm-air flight (validation.mcap), truth known; flown once per
module (~25 s with the filter kernels compiled).

The sensor-compatibility stage is skipped (``compat=False``, it takes ~2 min on this
flight): it applies no correction here anyway (air-data residuals 5-6 x their noise level in
the turbulence, so its estimates are not trusted and the data go to estimation as logged).

Both axes are fitted with the multi-axis models (pipeline.problems.multiaxis.multiaxis_problem): each
axis driven by the other axis' measured variables, air data at the boom's (x, y, z), and
for the filters the Dryden gust states - JSBSim's aerodynamics see p - p_turb, q - q_turb
(rotary turbulence 2.8 / 2.4 deg/s rms here), which a model of the gyro rates books on the
derivatives (JSBSim's own Cm regressed on the gyro q: Cmde -0.76, truth -1.122) - with
CLalphadot, Cmalphadot free (truth 1.7, -7.27; FEM 1.81 +- 0.64, -7.83 +- 0.54;
corr(Cmq, Cmalphadot) -0.32, corr(CLq, CLalphadot) -0.16, corr(Cmalpha, Cmalphadot) 0.69),
and the air density along the flight as an input (ISA at the measured altitude: the
phugoid moves it +-1.2 %; with the flight's mean density FEM CD0 was 9.6, CLalpha 3.6 std off).

Now (3 deg multisines, every maneuver of the flight fitted, the proof of match on the
scenario's calm-air [validation_flight] - a 3-axis multisine, an elevator 3211, an aileron
doublet - which the run flies into validation.mcap; seed 31): longitudinal FEM every
derivative within 2.6 std (Cmde; its std the maneuver scatter where that is significantly
beyond the Cramér-Rao bound, pipeline.validation.uncertainty.widen_by_scatter: with the bounds alone
Cmalpha was 3.37 std off), lateral FEM within 2.9 (Cnp); every Theil
coefficient below 0.1; the proof of match passes for FEM and UKF, and for the EKF's
longitudinal model. EKF/UKF: longitudinal Cmalphadot 6.2/5.5, CLq 4.2/4.4, Cmalpha
4.7/4.1, CL0 3.6/3.6 std off; lateral EKF Clbeta 7.7, Cnda 7.6, Cnp 4.2, Clp 3.4 (its
Clp, Clda 28 and 20 filter-P std off, their maneuvers scattering 8.3x and 6.9x that: the
std is the scatter, pipeline.validation.uncertainty.widen_by_scatter), UKF Clp 6.5, Clda 4.5.
Over seeds 31-38 (benchmarks/multiaxis_seeds.py --methods fem): every derivative within 3
reported std on 3/8 seeds (longitudinal) and 5/8 (lateral), 6/8 and 6/8 with the larger
of the reported and the maneuver-scatter std; empirical / reported std up to 3.5
(Cmalphadot), 2.5 (Cmq), 2.1 (Cmalpha) and 1.9 (Cnbeta); |bias| at most 1.03 empirical std.
The history below was measured with 1.5 deg multisines and the last one held out.

The turbulence is in the aircraft's axes ([turbulence] axes = "aircraft", as MIL-F-8785C
defines it above 2000 ft; this flight turns through 80 deg, and in JSBSim's own
wind-azimuth frame part of its pitch gust became roll turbulence). Over seeds 31-38
(benchmarks/multiaxis_seeds.py, FEM worst |error|/std per seed): longitudinal 2.0, 3.6,
4.0, 2.6, 6.0, 3.3, 5.0, 2.8, lateral 2.7, 3.6, 1.8, 2.3, 3.7, 1.6, 5.6, 2.4, and FEM's
empirical / reported std 0.45-3.1 (Cmalphadot 3.1, Cmq 2.0) and 0.65-2.2; in JSBSim's frame
longitudinal 1.7, 8.9, 4.5, 2.2, 4.4, 2.6, 15.8, 1.9, lateral 2.8, 6.6, 1.8, 2.5, 3.4, 1.6,
12.2, 1.9 and 0.81-7.9 (Cmq 7.9, Cmalphadot 7.6) and 0.92-5.2. The EKF and UKF are within
3 std on no seed in either frame.

Measured before this model (wings-level longitudinal model, linear lateral model): FEM
CL0 9.3, Cmde 9.5, Cm0 7.9, CLq 7.0 std off, EKF/UKF Cm0/Cmalpha/Cmde 30-40 std, lateral
FEM Clp 49, Clda 31, Clbeta 30 std, EKF/UKF Clp 330 std. Then (seed 31): longitudinal FEM
every derivative within 2.0 std; EKF/UKF, their passes repeated until the estimates settle
(estimators.EKF passes="auto"), all but Cmalphadot 5.7/5.3, CLq 4.5/4.7, CL0 3.8/4.0, CLde
3.6/3.9, EKF Cmalpha 3.0, UKF Cmde 3.0 within 3; lateral FEM every derivative within 2.7
std (Clp); UKF all but Clp 5.9 within 3 std (8 passes); the EKF flipped Clp's sign in its
6th pass (139 std off at the 8th): the passes stop there and pass 5 is kept, labelled not
settled (Clp 14.9, Clda 7.1, Clbeta 5.6, CYbeta 5.4, CYp 5.2, Clr 5.2, CYda 3.6 std off).

The measured surface positions drive the models low-passed where their noise floor begins
(pipeline.conditioning.input_smoothing; here de 9.5, da 6.0, dr 7.6 Hz): their 0.05 deg noise had
driven the model's roll mode as the aircraft never was, and the lateral FEM had put Clp and
Clda 4.7 std off, both 23 % low (Cnp 3.6, Cnda 3.3), the EKF Clp 18.7, Clda 10.4, Clbeta
8.0, the UKF Clp 6.5, Clda 3.6 (JSBSim's turbulence frame). Ad-hoc, the lateral model
itself driven by JSBSim's own gusts: with the flight's logged surfaces in the simulation
and the fit FEM Clp 1.6-2.1 std (3 noise draws), with the true surfaces in the simulation
and the logged ones in the fit 3.2-3.7. The filters' roll gust starts each segment with its
stationary spread (estimators.EKF state_std default; at 1e-3 rad/s the lateral UKF had Clp
24, the EKF 32, before the input smoothing). What does not hold is a strict xfail with the
measured numbers.

The roll gust (measured with scripts not kept in the repo, before the input smoothing):
given JSBSim's own p_turb and r_turb as known inputs, the same FEM put Clp at -0.494 and
Clda at 0.233 (truth -0.484, 0.229). On data simulated by the model itself (a first-order
p_g) an earlier ad-hoc run put Clp 0.5-2.4 std low (8 seeds), and with JSBSim's p_turb of
this seed 3.3 std low (seeds 32, 33: 1.5, 1.4); benchmarks/lateral_gust_filters_mc.py
(the pipeline's settings, the flight's logged noise levels) finds FEM's Clp unbiased there
(-0.33 empirical std) and within 2 std with this seed's p_turb (all in JSBSim's turbulence
frame).

Neither a better noise model nor a likelihood refinement moves the filters to the truth
(ad hoc, seed 31, scripts not kept). Their estimate is not the optimum of their own
innovation likelihood: a pass with the parameters held, the pipeline's noise, gives FEM's
longitudinal estimate a negative log-likelihood 44 lower than the EKF's own. That optimum
is biased too: on longitudinal_3211_turbulence (seed 1), where the EKF lands within 1.3
std, a Gauss-Newton step on it (finite-difference gradient, the filter's P as the inverse
Hessian) raised the likelihood and would put CLq 5.7 std off (on this flight the same step
overshot: the filter's P is no Hessian there). With Ljung's gain sensitivity (a recursive
prediction-error method) and FEM's F and R, the longitudinal EKF still ends Cmde 6.3 and
Cm0 5.7 of FEM's std off, and the lateral one does not settle. Split into 1-10 s blocks,
the maneuvers scatter as they do whole (the derivatives off: 0.6-2.4x the filter's P, the
EKF's lateral Clp and Clda 5.6-9.2x, as over the 3 maneuvers), so the blocks show no more:
the filters' bias is shared, not a variance.

What limits the lateral EKF/UKF is the parameter-in-the-state filter itself
(benchmarks/lateral_gust_filters_mc.py: data the lateral gust model makes on this flight's
inputs, 8 draws). With the model's own first-order roll gust, FEM is honest (empirical /
reported std 0.50-1.47, worst mean |error|/std 1.13) while EKF/UKF put Clp 2.4-2.5 std off
on average (bias 3.7-4 empirical std), the EKF given the true process noise 8.2 (Clbeta);
with JSBSim's p_turb of seed 31 as the gust (a first-order process, time constant 0.42 s,
like the model's) FEM stays within 2 std and EKF/UKF end Clbeta 6.7/4.8 std off.

Larger multisines (JSBSim's turbulence frame, after the measurement-noise change, before the input smoothing; a
larger input also shrinks the surface noise relative to it): at 4 deg on every axis every TIC
is below 0.1 (alpha 0.072, beta 0.061, ay 0.060) and the lateral FEM is within 2.6 std, but
the longitudinal FEM's Cm0, Cmde, Cmalphadot go to 3.5-3.9 std (Cmalphadot -8.64 for
-7.27) and EKF/UKF Clp stayed ~31 std (gust state started at 1e-3 rad/s); at [3.5, 3, 3] deg, Clp 3.3 and Cm0/Cmalphadot
3.4/3.7. The scenario kept 1.5 deg until the longitudinal model held at the larger
amplitude; in the aircraft's axes and with every maneuver fitted it does as well at 3 deg
as at 1.5 over seeds 31-38 (3/8 seeds within 3 reported std either way, the empirical std
a median 0.65 of the 1.5 deg one), so the scenario flies 3 deg.
"""

import json
import re
from pathlib import Path

import pytest

from pipeline.jobs.scenario import run_scenario
from pipeline.problems.lateral import LAT_FREE
from pipeline.problems.longitudinal import LONG_FREE

SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "multiaxis_multisine_turbulence.toml"
METHODS = ("fem", "ekf", "ukf")
LONG = (*LONG_FREE, "CLalphadot", "Cmalphadot")
LAT = LAT_FREE
#: longitudinal derivatives measured more than 3 std from the truth (|error|/std, seed 31)
LONG_OFF = {"fem": {}, "ekf": {}, "ukf": {}}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("multiaxis")
    run_scenario(SCENARIO, out, methods=list(METHODS), quiet=True, compat=False, figures=False)
    return out


@pytest.fixture(scope="module")
def report(run_dir):
    return json.loads((run_dir / "report.json").read_text())


def test_no_input_dynamics_applied_in_the_gusts(report):
    """The MCAP logs the surfaces' own positions: no delay, no lag. Equation error in this
    flight's gusts is biased (its rates carry the gusts' response): the aileron's delay runs
    to the end of its range (216-228 ms with the range to 250 ms, seeds 31-33, ad hoc), so
    an estimate there is not applied (pipeline.conditioning.input_dynamics.DELAY_RANGE_S)."""
    dyn = report["meta"]["input_dynamics"]
    assert dyn["status"] == "estimated" and dyn["applied"] == {}
    assert dyn["surfaces"]["da"]["at_bound"], dyn["surfaces"]["da"]


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
    # the moment derivatives, the aim of the multisines, within 3 std (UKF Cmde 3.005)
    assert all(errs[n] <= 3.0 for n in ("Cm0", "Cmq", "Cmde") if n not in LONG_OFF[method]), errs
    if method == "fem":
        ps = m["parameters"]
        assert {"F_V", "F_alpha", "F_q_gi"} <= set(ps) and ps["F_q_gi"]["estimate"] > 0
        # CLalphadot, Cmalphadot free here: no note that Cmq carries Cmalphadot
        assert not any("Cmq estimates" in n for n in m["validation"]["problem"]["notes"])
        # the 4 fitted maneuvers' scatter (estimators.covariance.cluster, from FEM's own
        # per-maneuver information; seed 31: median 1.76 of the Cramér-Rao bound, largest
        # 3.9 on CLq); where it is beyond an exact bound's 95 % limit (1.61x with 4
        # maneuvers) it is the std (pipeline.validation.uncertainty.widen_by_scatter): CDalpha, CLalpha,
        # CLq, Cmalpha, Cmq, CLalphadot, Cmalphadot 1.8-3.9x. With the Cramér-Rao bounds
        # Cmalpha was 3.37 std off; with these 1.54.
        cl = m["validation"]["uncertainty"]["cluster"]
        assert cl["n_segments"] == 4 and 0.5 < cl["median_ratio"] < 2.5, cl
        assert all(ps[n]["cluster_std"] is not None for n in LONG), {n: ps[n]["cluster_std"] for n in LONG}
        wide = m["validation"]["uncertainty"]["widened"]["parameters"]
        assert m["std_method"] == "crb|scatter" and {"Cmalpha", "Cmq", "CLq"} <= set(wide), wide
        for n, r in wide.items():
            assert ps[n]["std"] == pytest.approx(ps[n]["cluster_std"], rel=1e-6), n
            assert r > m["validation"]["uncertainty"]["widened"]["threshold"]


@pytest.mark.parametrize("method", METHODS)
def test_longitudinal_all_within_3_std(report, method):
    """EKF/UKF with filter error's process noise (twice its F; seed 31: worst Cmde 2.56 /
    2.75 std) instead of twice the Dryden level (Cmalphadot 6.2 / 5.5 std off)."""
    errs = _errors(report, f"longitudinal-{method}", LONG)
    assert max(errs.values()) <= 3.0, errs


def _tic(rep, key):
    return {k: d["TIC"] for k, d in rep["methods"][key]["validation"]["fit"]["per_output"].items()}


@pytest.mark.parametrize("method", METHODS)
def test_tic_below_0_1_every_output(report, method):
    """Theil's coefficient of every output under 0.1 (seed 31, FEM: alpha 0.092, ax 0.062,
    beta 0.080, ay 0.076; 0.090-0.095 on alpha over seeds 31-38). With 1.5 deg multisines
    alpha, beta and ay had 0.13-0.14 for every method: residuals at the sensor noise on
    signals only ~4x the noise."""
    lon, lat = _tic(report, f"longitudinal-{method}"), _tic(report, f"lateral-{method}")
    assert set(lon) == {"V", "alpha", "theta", "q", "ax", "az"}
    assert set(lat) == {"beta", "p", "r", "phi", "ay"}
    assert max({**lon, **lat}.values()) < 0.1, (lon, lat)


#: open (issue 35): the closed loops below were calibrated on the earlier filter error (G as free
#: parameters); with the reference algorithm (R by relaxation, full R, R's uncertainty in the
#: std) they miss, measured 2026-11-27 on seed 31 - kept strict so that a fix shows
REFERENCE_FEM = "filter error as the reference algorithm (issue 35): "


@pytest.mark.xfail(strict=True, reason=REFERENCE_FEM + "lateral CYda 3.48 std off (CYp 2.45)")
def test_lateral_fem_gust_model(report):
    """The lateral FEM with the gust states and the surface inputs smoothed at their noise
    floor: every derivative within 3 std (seed 31: Cnp 2.86, Cnda 2.74; at 1.5 deg
    multisines Clp, Clda had been 4.7 std off without the smoothing, up to 49 without the
    gust states)."""
    m = report["methods"]["lateral-fem"]
    assert m["model"] == "lateral-measured" and m["converged"]
    errs = _errors(report, "lateral-fem", LAT)
    assert max(errs.values()) <= 3.0, errs
    assert 0.05 < m["parameters"]["tau_pg"]["estimate"] < 1.0
    # the report says where the surfaces were smoothed: between their 1.5 Hz multisine band
    # and the 50 Hz of their noise
    note = [n for n in m["validation"]["problem"]["notes"] if n.startswith("control inputs")]
    assert len(note) == 1, m["validation"]["problem"]["notes"]
    corners = dict(re.findall(r"(d[ar]) ([0-9.]+) Hz", note[0]))
    assert set(corners) == {"da", "dr"} and all(3.0 < float(v) < 15.0 for v in corners.values())


@pytest.mark.xfail(
    strict=True,
    reason="lateral |error|/std > 3 (seed 31): EKF Clbeta 7.7, Cnda 7.6, "
    "Cnp 4.2, Clp 3.4 (Clp, Clda with their std the maneuver scatter, 8.3x and 6.9x "
    "the filter's P; 28 and 20 of P's std off; 6 passes); UKF Clp 6.5, Clda 4.5, Cnp "
    "3.7, Cnda 3.6 (8 passes): the parameter-in-the-state "
    "filters miss Clbeta by 6.7/4.8 std on data their own model makes with this "
    "flight's roll gust (benchmarks/lateral_gust_filters_mc.py; see the module "
    "docstring)",
)
@pytest.mark.parametrize("method", ("ekf", "ukf"))
def test_lateral_all_within_3_std(report, method):
    errs = _errors(report, f"lateral-{method}", LAT)
    assert max(errs.values()) <= 3.0, errs


def test_methods_cross_check_finds_what_the_truth_finds(report):
    """Without the truth, the run's methods check each other (pipeline.validation.agreement.
    cross_check_methods): the lateral EKF disagrees with FEM by more than 3 combined std
    (seed 31: on Clbeta and Cnda, 7.7 and 7.6 of its std off the truth), and every pair
    flagged holds a method that the truth check puts more than 3 std off. Its Clp and Clda
    (28 and 20 of its filter-P std off the truth, where its maneuvers scatter 8.3x and 6.9x
    that P: the std is that scatter, pipeline.validation.uncertainty.widen_by_scatter) are within the
    combined std of FEM's and the UKF's; with P they had been flagged too. The UKF's Clp
    (6.5 std off, low like FEM's 2.1) is no disagreement with FEM. On the longitudinal
    axis FEM's std is its maneuver scatter where that is significant (CLq 3.9x its
    Cramér-Rao bound): the EKF's and UKF's CLq (4.2, 4.4 std off the truth) are within the
    combined std of it; with the Cramér-Rao bounds they had been flagged (4.4, 4.7)."""
    ag = report["agreement"]
    flagged = {
        (r["parameter"], r["method_a"], r["method_b"])
        for axis in ("longitudinal", "lateral")
        for r in ag[axis]["table"]
        if r["flag"]
    }
    assert {("Clbeta", "lateral-fem", "lateral-ekf")} <= flagged, flagged
    for name, a, b in flagged:
        errs = [report["methods"][k]["parameters"][name]["error_in_std"] for k in (a, b)]
        assert max(abs(e) for e in errs) > 3.0, (name, a, b, errs)
    # filter error is the method to trust here: the EKF's disagreement is a FAIL reason
    # (test_filters_fail_where_they_disagree_with_filter_error), no longer a note
    reasons = report["methods"]["lateral-ekf"]["verdict"]["reasons"]
    assert any(r.startswith("disagrees with filter error (lateral-fem)") and "Clbeta" in r for r in reasons), reasons
    wide = report["methods"]["lateral-ekf"]["validation"]["uncertainty"]["widened"]["parameters"]
    assert report["methods"]["lateral-ekf"]["std_method"] == "filter-covariance|scatter"
    assert {"Clp", "Clda"} <= set(wide) and min(wide["Clp"], wide["Clda"]) > 4.0, wide


@pytest.mark.parametrize("method", ("ekf", "ukf"))
def test_filters_fail_where_they_disagree_with_filter_error(report, method):
    """The EKF's and UKF's verdicts are FAIL on both axes: in this coloured turbulence their
    white process noise puts them more than 3 std off the truth (the strict xfails above),
    and where they disagree with filter error of the same flight by more than 3 combined
    std the verdict says so and why (pipeline.validation.verdict.REASON_LEVELS, DESIGN.md section 8;
    seed 31: the lateral EKF on Clbeta and Cnda)."""
    from pipeline.validation import FILTER_ERROR_TRUST

    for axis in ("lateral",):
        m = report["methods"][f"{axis}-{method}"]
        vd = m["verdict"]
        assert vd["level"] == "FAIL" and vd["ok"] is False, vd
        assert any(r.endswith("std from the truth") for r in vd["reasons"]), vd
        flagged = (m["validation"]["agreement"]["flagged"]).get(f"{axis}-fem") or {}
        why = [
            (r, lv)
            for r, lv in zip(vd["reasons"], vd["reason_levels"])
            if r.startswith(f"disagrees with filter error ({axis}-fem) by more than 3 combined std")
        ]
        assert len(why) == (1 if flagged else 0), (flagged, vd["reasons"])
        for r, lv in why:
            assert lv == "FAIL" and r.endswith(FILTER_ERROR_TRUST), r
            assert all(f"{n} (" in r for n in flagged), (flagged, r)
        # filter error's own verdict notes the disagreement, it does not fail on it
        fem = report["methods"][f"{axis}-fem"]["verdict"]
        assert not any("filter error" in r for r in fem["reasons"]), fem
    if method == "ekf":
        r = next(
            r
            for r in report["methods"]["lateral-ekf"]["verdict"]["reasons"]
            if r.startswith("disagrees with filter error")
        )
        assert "Clbeta (" in r, r


@pytest.mark.parametrize(
    "key",
    [
        "lateral-ekf",
        *(
            pytest.param(
                k,
                marks=pytest.mark.xfail(
                    strict=True,
                    reason=(
                        "seed 31: within 3 combined std of filter error on every derivative (largest z: "
                        "longitudinal EKF Cmalphadot 2.65, UKF CL0 2.53; lateral UKF tau_pg 1.79, Clp 1.74) "
                        "while 5.5-6.5 std off the truth: sqrt(std_a^2 + std_b^2), conservative for two fits "
                        "of one flight, with FEM's std its maneuver scatter, does not separate them; their "
                        "FAIL is the truth's alone, on a real log they would PASS"
                    ),
                ),
            )
            for k in ("longitudinal-ekf", "longitudinal-ukf", "lateral-ukf")
        ),
    ],
)
def test_filter_error_reason_fails_the_filters_without_the_truth(report, key):
    """Without the truth (a real log) only the disagreement with filter error can fail an
    EKF/UKF whose proof of match passes: each fit's verdict carries it (seed 31: the
    lateral EKF, Clbeta 3.6 and Cnda 3.4 combined std from FEM)."""
    vd = report["methods"][key]["verdict"]
    assert any(
        r.startswith("disagrees with filter error") and lv == "FAIL"
        for r, lv in zip(vd["reasons"], vd["reason_levels"])
    ), vd["reasons"]


@pytest.mark.parametrize(
    "method",
    [
        "fem",
        "ukf",
        pytest.param(
            "ekf",
            marks=pytest.mark.xfail(
                strict=True,
                reason=(
                    "lateral proof of match fails (seed 31): EKF p 2.0 deg/s on the multisine, 3.6 on "
                    "the aileron doublet (band 1.5): its Clp and Clda are 28 and 20 filter-P std off; its "
                    "longitudinal model passes"
                ),
            ),
        ),
    ],
)
def test_proof_of_match_on_the_calm_validation_flight(report, method):
    """The scenario's [validation_flight], in calm air, carries the proof of match (the
    model is fitted to all 4 maneuvers of the turbulent flight): the open-loop simulation,
    every channel judged. In the turbulent flight itself the TRUE derivatives miss a held-
    out multisine by more than the bands (benchmarks/pom_floor.py: q 4.9 deg/s, p 6.2,
    phi 6.8 deg in JSBSim's turbulence frame; FEM in this frame p 9.3, phi 11.1, az 0.19 g):
    the rotary turbulence (2.4-2.8 deg/s rms) is in no air-data channel.
    FEM, seed 31: longitudinal multisine alpha 0.81 deg, q 0.30 deg/s, 3211 alpha 0.62;
    lateral multisine p 0.79 deg/s, aileron doublet p 0.89 (UKF 0.81, 1.41). With the
    flight's multisines at 1.5 deg FEM had p 1.25, 1.49 (UKF 1.66, 1.70), and with a 4 deg,
    1 s doublet (peak roll rate 28 deg/s; this one 18, as in the fitted maneuvers) 2.19."""
    assert report["meta"]["validation flight"].startswith("validation.mcap")
    for axis, n_val in (("longitudinal", 2), ("lateral", 2)):
        m = report["methods"][f"{axis}-{method}"]
        pm = m["validation"]["proof_of_match"]
        assert pm["mode"] == "simulation", pm["mode"]
        assert len(pm["segments"]) == n_val
        assert all(sg["name"].startswith("validation flight: ") for sg in pm["segments"])
        # every channel judged (airspeed has no default band)
        assert all(d["pass"] is not None for sg in pm["segments"] for c, d in sg["channels"].items() if c != "V")
        assert any("every maneuver of this flight fitted" in n for n in m["validation"]["problem"]["notes"])
        errs = {
            sg["name"]: {c: round(d["max_abs_error_display"], 2) for c, d in sg["channels"].items()}
            for sg in pm["segments"]
        }
        assert pm["all_pass"], f"{axis} {method}: {errs}"


@pytest.mark.xfail(
    strict=True,
    reason=REFERENCE_FEM + "longitudinal-fem's first calm-air "
    "segment has no prediction uncertainty (its sensitivity simulation fails)",
)
def test_proof_of_match_failures_are_set_against_the_estimates_uncertainty(report):
    """Every fit's calm-air proof of match has the prediction's own std from its
    derivatives' covariance (filter error's noise parameters left out); the lateral EKF's
    failure on p is noted against it (seed 31: within 2 std on the multisine, 0.14 deg/s
    beyond on the aileron doublet, its std there up to 1.9 deg/s)."""
    for key, m in report["methods"].items():
        free = [
            n
            for n, p in m["parameters"].items()
            if p.get("std") is not None and "[" not in n and not n.startswith(("F_", "G_"))
        ]
        for sg in m["validation"]["proof_of_match"]["segments"]:
            pu = sg["prediction_uncertainty"]
            assert pu["k"] == 2.0 and 0 < pu["parameters"] <= len(free), (key, pu, free)
            assert sg["channels"]["p" if key.startswith("lateral") else "q"]["prediction_std_max_display"] > 0
    notes = [n for n in report["methods"]["lateral-ekf"]["verdict"]["notes"] if n.startswith("proof of match")]
    assert notes and all(" p " in n or n.startswith("proof of match: p ") for n in notes), notes


def _lateral_ls_notes(log: Path, out: Path, *extra: str) -> list[str]:
    from pipeline.cli import main

    assert (
        main(
            [
                "estimate",
                str(log),
                "--model",
                "lateral",
                "--method",
                "ls",
                "--no-compat",
                "--no-figures",
                "--quiet",
                "--out",
                str(out),
                *extra,
            ]
        )
        == 0
    )
    return json.loads((out / "report.json").read_text())["methods"]["ls"]["validation"]["problem"]["notes"]


def test_raw_inputs_keep_the_logged_surfaces(run_dir, tmp_path):
    """``fsid estimate --raw-inputs`` on the written flight: no surface smoothing (the
    default run of the same log lists its corners), the same equation-error estimates
    (the regressions always use the logged surfaces), and the held-out simulation driven
    by other inputs (its error moves)."""
    log = run_dir / "flight.mcap"
    smooth = _lateral_ls_notes(log, tmp_path / "smooth")
    raw = _lateral_ls_notes(log, tmp_path / "raw", "--raw-inputs")
    assert any(n.startswith("control inputs low-passed") for n in smooth), smooth
    assert not any(n.startswith("control inputs") for n in raw), raw
    reps = [json.loads((tmp_path / k / "report.json").read_text())["methods"]["ls"] for k in ("smooth", "raw")]
    est = [{n: p["estimate"] for n, p in r["parameters"].items()} for r in reps]
    assert est[0] == est[1]
    pom = [r["validation"]["proof_of_match"]["segments"][0]["channels"]["p"]["max_abs_error_display"] for r in reps]
    assert pom[0] != pom[1]


def test_estimate_without_the_turbulence_level(run_dir, report, tmp_path):
    """``fsid estimate flight.mcap --method fem --validate-with validation.mcap``: the
    real-log path, where no Dryden level is known. Its gust models start from light
    turbulence at the flight's altitude (pipeline.methods.noise.assumed_turbulence; before, the data
    default left the gust states at 0 and filter error stopped at a singular information
    matrix on the lateral axis, tau_pg); filter error lands where the run's did (which
    started from the scenario's level; ad hoc, from 0.3x and 3x that level too), and its
    models pass the air-data proof of match on the validation flight (seed 31: lateral p
    1.05 deg/s, phi 1.3 deg; longitudinal q 0.68 deg/s, az 0.08 g). The UKF there takes
    filter error's noise model; where it ends beyond 3 std of the truth (5.6 on the lateral
    axis, seed 31) its verdict fails."""
    from pipeline.cli import main

    out = tmp_path / "est"
    assert (
        main(
            [
                "estimate",
                str(run_dir / "flight.mcap"),
                "--method",
                "fem",
                "--method",
                "ukf",
                "--no-compat",
                "--no-figures",
                "--quiet",
                "--validate-with",
                str(run_dir / "validation.mcap"),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    rep = json.loads((out / "report.json").read_text())
    # the UKF takes filter error's noise model: its F (pipeline.methods.noise.filter_process_noise)
    # and the roll gust's time constant held at FEM's estimate (GUST_NOISE_PARAMETERS;
    # with tau_pg free it ended at 0.38 s against FEM's 0.46 and Clp 3.0 std off)
    ukf = rep["methods"]["lateral-ukf"]
    tau = rep["methods"]["lateral-fem"]["parameters"]["tau_pg"]["estimate"]
    assert f"tau_pg = {tau:.4g} held at filter error's estimate" in " ".join(ukf["validation"]["problem"]["notes"])
    # the UKF's bias in multi-axis turbulence is the filter's (decided: FAIL it where it
    # disagrees): a derivative beyond 3 std of the truth fails its verdict
    worst = max(abs(ukf["parameters"][n]["error_in_std"]) for n in LAT)
    assert worst < 3.0 or ukf["validation"]["verdict"]["level"] == "FAIL", (worst, ukf["validation"]["verdict"])
    for axis, names in (("longitudinal", LONG), ("lateral", LAT)):
        m, ran = rep["methods"][f"{axis}-fem"], report["methods"][f"{axis}-fem"]
        assert m["converged"]
        for n in names:
            assert m["parameters"][n]["estimate"] == pytest.approx(
                ran["parameters"][n]["estimate"], abs=0.05 * ran["parameters"][n]["std"]
            ), n
        pm = m["validation"]["proof_of_match"]
        assert pm["mode"] == "air-data" and pm["all_pass"], pm["segments"]
    assert rep["methods"]["lateral-fem"]["parameters"]["F_p_g"]["estimate"] > 0.05
