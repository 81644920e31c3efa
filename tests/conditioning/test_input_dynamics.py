"""The delay and lag between a logged control input and its surface (pipeline.conditioning.input_dynamics).

Hand-computed: the lag's ramp response, cubic reads of a quadratic, a channel moved by
given dynamics. Closed loop: the default scenario flown with a 50 ms first-order servo lag
([actuators] lag_s), its ArduPilot .bin carrying the servo *commands* (RCOU) and its MCAP
the surfaces' positions: from the .bin every surface's lag is found within 3 std of
50 ms and its delay of 0, the MCAP needs nothing; ``fsid estimate`` of the .bin refines
them by output error and with the dynamics applied puts every derivative within 3 std of
the truth and passes the proof of match on both axes, as logged (``--input-dynamics
off``) the longitudinal ones are more than 10 std off (76). A refinement whose fits fail
keeps equation error's values and says why.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.conditioning.input_dynamics import cubic_at, estimate_input_dynamics, lagged, with_input_dynamics
from pipeline.ingest.flightdata import Channel, FlightData

LAG = 0.05


def test_lag_is_exact_on_a_ramp():
    """x' = (u - x) / tau with u = t from rest: x = t - tau (1 - exp(-t / tau))."""
    h, tau = 0.01, 0.05
    t = np.arange(0.0, 1.0, h)
    np.testing.assert_allclose(lagged(t, tau, h), t - tau * (1.0 - np.exp(-t / tau)), atol=1e-12)
    np.testing.assert_array_equal(lagged(t, 0.0, h), t)
    rows = lagged(t, np.array([0.0, tau]), h)  # one lag per row
    assert rows.shape == (2, t.size) and np.allclose(rows[1], lagged(t, tau, h))


def test_cubic_reads_a_quadratic_exactly():
    t = np.arange(0.0, 1.0001, 0.01)
    x = np.linspace(0.013, 0.987, 57)
    np.testing.assert_allclose(cubic_at(3 * t**2 - t + 1, 0.0, 0.01, x), 3 * x**2 - x + 1, atol=1e-12)


def test_a_channel_takes_the_given_delay_and_lag():
    t = np.arange(0.0, 2.0, 0.01)
    step = np.where(t >= 0.5, 0.1, 0.0)
    fd = FlightData({"de": Channel(t, step, "rad", "RCOU.C2"), "q": Channel(t, 0 * t, "rad/s")})
    out = with_input_dynamics(fd, {"de": {"delay_s": 0.03, "lag_s": LAG}})
    np.testing.assert_array_equal(fd["de"].t, t)  # the input is kept
    np.testing.assert_array_equal(fd["de"].values, step)
    np.testing.assert_array_equal(out["de"].t, t)  # the log's time stamps
    assert np.all(out["de"].values[t < 0.52] == 0.0)  # the step 30 ms later
    k = round((0.53 + 5 * LAG) / 0.01)  # 5 tau after it
    assert out["de"].values[k] == pytest.approx(0.1 * (1 - np.exp(-5.0)), abs=2e-3)
    k = round((0.53 + LAG) / 0.01)
    assert out["de"].values[k] == pytest.approx(0.1 * (1 - np.exp(-1.0)), abs=5e-3)
    assert "delay 30.0 ms, lag 50.0 ms" in out["de"].source
    assert with_input_dynamics(fd, {}) is fd


