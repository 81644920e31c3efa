"""pipeline.validation.validate and pipeline.outputs.report on a real OEM fit of the HFB-320-like example:
proof of match passes on a held-out maneuver and fails for a wrong model; report.json
carries exactly the result's numbers; report.md has the parameter table rows."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

import estimators
from estimators.datasets import longitudinal_example
from pipeline.outputs.method_section import param_rows
from pipeline.outputs.report import write_report
from pipeline.validation import cross_check_methods, json_ready, validate


@pytest.fixture(scope="module")
def fitted():
    ex = longitudinal_example(0, segments=2)
    res = estimators.OutputError(ex.model).fit(ex.segments[:1])
    v = validate(res, held_out=ex.segments[1:], truth=ex.truth)
    return ex, res, v


def _wrong(res):
    """The same result with the pitch derivatives badly off (a deliberately wrong model)."""
    vals = res.values.copy()
    for name, factor in (("Cmalpha", 0.5), ("Cmq", 0.5)):
        vals[res.names.index(name)] *= factor
    return dataclasses.replace(res, values=vals)


def test_good_fit_passes_proof_of_match_on_held_out_segment(fitted):
    ex, res, v = fitted
    pm = v["proof_of_match"]
    assert pm["all_pass"]
    chans = pm["segments"][0]["channels"]
    judged = {c for c, d in chans.items() if d["pass"] is not None}
    assert judged == {"alpha", "theta", "q", "ax", "az"}  # V, qdot have no default band
    assert all(chans[c]["pass"] for c in judged)
    # display units: q in deg/s against the 1.5 deg/s band, az in g against 0.1 g
    assert chans["q"]["unit"] == "deg/s" and chans["q"]["tolerance_display"] == pytest.approx(1.5)
    assert chans["az"]["unit"] == "g" and chans["az"]["tolerance_display"] == pytest.approx(0.1)
    assert v["verdict"]["ok"], v["verdict"]
    assert v["fit"]["tic_ok"] and v["fit"]["max_TIC"] < 0.1
    assert v["plausibility"]["truth"]["all_within"]


def test_wrong_model_fails_proof_of_match(fitted):
    ex, res, _ = fitted
    v = validate(_wrong(res), held_out=ex.segments[1:], truth=ex.truth)
    assert not v["proof_of_match"]["all_pass"]
    assert v["proof_of_match"]["segments"][0]["channels"]["q"]["pass"] is False
    assert not v["verdict"]["ok"]
    assert any("proof of match failed" in r for r in v["verdict"]["reasons"])
    # the frequency check sees it too: the model's response off the data's beyond the
    # bounds and the data's random error where it is judged
    assert v["frequency"]["n_judged"] > 0 and not v["frequency"]["all_pass"], v["frequency"]["table"]
    # inverse simulation: the wrong model needs larger extra elevator to follow the data
    good = fitted[2]["inverse_simulation"]["per_input"]["de"]["ratio"]
    assert v["inverse_simulation"]["per_input"]["de"]["ratio"] > 1.5 * good


def test_validation_contents(fitted):
    ex, res, v = fitted
    json.dumps(json_ready(v), allow_nan=False)  # JSON-ready apart from arrays
    assert "arrays" not in json_ready(v)
    names = set(v["modes"]["table"])
    assert {"short period", "phugoid"} <= names
    sp = v["modes"]["table"]["short period"]
    assert sp["stable"] and 0.1 < sp["zeta"] < 1.0
    # white residuals: the Morelli-Klein correction changes the bounds little
    ratios = [d["ratio"] for d in v["uncertainty"]["per_parameter"].values()]
    assert len(ratios) == len(res.free_names) and all(0.7 < r < 1.3 for r in ratios)
    assert v["residuals"]["all_white"]
    fr = v["frequency"]
    assert fr["inputs"] == ["de"] and fr["n_judged"] > 0
    for key in ("q/de", "qdot/de", "az/de"):  # well-excited, low-noise pairs
        assert fr["table"][key]["pass"], (key, fr["table"][key])
    a = v["arrays"]
    assert a["psd"]["Pxx"].shape == (a["psd"]["f"].size, len(res.outputs))
    assert a["freq"]["H_data"].shape == (a["freq"]["f"].size, len(fr["outputs"]), 1)


def test_apriori_plausibility(fitted):
    ex, res, _ = fitted
    ap = {"Cmq": {"value": -16.0, "std": 2.0}, "Cmalpha": {"value": -0.3, "std": 0.01}}
    v = validate(res, apriori=ap)
    pl = v["plausibility"]["apriori"]
    assert pl["Cmq"]["flag"] is False and pl["Cmalpha"]["flag"] is True
    assert v["verdict"]["level"] == "FAIL" and any("Cmalpha" in r and "a-priori" in r for r in v["verdict"]["reasons"])


def test_report_json_equals_result_numbers(fitted, tmp_path):
    ex, res, v = fitted
    md, js = write_report(tmp_path, {"oem": res}, {"oem": v}, truth=ex.truth, meta={"scenario": "unit test", "seed": 0})
    assert md == tmp_path / "report.md" and js == tmp_path / "report.json"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json", "report.md"]  # no temp files
    rep = json.loads(js.read_text())
    assert rep["schema"] == "fsid-report/1" and rep["meta"]["seed"] == 0
    m = rep["methods"]["oem"]
    assert set(m["parameters"]) == set(res.free_names)
    for name in res.free_names:
        p = m["parameters"][name]
        assert p["estimate"] == float(res.params[name])
        assert p["std"] == float(res.std[name])
        assert p["truth"] == ex.truth[name]
        assert p["error_in_std"] == pytest.approx(abs(res.params[name] - ex.truth[name]) / res.std[name])
        assert p["mk_std"] == pytest.approx(v["uncertainty"]["per_parameter"][name]["mk_std"])
    assert m["det_R"] == res.cost and m["converged"] is True
    # the held derivatives, the alphadot terms among them (default 0)
    assert m["fixed"] == {"CDalpha2": 0.0, "CLalphadot": 0.0, "Cmalphadot": 0.0}
    for o in res.outputs:
        assert m["fit"][o]["TIC"] == v["fit"]["per_output"][o]["TIC"]
        assert m["fit"][o]["RMS"] == pytest.approx(float(np.sqrt(np.mean(res.residuals[0][o] ** 2))))
    assert m["verdict"]["ok"] is True
    assert m["validation"]["proof_of_match"]["all_pass"] is True


def test_report_md_has_table_rows_and_verdict(fitted, tmp_path):
    ex, res, v = fitted
    md, js = write_report(
        tmp_path,
        {"oem": res, "wrong": _wrong(res)},
        {"oem": v, "wrong": validate(_wrong(res), held_out=ex.segments[1:], truth=ex.truth)},
        truth=ex.truth,
    )
    text = md.read_text()
    rep = json.loads(js.read_text())
    for name in res.free_names:
        est, sd = float(res.params[name]), float(res.std[name])
        row = (
            f"| {name} | {est:.6g} | {sd:.4g} | {100 * sd / abs(est):.2f} | "
            f"{ex.truth[name]:.6g} | {abs(est - ex.truth[name]) / sd:.2f} |"
        )
        assert row in text, row
    rows = param_rows(rep["methods"]["oem"], True)
    assert len(rows) == len(res.free_names)
    assert "## OEM (longitudinal)" in text and "**Verdict: PASS**" in text
    # the wrong model misses beyond its prediction's uncertainty and the truth: FAIL
    assert "## WRONG (longitudinal)" in text and "**Verdict: FAIL**" in text
    assert "| oem | PASS | yes |" in text and "| wrong | FAIL | yes |" in text
    assert rep["methods"]["oem"]["verdict"]["level"] == "PASS"
    assert rep["methods"]["wrong"]["verdict"]["level"] == "FAIL"
    assert "| short period |" in text and "Held-out segment **3211-1**: PASS" in text
    assert "| q | deg/s | 1.5 |" in text
    tic_q = v["fit"]["per_output"]["q"]["TIC"]
    assert f"| q | deg/s | {tic_q:.4f} |" in text  # fit table, display unit
    assert "### Inverse simulation" in text and "| de | deg |" in text
    assert "Data preparation" not in text  # no problem notes given


def test_report_shows_how_the_data_were_prepared(fitted, tmp_path):
    ex, res, v = fitted
    notes = ["grid 50 Hz", "control inputs low-passed zero-phase: de 9.5 Hz"]
    md, js = write_report(tmp_path, {"oem": res}, {"oem": {**v, "problem": {"notes": notes}}})
    text = md.read_text()
    assert "Data preparation:\n\n- grid 50 Hz\n- control inputs low-passed zero-phase: de 9.5 Hz\n" in text
    assert json.loads(js.read_text())["methods"]["oem"]["validation"]["problem"]["notes"] == notes


def test_methods_cross_check_flags_the_wrong_model(fitted, tmp_path):
    """Without a truth, the run's methods check each other: the fit of the other maneuver
    (independent data) agrees with the first within 3 combined std; the model with Cmalpha
    and Cmq halved disagrees with both, there and only there."""
    ex, res, v = fitted
    other = estimators.OutputError(ex.model).fit(ex.segments[1:])
    results = {"oem": res, "oem_b": other, "wrong": _wrong(res)}
    vals = {k: validate(r) for k, r in results.items()}
    ag = cross_check_methods(results, vals)
    assert list(ag) == [""] and ag[""]["methods"] == ["oem", "oem_b", "wrong"]
    table = ag[""]["table"]
    assert len(table) == 3 * len(res.free_names)
    z = {(r["parameter"], r["method_a"], r["method_b"]): r["z"] for r in table}
    name = "Cmq"
    assert z[(name, "oem", "oem_b")] == pytest.approx(
        abs(res.params[name] - other.params[name]) / math.hypot(res.std[name], other.std[name])
    )
    assert max(z[(n, "oem", "oem_b")] for n in res.free_names) < 3.0
    flagged = {k for k, d in z.items() if d > 3.0}
    assert flagged == {(n, a, "wrong") for n in ("Cmalpha", "Cmq") for a in ("oem", "oem_b")}
    assert vals["oem"]["agreement"]["flagged"] == {
        "wrong": {
            "Cmalpha": pytest.approx(z[("Cmalpha", "oem", "wrong")]),
            "Cmq": pytest.approx(z[("Cmq", "oem", "wrong")]),
        }
    }
    assert any(
        n.startswith("disagrees with wrong by more than 3 combined std on Cmalpha")
        for n in vals["oem"]["verdict"]["notes"]
    )
    assert set(vals["wrong"]["agreement"]["flagged"]) == {"oem", "oem_b"}
    assert not any("disagrees" in n for n in validate(res)["verdict"]["notes"])
    md, js = write_report(tmp_path, results, vals, agreement=ag)
    text = md.read_text()
    assert "## Method agreement" in text and f"4 of {3 * len(res.free_names)} pairs flagged" in text
    assert f"| Cmq | {res.params['Cmq']:.5g} +- {res.std['Cmq']:.2g} |" in text
    assert json.loads(js.read_text())["agreement"][""]["n_flagged"] == 4
    # one method per axis: nothing to compare
    assert cross_check_methods({"longitudinal-oem": res, "lateral-oem": other}, {}) == {}


def test_report_without_truth_or_validation(fitted, tmp_path):
    ex, res, _ = fitted
    md, js = write_report(tmp_path, {"oem": res}, {})
    rep = json.loads(js.read_text())
    assert rep["truth"] is None
    assert all(p["truth"] is None for p in rep["methods"]["oem"]["parameters"].values())
    assert "truth" not in md.read_text().split("### Parameters")[1].split("\n")[2]
    assert not math.isnan(rep["methods"]["oem"]["det_R"])


def test_report_lists_data_check_findings(fitted, tmp_path):
    ex, res, v = fitted
    checks = json.dumps(
        {
            "summary": {"pass": 3, "warn": 1, "fail": 0},
            "findings": [
                {"status": "pass", "check": "rate", "channel": "q", "message": "ok"},
                {"status": "warn", "check": "excitation", "channel": "da", "message": "aileron barely moves"},
            ],
        }
    )
    md, js = write_report(tmp_path, {"oem": res}, {"oem": v}, checks=checks)
    text = md.read_text()
    assert "## Data checks" in text and "pass: 3, warn: 1, fail: 0" in text
    assert "| warn | excitation | da | aileron barely moves |" in text
    assert "| pass | rate |" not in text
    assert json.loads(js.read_text())["checks"]["summary"]["warn"] == 1


def test_report_lists_check_summaries_per_log(fitted, tmp_path):
    ex, res, v = fitted
    checks = {"flight.bin": {"pass": 9, "warn": 2, "fail": 0}, "flight.mcap": {"pass": 11, "warn": 0, "fail": 0}}
    md, _ = write_report(tmp_path, {"oem": res}, {"oem": v}, checks=checks)
    text = md.read_text()
    assert "- flight.bin: pass: 9, warn: 2, fail: 0" in text
    assert "- flight.mcap: pass: 11, warn: 0, fail: 0" in text


def test_inverse_simulation_on_log_times(fitted):
    """Times like a log's (t0 = 0.03 s) once made scipy's dlsim return one sample short."""
    ex, res, v = fitted
    seg = ex.segments[0]
    t = 0.03 + np.arange(seg.t.size) * 0.02
    shifted = dataclasses.replace(res, segments=[estimators.Segment(t=t, u=seg.u, z=seg.z, x0=seg.x0)])
    inv = validate(shifted)["inverse_simulation"]
    assert "error" not in inv
    assert inv["per_input"]["de"]["ratio"] == pytest.approx(
        v["inverse_simulation"]["per_input"]["de"]["ratio"], rel=1e-6
    )


def test_verdict_advises_filter_error_for_output_error_in_turbulence():
    """Output error with coloured residuals and maneuvers that scatter beyond the bound:
    the verdict's notes say to fit filter error too; not for filter error itself, nor
    with white residuals."""
    from pipeline.validation import verdict

    v = {
        "method": "oem",
        "converged": True,
        "residuals": {"all_white": False, "whiteness": {"q": {"white": False}}},
        "uncertainty": {"cluster": {"n_segments": 4, "flag_ratio": 3.0, "flagged": {"Cmq": 5.0}}},
    }
    advice = "fit filter error too (--method fem)"
    assert any(advice in n for n in verdict(v)["notes"])
    assert any(advice in n for n in verdict({**v, "method": "oem-stabilized"})["notes"])
    assert not any(advice in n for n in verdict({**v, "method": "fem"})["notes"])
    white = {**v, "residuals": {"all_white": True, "whiteness": {}}}
    assert not any(advice in n for n in verdict(white)["notes"])
    calm = {**v, "uncertainty": {"cluster": {"n_segments": 4, "flag_ratio": 3.0, "flagged": {}}}}
    assert not any(advice in n for n in verdict(calm)["notes"])


# -- verdict levels (pipeline.validation.verdict.REASON_LEVELS) ------------------------------------------
def _pom(**channels):
    """A proof of match of one held-out segment: channel -> (pass, beyond, std) in display
    units (beyond/std None: no prediction uncertainty)."""
    ch = {
        c: {"pass": ok, "beyond_prediction_display": b, "prediction_std_max_display": sd, "unit": "deg/s"}
        for c, (ok, b, sd) in channels.items()
    }
    return {
        "all_pass": all(ok for ok, _, _ in channels.values()),
        "segments": [{"name": "3211", "channels": ch, "prediction_uncertainty": {"parameters": 3, "k": 2.0}}],
    }


def _clean(method="ekf"):
    """A validation dict with nothing against the fit."""
    return {
        "method": method,
        "converged": True,
        "fit": {"tic_ok": True, "tic_limit": 0.1, "per_output": {"p": {"TIC": 0.03}}},
        "proof_of_match": _pom(p=(True, 0.0, 0.2)),
        "plausibility": {"truth": {"k": 3.0, "all_within": True, "per_parameter": {"Clp": {"within": True}}}},
    }


def _disagreeing(other="lateral-fem", method="fem", converged=True):
    return {
        "k": 3.0,
        "flagged": {other: {"Clbeta": 7.7, "Cnda": 7.6}},
        "against": {other: {"method": method, "converged": converged}},
    }


def test_verdict_levels_from_hand_made_validations():
    """PASS when clean; a proof-of-match miss within the prediction's own uncertainty and a
    TIC over the limit are CHECK; a miss beyond it (or with none to weigh it), a truth
    beyond k std and no convergence are FAIL; the level is the worst reason's, ok is PASS."""
    from pipeline.validation import LEVELS, REASON_LEVELS, verdict

    assert LEVELS == ("PASS", "CHECK", "FAIL") and set(REASON_LEVELS.values()) <= set(LEVELS)
    v = verdict(_clean())
    assert v == {"ok": True, "level": "PASS", "reasons": [], "reason_levels": [], "notes": []}

    within = verdict({**_clean(), "proof_of_match": _pom(p=(False, 0.0, 1.9), r=(True, 0.0, 0.1))})
    assert within["level"] == "CHECK" and not within["ok"], within
    assert within["reasons"] == ["proof of match failed on p within 2 std of the prediction's own uncertainty"]
    assert any("too imprecise" in n for n in within["notes"])

    beyond = verdict({**_clean(), "proof_of_match": _pom(p=(False, 0.0, 1.9), r=(False, 0.4, 0.1))})
    assert beyond["level"] == "FAIL" and beyond["reason_levels"] == ["FAIL", "CHECK"], beyond
    assert beyond["reasons"][0] == ("proof of match failed on r beyond 2 std of the prediction's own uncertainty")
    unweighed = verdict({**_clean(), "proof_of_match": _pom(p=(False, None, None))})
    assert unweighed["level"] == "FAIL" and "no prediction uncertainty" in unweighed["reasons"][0]

    tic = {"tic_ok": False, "tic_limit": 0.1, "per_output": {"p": {"TIC": 0.14}}, "tic_noise_floor": []}
    assert verdict({**_clean(), "fit": tic})["level"] == "CHECK"
    truth = {"k": 3.0, "all_within": False, "per_parameter": {"Clp": {"within": False}}}
    v = verdict({**_clean(), "fit": tic, "plausibility": {"truth": truth}})
    assert v["level"] == "FAIL" and v["reason_levels"] == ["CHECK", "FAIL"], v
    assert v["reasons"][1] == "Clp more than 3 std from the truth"
    assert verdict({**_clean(), "converged": False})["level"] == "FAIL"
    assert verdict({"converged": False, "not_settled": "moved"})["reasons"] == [
        "the filter passes did not settle: moved"
    ]


