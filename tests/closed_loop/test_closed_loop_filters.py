"""Closed loop of the methods for turbulence and for unstable aircraft through the real-log
path (issue 6): scenario -> JSBSim -> flight.mcap/.bin -> ingest -> estimation -> validation,
truth known. Each scenario is flown once per module.

What is asserted is what was measured to hold; what does not hold is stated, not hidden:

* longitudinal_3211_turbulence, FEM / EKF / UKF: every free derivative within 3 std of the
  truth and the Theil coefficient of each output < 0.1. Proof of match on the held-out
  doublet is NOT met by any model: validation's proof of match simulates the model without
  the gusts, and the flown response to the gusts alone exceeds the bands - the TRUE
  derivatives (x0 and biases fitted) miss by 3.9 deg/s on q (band 1.5), 1.6 deg on theta,
  0.118 g on az. Kept as a strict xfail so that it shows up when validation learns a
  turbulence-aware proof of match.
* unstable_short_period, FEM / EKF / UKF / equation decoupling / stabilised OEM: every
  derivative within 3 std, TIC < 0.1, proof of match (air-data driven: an open-loop
  simulation of a statically unstable model through the SAS-flown surface positions misses
  by 18.6 deg/s on q even with the TRUE derivatives) passes. Decoupling needs the surface
  positions as commanded: with 0.05 deg of surface noise its Cm0/Cmalpha/Cmq/Cmde were
  2.2-3.6 std off. Stabilised OEM and decoupling feed measured outputs back into the model;
  their std carry that measurement noise (estimators.output_error.pseudo_input_noise). With the
  Cramér-Rao bounds stabilised OEM was 5.4 std off on Cmalpha and 5.3 on CDalpha here, and
  over 12 flights its estimates scattered 2.2-7.2x those bounds, 0.8-1.3x the propagated
  std (benchmarks/fed_measurement_std_mc.py). The eigenvalue transformation is exact for
  linear models only (the built-in longitudinal model is nonlinear) and is not among the
  scenario's methods.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import build_parser
from pipeline.jobs.scenario import run_scenario
from pipeline.registry import scenario_methods

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
TURBULENCE_METHODS = ("fem", "ekf", "ukf")
UNSTABLE_METHODS = ("fem", "ekf", "ukf", "decouple", "soem")


def _run(tmp_path_factory, name, methods):
    out = tmp_path_factory.mktemp(name)
    run_scenario(SCENARIOS / f"{name}.toml", out, methods=list(methods), quiet=True, figures=False)
    rep = json.loads((out / "report.json").read_text())
    rep["_out"] = out
    return rep


@pytest.fixture(scope="module")
def turbulence(tmp_path_factory):
    # output error too: the methods' cross-check has to find it out
    return _run(tmp_path_factory, "longitudinal_3211_turbulence", ("oem",) + TURBULENCE_METHODS)


@pytest.fixture(scope="module")
def unstable(tmp_path_factory):
    return _run(tmp_path_factory, "unstable_short_period", UNSTABLE_METHODS)


def _derivatives_within_3_std(rep, method):
    m = rep["methods"][method]
    derivs = {k: v for k, v in m["parameters"].items() if v.get("truth") is not None}
    # the gust model's angle-of-attack-rate derivatives (truth 0 here) when they are free
    alphadot = {"CLalphadot", "Cmalphadot"} & set(derivs)
    assert len(derivs) == 11 + len(alphadot) and len(alphadot) in (0, 2), sorted(derivs)
    errs = {k: round(v["error_in_std"], 2) for k, v in derivs.items()}
    assert all(e <= 3.0 for e in errs.values()), f"{method}: |error|/std per derivative {errs}"
    tic = {k: d["TIC"] for k, d in m["validation"]["fit"]["per_output"].items()}
    assert set(tic) == {"V", "alpha", "theta", "q", "ax", "az"}
    assert max(tic.values()) < 0.1, f"{method}: TIC {tic}"
    return m


@pytest.mark.parametrize("method", TURBULENCE_METHODS)
def test_turbulence_derivatives_within_3_std_and_tic(turbulence, method):
    m = _derivatives_within_3_std(turbulence, method)
    assert turbulence["meta"]["log"] == "flight.mcap"
    # the gust model (rotary gust q_g in the damping terms) although only the elevator moves
    assert m["model"] == "longitudinal-measured"
    if method == "fem":
        assert m["converged"]
        # the process noise is estimated, on the gust-driven states
        assert {"F_V", "F_alpha", "F_q_gi"} <= set(m["parameters"])
        assert m["parameters"]["F_alpha"]["estimate"] > 0
        # with CLalphadot, Cmalphadot free FEM could not separate them from CLq, Cmq on
        # these 3-2-1-1s (CLq -13.4 +- 4.3, CLalphadot 11.8 +- 4.3): held at 0 and said so
        assert "CLalphadot" not in m["parameters"]
        assert any(
            n.startswith("CLalphadot, Cmalphadot held at 0: this flight does not separate them")
            for n in m["validation"]["problem"]["notes"]
        )


def _air_data_proof_of_match(rep, method):
    pm = rep["methods"][method]["validation"]["proof_of_match"]
    assert pm["mode"] == "air-data" and pm["driven"] == ["V", "alpha"]
    chans = pm["segments"][0]["channels"]
    # the driving channels are not judged; every predicted one is
    assert {c for c, d in chans.items() if d["pass"] is None} == {"V", "alpha"}
    errs = {c: round(d["max_abs_error_display"], 2) for c, d in chans.items()}
    assert pm["all_pass"], f"{method}: max abs error per channel {errs}"
    # the filter-driven prediction's own std from the derivatives' covariance (one filter
    # pass per derivative): on the judged channels only, up to 0.23-0.36 deg/s on q (seed 1)
    assert pm["segments"][0]["prediction_uncertainty"]["parameters"] >= 9
    assert all((d["prediction_std_max_display"] is None) == (d["pass"] is None) for d in chans.values())
    assert 0.05 < chans["q"]["prediction_std_max_display"] < 1.5, chans["q"]
    return chans


@pytest.mark.parametrize("method", TURBULENCE_METHODS)
def test_turbulence_proof_of_match(turbulence, method):
    chans = _air_data_proof_of_match(turbulence, method)
    assert set(chans) == {"V", "alpha", "theta", "q", "ax", "az"}


def test_methods_cross_check_singles_out_output_error_in_turbulence(turbulence):
    """Without the truth, the methods check each other (pipeline.validation.agreement.
    cross_check_methods): FEM, EKF and UKF agree within 3 combined std on every derivative,
    and output error, which takes the air as calm, disagrees with each of them - on Cm0,
    Cmq, Cmde, which the truth check puts 10-18 std off (seed of the scenario)."""
    ag = turbulence["agreement"][""]
    assert ag["methods"] == ["oem", *TURBULENCE_METHODS] and ag["odd_one_out"] == "oem"
    flagged = [r for r in ag["table"] if r["flag"]]
    assert flagged and all("oem" in (r["method_a"], r["method_b"]) for r in flagged)
    oem = turbulence["methods"]["oem"]
    assert set(oem["validation"]["agreement"]["flagged"]) == set(TURBULENCE_METHODS)
    assert {"Cm0", "Cmq", "Cmde"} <= set(oem["validation"]["agreement"]["flagged"]["fem"])
    assert all(oem["parameters"][n]["error_in_std"] > 3.0 for n in ("Cm0", "Cmq", "Cmde"))
    assert sum("disagrees with" in n for n in oem["verdict"]["notes"]) == 3


def test_maneuver_scatter_flags_output_error_in_turbulence(turbulence):
    """Without the truth and without a second method: output error's two maneuvers
    disagree far beyond its Cramér-Rao bounds (estimators.covariance.cluster; seed of the
    scenario: CLalpha 6.8x, CL0 6.2x, CLq 5.3x, CLde 4.0x, Cmq 3.0x) and its verdict says
    so; filter error's agree within theirs (largest 2.6x, CDalpha), and so do the EKF's
    (from the information each segment adds to its parameter covariance,
    estimators.filters.parameter_filter). What both maneuvers share (output error's Cm0, Cmde, 13-18 std off
    the truth) no scatter can show: that takes the methods' cross-check."""
    oem = turbulence["methods"]["oem"]["validation"]
    fem = turbulence["methods"]["fem"]["validation"]
    assert oem["uncertainty"]["cluster"]["n_segments"] == 2
    assert {"CLalpha", "CL0", "CLq"} <= set(oem["uncertainty"]["cluster"]["flagged"])
    assert any(n.startswith("the 2 maneuvers scatter more than 3x") for n in oem["verdict"]["notes"])
    assert not fem["uncertainty"]["cluster"]["flagged"], fem["uncertainty"]["cluster"]
    ekf = turbulence["methods"]["ekf"]["validation"]["uncertainty"]["cluster"]
    assert ekf["n_segments"] == 2 and not ekf["flagged"], ekf