def test_consider_covariance_is_the_applied_part_of_the_joint_one():
    """The refits move the applied surfaces' delays and lags; a lag at its bound 0 has no
    std and is left out; the cross-surface covariance of the joint fit is kept."""
    from pipeline.conditioning.input_dynamics import covariance

    names = ["de delay", "de lag", "da delay", "da lag", "dr delay", "dr lag"]
    sd = np.array([1.0, 2.0, 3.0, 0.0, 5.0, 6.0]) * 1e-3
    corr = np.eye(6)
    corr[0, 2] = corr[2, 0] = 0.5  # de delay ~ da delay
    cov = corr * np.outer(sd, sd)
    doc = {
        "applied": {"da": {"delay_s": 0.01, "lag_s": 0.0}, "de": {"delay_s": 0.0, "lag_s": 0.05}},
        "covariance": {"names": names, "matrix": cov.tolist()},
    }
    got, C, where = covariance(doc)
    assert got == ["da delay", "de delay", "de lag"]
    assert where["da delay"] == ("da", "delay_s") and where["de lag"] == ("de", "lag_s")
    np.testing.assert_allclose(np.sqrt(np.diag(C)), [3e-3, 1e-3, 2e-3])
    assert C[0, 1] == pytest.approx(0.5 * 3e-3 * 1e-3)
    assert covariance({"applied": {}})[0] == []


@pytest.fixture(scope="module")
def lagged_flight(tmp_path_factory):
    """The default scenario with a 50 ms servo lag, written as flight.bin / flight.mcap."""
    pytest.importorskip("jsbsim")
    import sim
    from pipeline.outputs.writers import write_dataflash, write_mcap, write_truth_json
    from tests._simdata import custom, scenario

    raw = dict(scenario("default").raw)
    raw["actuators"] = {"lag_s": LAG}
    res = sim.fly(custom(raw, "default_servo_lag"))
    out = tmp_path_factory.mktemp("servo_lag")
    write_dataflash(out / "flight.bin", res, airspeed="eas")
    write_mcap(out / "flight.mcap", res)
    write_truth_json(out / "truth.json", res)
    return out


@pytest.mark.slow
def test_servo_lag_found_from_the_commands(lagged_flight):
    from pipeline.ingest.readers import read_log

    doc = estimate_input_dynamics(read_log(lagged_flight / "flight.bin"))
    assert set(doc["surfaces"]) == {"de", "da", "dr"} and set(doc["applied"]) == {"de", "da", "dr"}
    for s, d in doc["surfaces"].items():
        assert abs(d["lag_s"] - LAG) <= 3 * d["lag_std"], (s, d)
        assert abs(d["delay_s"]) <= 3 * d["delay_std"], (s, d)
        assert d["lag_std"] < 0.015 and not d["at_bound"], (s, d)
    # the MCAP logs the surfaces' own positions: nothing to apply
    doc = estimate_input_dynamics(read_log(lagged_flight / "flight.mcap"))
    assert doc["applied"] == {}
    assert all(abs(d["equivalent_delay_s"]) < 0.01 for d in doc["surfaces"].values()), doc


def _worst(out, key):
    rep = json.loads((out / "report.json").read_text())
    pars = rep["methods"][key]["parameters"]
    return max(
        abs(p["error_in_std"]) for n, p in pars.items() if p.get("error_in_std") is not None and "[" not in n
    ), rep