def test_verdict_fails_an_ekf_that_disagrees_with_filter_error():
    """An EKF or UKF more than k combined std from a converged filter-error fit (fem or
    fem-nl) of the same flight: FAIL, naming the parameters and why. Any other pair, and
    filter error's own verdict, keep a note; an unconverged filter error is no reference."""
    from pipeline.validation import FILTER_ERROR_TRUST, verdict

    for method in ("ekf", "ukf", "ukf-aug"):
        for fem in ("fem", "fem-nl"):
            v = verdict({**_clean(method), "agreement": _disagreeing(method=fem)})
            assert v["level"] == "FAIL" and not v["ok"], v
            assert v["reasons"] == [
                "disagrees with filter error (lateral-fem) by more than 3 combined std on "
                f"Clbeta (7.7), Cnda (7.6): {FILTER_ERROR_TRUST}"
            ], v
            assert not any("disagrees" in n for n in v["notes"])
    assert "method to trust in turbulence" in FILTER_ERROR_TRUST
    # without the other's method name, its result key says it
    v = verdict({**_clean("ekf"), "agreement": {"k": 3.0, "flagged": {"fem-nl": {"Clp": 4.0}}}})
    assert v["level"] == "FAIL" and "filter error (fem-nl)" in v["reasons"][0], v
    for val in (
        {**_clean("fem"), "agreement": _disagreeing("lateral-ekf", "ekf")},
        {**_clean("oem"), "agreement": _disagreeing()},
        {**_clean("ekf"), "agreement": _disagreeing("lateral-ukf", "ukf")},
        {**_clean("ekf"), "agreement": _disagreeing(converged=False)},
    ):
        v = verdict(val)
        assert v["level"] == "PASS" and v["reasons"] == [], v
        assert v["notes"][0].startswith("disagrees with lateral-") and "Clbeta (7.7)" in v["notes"][0]