def test_filters_on_a_log_take_the_process_noise_from_filter_error(turbulence, tmp_path, capsys):
    """fsid estimate on the same flight.mcap knows no turbulence level: EKF's process noise
    is then twice FEM's maximum-likelihood estimate (pipeline.methods.fitting.filters_process_noise),
    and every derivative stays within 3 std (with the data's default, 0.05 sqrt(var(diff
    z)/h), CLalpha ended 5.3 and Cmalpha 4.5 std off)."""
    from pipeline.jobs.estimate import estimate_log

    out = tmp_path / "est"
    estimate_log(turbulence["_out"] / "flight.mcap", out, methods=["ekf"], compat=False, figures=False)
    assert "process noise for the longitudinal filters from a filter-error fit" in capsys.readouterr().err
    rep = json.loads((out / "report.json").read_text())
    assert "turbulence" not in rep["meta"]
    _derivatives_within_3_std(rep, "ekf")


@pytest.mark.parametrize("method", UNSTABLE_METHODS)
def test_unstable_derivatives_within_3_std_and_tic(unstable, method):
    m = _derivatives_within_3_std(unstable, method)
    assert m["converged"]
    # the identified model is statically unstable, as the truth (Cmalpha > 0)
    assert m["parameters"]["Cmalpha"]["estimate"] > 0