@pytest.mark.slow
def test_estimate_applies_the_servo_lag(lagged_flight, tmp_path, capsys):
    from pipeline.cli import main

    log = lagged_flight / "flight.bin"
    base = ["estimate", str(log), "--model", "longitudinal", "--no-compat", "--no-figures", "--quiet"]
    # both axes (the lateral output error holds the longitudinal estimates)
    assert main(base[:2] + base[4:] + ["--out", str(tmp_path / "auto")]) == 0
    for key in ("longitudinal-oem", "lateral-oem"):
        worst, rep = _worst(tmp_path / "auto", key)
        assert worst <= 3.0, (key, worst)
    dyn = rep["meta"]["input_dynamics"]
    assert dyn["status"] == "estimated" and set(dyn["applied"]) == {"de", "da", "dr"}
    # refined by output error: every delay and lag within 3 of their std (1 ms, the floor;
    # output error's own 0.08-0.9 ms) of the truth, the equivalent delays (delay + lag)
    # within 1 ms of 50 (measured 49.95, 49.88, 49.78 ms) and closer than equation error's
    # (51.3, 56.9, 45.5 ms); with them the lateral proof of match passes on p (0.38 deg/s;
    # 2.8 with equation error's, for a band of 1.5)
    assert dyn["refined"]["status"] == "refined", dyn["refined"]
    for s, d in dyn["surfaces"].items():
        r = d["refined"]
        assert abs(r["delay_s"]) <= 3 * r["delay_std"] and abs(r["lag_s"] - LAG) <= 3 * r["lag_std"], (s, r)
        eq = r["delay_s"] + r["lag_s"]
        assert abs(eq - LAG) < 0.001 and abs(eq - LAG) < abs(d["equivalent_delay_s"] - LAG), (s, d)
        assert dyn["applied"][s] == {"delay_s": r["delay_s"], "lag_s": r["lag_s"]}
    for key in ("longitudinal-oem", "lateral-oem"):
        assert rep["methods"][key]["verdict"]["ok"], rep["methods"][key]["verdict"]
    # the lags' std reach the estimates as a consider part (refits with each moved)
    assert set(dyn["uncertainty"]["methods"].values()) == {"propagated"}
    pars = rep["methods"]["longitudinal-oem"]["parameters"]
    assert pars["Cmq"]["consider_std"] > 0
    assert "control-input delay and lag" in (tmp_path / "auto" / "report.md").read_text()
    # the longitudinal model alone sees the elevator only: the aileron and rudder keep
    # equation error's values (and report.md does not call them refined)
    assert main(base + ["--out", str(tmp_path / "lon")]) == 0
    lon = json.loads((tmp_path / "lon" / "report.json").read_text())["meta"]["input_dynamics"]
    assert lon["refined"]["not_seen"] == ["da delay", "da lag", "dr delay", "dr lag"]
    assert "refined" in lon["surfaces"]["de"] and "refined" not in lon["surfaces"]["da"]
    assert lon["applied"]["da"] == {k: lon["surfaces"]["da"][k] for k in ("delay_s", "lag_s")}
    assert main(base + ["--out", str(tmp_path / "off"), "--input-dynamics", "off"]) == 0
    assert _worst(tmp_path / "off", "oem")[0] > 10.0
    # given: the truth's lag on every surface
    assert main(base + ["--out", str(tmp_path / "given"), "--input-dynamics", f"0,{LAG}"]) == 0
    worst, rep = _worst(tmp_path / "given", "oem")
    assert worst <= 3.0 and rep["meta"]["input_dynamics"]["status"] == "given"


def test_a_failed_refinement_keeps_the_equation_error_values():
    from pipeline.conditioning.input_dynamics import refine_by_output_error, summary

    doc = {
        "status": "estimated",
        "applied": {"da": {"delay_s": 0.0, "lag_s": 0.05}},
        "covariance": {"names": ["da delay", "da lag"], "matrix": [[1e-6, 0.0], [0.0, 4e-6]]},
        "surfaces": {
            "da": {
                "delay_s": 0.0,
                "delay_std": 1e-3,
                "lag_s": 0.05,
                "lag_std": 2e-3,
                "equivalent_delay_s": 0.05,
                "equivalent_std": 2e-3,
                "applied": True,
                "at_bound": False,
                "significant": True,
            }
        },
    }

    def fit(dynamics, starts):
        raise np.linalg.LinAlgError("singular information matrix")

    before = json.dumps(doc, sort_keys=True)
    ref = refine_by_output_error(doc, fit)
    assert ref["status"] == "not refined" and "LinAlgError: singular information matrix" in ref["reason"]
    assert ref["fits"] == 1
    doc.pop("refined")
    assert json.dumps(doc, sort_keys=True) == before
    doc["refined"] = ref
    assert "not refined by output error (a fit failed (LinAlgError" in summary(doc)


@pytest.mark.parametrize("value", ["0.02,abc", "2", "0.01,-0.1", "0,0,0"])
def test_bad_setting_is_one_line(value, capsys):
    from pipeline.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["estimate", "missing.bin", "--input-dynamics", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("fsid estimate: error: argument --input-dynamics:") and value in err