def test_report_shows_fail_for_an_ekf_that_disagrees_with_filter_error(fitted, tmp_path):
    """The run's cross-check on an EKF whose Cmalpha and Cmq are far from filter error's
    (the fit with those halved, labelled EKF): its report.json level and report.md verdict
    are FAIL with the filter-error reason; filter error's own verdict stays PASS with a note."""
    ex, res, v = fitted
    fem = dataclasses.replace(res, method="fem")
    ekf = dataclasses.replace(_wrong(res), method="ekf")
    results = {"longitudinal-fem": fem, "longitudinal-ekf": ekf}
    vals = {k: validate(r) for k, r in results.items()}
    ag = cross_check_methods(results, vals)
    assert vals["longitudinal-ekf"]["agreement"]["against"] == {
        "longitudinal-fem": {"method": "fem", "converged": True}
    }
    md, js = write_report(tmp_path, results, vals, agreement=ag)
    rep = json.loads(js.read_text())
    vd = rep["methods"]["longitudinal-ekf"]["verdict"]
    assert vd["level"] == "FAIL" and vd["ok"] is False, vd
    assert vd["reasons"][0].startswith(
        "disagrees with filter error (longitudinal-fem) by more than 3 combined std on Cmalpha"
    ), vd
    assert rep["methods"]["longitudinal-fem"]["verdict"]["level"] == "PASS"
    text = md.read_text()
    assert "| longitudinal-ekf | FAIL |" in text and "| longitudinal-fem | PASS |" in text
    ekf_md = text[text.index("## LONGITUDINAL-EKF") :]
    assert ekf_md.splitlines()[2].startswith(
        "**Verdict: FAIL** - disagrees with filter error (longitudinal-fem) by more than 3 combined std on Cmalpha"
    ), ekf_md.splitlines()[2]
    assert "filter error is the method to trust in turbulence" in ekf_md.splitlines()[2]


def test_report_md_lists_the_milder_reasons_of_a_fail_apart():
    """A FAIL with CHECK reasons too: the FAIL ones first, the others after 'to check too'.
    A verdict written before the levels (ok only) reads PASS or CHECK."""
    from pipeline.outputs.method_section import _verdict_reasons, verdict_level

    vd = {
        "level": "FAIL",
        "reasons": ["TIC >= 0.1 on p", "Clp more than 3 std from the truth"],
        "reason_levels": ["CHECK", "FAIL"],
    }
    assert _verdict_reasons(vd) == " - Clp more than 3 std from the truth; to check too: TIC >= 0.1 on p"
    assert verdict_level({"ok": True}) == "PASS" and verdict_level({"ok": False}) == "CHECK"