@pytest.mark.parametrize("method", UNSTABLE_METHODS)
def test_unstable_proof_of_match(unstable, method):
    _air_data_proof_of_match(unstable, method)


@pytest.mark.parametrize("method", ["soem", "decouple"])
def test_fed_back_measurements_widen_the_bounds(unstable, method):
    """Stabilised OEM and decoupling report std that carry the measurement noise fed back
    into the model, wider than the white-residual Cramér-Rao bounds where the feedback acts
    (measured on seed 41: soem Cmalpha 4.6x, decouple Cmq 2.2x), and the noise std they
    infer is the simulated sensor noise (vane 0.2 deg, gyro 0.1 deg/s)."""
    m = unstable["methods"][method]
    assert m["converged"], m["message"]
    assert "measurement noise propagated" in m["message"]
    ratio = {k: v["ratio"] for k, v in m["validation"]["uncertainty"]["per_parameter"].items()}
    crb = {k: v["crb_std"] for k, v in m["validation"]["uncertainty"]["per_parameter"].items()}
    std = {k: m["parameters"][k]["std"] for k in crb}
    widened = "Cmalpha" if method == "soem" else "Cmq"
    assert std[widened] > 1.8 * crb[widened], (std, crb, ratio)
    noise = m["noise_std"]
    assert noise["alpha"] == pytest.approx(np.radians(0.2), rel=0.25)
    assert noise["q"] == pytest.approx(np.radians(0.1), rel=0.25)


def test_report_names_how_each_std_was_computed(unstable):
    """report.json's std_method and report.md's std column say what the std is: the
    Cramér-Rao bound, the fed-back noise propagated (soem), the filters' covariance P."""
    ms = unstable["methods"]
    assert ms["soem"]["std_method"] == "propagated" and ms["fem"]["std_method"] == "crb"
    assert ms["ekf"]["std_method"] == ms["ukf"]["std_method"] == "filter-covariance"
    md = (unstable["_out"] / "report.md").read_text()
    for method, label in (("soem", "std (propagated)"), ("fem", "std (CRB)"), ("ekf", "std (filter P)")):
        section = md.split(f"## {method.upper()} (")[1].split("\n## ")[0]
        assert f"| {label} |" in section, (method, section[:600])


def test_methods_that_suit_the_scenario():
    assert scenario_methods({"turbulence": {"model": "off"}}) == ["oem", "ls"]
    assert scenario_methods({"turbulence": {"model": "milspec", "sigma_w": 0.5}}) == ["oem", "fem", "ekf", "ukf"]
    assert scenario_methods({"sas": {"k_alpha": 1.0}, "turbulence": {"model": "off"}}) == [
        "soem",
        "decouple",
        "fem",
        "ekf",
        "ukf",
    ]


def test_command_line_accepts_every_method():
    p = build_parser()
    names = ["oem", "ls", "fem", "ekf", "ukf", "soem", "eigen", "decouple"]
    args = p.parse_args(["run", "s.toml", *sum((["--method", n] for n in names), [])])
    assert args.method == names
    args = p.parse_args(["estimate", "log.bin", "--aircraft", "a.toml", "--method", "ukf"])
    assert args.method == ["ukf"]
    assert p.parse_args(["run", "s.toml"]).method is None  # the scenario decides
