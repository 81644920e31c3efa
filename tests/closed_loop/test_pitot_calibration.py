"""Closed loop: an uncalibrated pitot on a log without vanes (scenario pitot_wind_turn: small
UAV in a steady (3, -4) m/s wind, pitot (1 + 0.03) V + 0.4 m/s, the default maneuvers and a
210 deg turn) -> ``run_scenario`` writes flight.bin -> ``estimate_log`` rebuilds alpha and
beta from the flight path and estimates the pitot's scale factor with the wind
(pipeline.conditioning.flow_angles.airspeed_calibration) -> output error on the calibrated airspeed.

Measured (seed 1): scale factor +4.37 +- 0.04 % (the pitot's 3 % plus its 0.4 m/s bias,
4.2-4.4 % over the flight's 29-34 m/s), wind (3.01, -3.96) m/s; every derivative within
2.3 (longitudinal) and 2.8 std (lateral), both verdicts pass. The same log with the scale
factor taken as 0 (as before; the along-track wind takes the airspeed error, the models'
dynamic pressure keeps it): Cmalpha 46, Cnr 7.8 std off, both verdicts fail. The vanes' run (``fsid run``: flight.mcap, the
compatibility stage estimates the air-data errors) is within 2.5 std.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("jsbsim")
import pipeline.conditioning.flow_angles as flow_angles  # noqa: E402
from pipeline.jobs.estimate import estimate_log  # noqa: E402
from pipeline.jobs.scenario import run_scenario  # noqa: E402

SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "pitot_wind_turn.toml"
#: the pitot's scale factor the airspeed shows: (1.03 V + 0.4) / V - 1 over the flight's
#: true airspeeds, 29-34 m/s (4.18-4.38 %)
EFFECTIVE_SCALE = (0.0415, 0.0440)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("pitot_run")
    run_scenario(SCENARIO, out, methods=["oem"], quiet=True, figures=False)
    return out, json.loads((out / "report.json").read_text())


@pytest.fixture(scope="module")
def estimated(run, tmp_path_factory):
    out = tmp_path_factory.mktemp("pitot_bin")
    estimate_log(run[0] / "flight.bin", out, methods=("oem",), quiet=True, figures=False)
    return json.loads((out / "report.json").read_text()), (out / "report.md").read_text()


def _worst(rep):
    """Largest |error| / std over each method's derivatives."""
    return {
        k: max(
            abs(p["error_in_std"])
            for n, p in m["parameters"].items()
            if p.get("error_in_std") is not None and "[" not in n
        )
        for k, m in rep["methods"].items()
    }


def test_the_turn_calibrates_the_pitot_with_the_wind(estimated):
    rep, md = estimated
    flow = rep["meta"]["flow_angles"]
    cal = flow["airspeed_scale"]
    assert flow["heading_span_deg"] > 180.0
    assert cal["status"] == "estimated" and cal["applied"] and cal["carried"], cal
    assert EFFECTIVE_SCALE[0] < cal["estimate"] < EFFECTIVE_SCALE[1] and cal["std"] < 0.001, cal
    assert abs(flow["wind"]["north_mps"][0] - 3.0) < 0.1 and abs(flow["wind"]["east_mps"][0] + 4.0) < 0.1
    # its std reaches the derivatives with the wind's
    wu = flow["wind_uncertainty"]
    assert "airspeed scale" in wu["parts"] and set(wu["std_airspeed_scale"].values()) == {cal["std"]}
    assert "airspeed scale factor +4." in md and "calibrate the airspeed" not in md


def test_the_calibrated_airspeed_gives_the_derivatives(estimated):
    rep, _ = estimated
    assert set(rep["methods"]) == {"longitudinal-oem", "lateral-oem"}
    worst = _worst(rep)
    assert max(worst.values()) <= 3.0, worst
    assert all(m["verdict"]["ok"] for m in rep["methods"].values()), {
        k: m["verdict"] for k, m in rep["methods"].items()
    }


def test_without_the_calibration_the_pitot_error_breaks_the_fit(run, tmp_path, monkeypatch):
    """The contrast: the scale factor not estimated (its std limit 0), the airspeed error
    goes into the wind and the dynamic pressure."""
    monkeypatch.setattr(flow_angles, "SCALE_STD_MAX", 0.0)
    estimate_log(run[0] / "flight.bin", tmp_path, methods=("oem",), quiet=True, figures=False)
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["meta"]["flow_angles"]["airspeed_scale"]["status"] == "not identifiable"
    worst = _worst(rep)
    assert min(worst.values()) > 5.0, worst
    assert "calibrate the airspeed" in (tmp_path / "report.md").read_text()


def test_the_vanes_run_estimates_the_air_data_errors(run):
    """flight.mcap with vanes: the compatibility stage finds the pitot's error and the
    derivatives hold."""
    out, rep = run
    worst = _worst(rep)
    assert max(worst.values()) <= 3.0, worst
    applied = rep["compatibility"]["applied"]
    assert set(applied) == {"scale_V"}, applied  # the bias carried by the scale factor
    k = applied["scale_V"]  # seed 1: 4.72 +- 0.21 %
    assert EFFECTIVE_SCALE[0] - 3 * k["std"] < k["estimate"] < EFFECTIVE_SCALE[1] + 3 * k["std"], k


def test_fsid_check_of_the_bin_calibrates_the_pitot_and_checks_the_imu(run, tmp_path, capsys):
    """``fsid check flight.bin``: the stages of ``fsid estimate`` - ArduPilot's AOA/SSA (the
    autopilot's estimates) are not taken as vanes: the angles are rebuilt, the pitot's scale
    factor estimated with the wind, and the compatibility reconstruction checks the IMU
    against the calibrated airspeed and the wind held (before, it fitted vane biases and
    scale factors to the autopilot's angles and called scale_V significant)."""
    from pipeline.cli import main

    assert main(["check", str(run[0] / "flight.bin"), "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "checks.json").read_text())
    cal = doc["air_data_angles"]["airspeed_scale"]
    assert cal["applied"] and EFFECTIVE_SCALE[0] < cal["estimate"] < EFFECTIVE_SCALE[1], cal
    comp = doc["compatibility"]
    assert comp["status"] == "ok" and comp["scope"].startswith("IMU errors only") and "airspeed" in comp
    assert not {"bias_V", "scale_V", "bias_alpha", "scale_alpha"} & set(comp["parameters"])
    assert comp["applied"] == {}  # the IMU has no error in this scenario
    assert "airspeed scale factor +4." in capsys.readouterr().out


#: a straight second flight with the same pitot and wind (12 deg of heading: too little to
#: tell its own scale factor from the wind), for the proof of match
VALIDATION_FLIGHT = """
[validation_flight]
duration_s = 40.0

[[validation_flight.maneuver]]
name = "elevator_3211_v"
axis = "de"
shape = "3211"
amplitude_deg = 2.0
pulse_s = 0.3

[[validation_flight.maneuver]]
name = "aileron_doublet_v"
axis = "da"
shape = "doublet"
amplitude_deg = 5.0
pulse_s = 0.5
"""


def test_a_validation_flight_takes_the_fitted_flights_scale_factor(tmp_path, capsys):
    """``fsid estimate flight.bin --validate-with validation.bin``: the same pitot, so the
    validation flight's airspeed is calibrated with the fitted flight's scale factor
    (seed 1: +4.37 %; its own 12 deg of heading could not tell it), and the proof of match
    on it passes (worst derivative 2.7 / 2.0 std, ad hoc)."""
    from pipeline.jobs.simulate import simulate

    text = SCENARIO.read_text().replace('aircraft = "aircraft/', f'aircraft = "{SCENARIO.parent}/aircraft/')
    scen = tmp_path / "pitot_validation.toml"
    scen.write_text(text + VALIDATION_FLIGHT)
    run_dir, _ = simulate(scen, tmp_path / "sim", progress=False)
    out = tmp_path / "est"
    estimate_log(
        run_dir / "flight.bin", out, methods=("oem",), validation_log=run_dir / "validation.bin", figures=False
    )
    rep = json.loads((out / "report.json").read_text())
    cal = rep["meta"]["flow_angles"]["airspeed_scale"]
    assert cal["applied"] and EFFECTIVE_SCALE[0] < cal["estimate"] < EFFECTIVE_SCALE[1], cal
    # the validation flight's air-data-angle stage (its progress line) held that value
    said = capsys.readouterr()
    held = [ln for ln in (said.out + said.err).splitlines() if "(the fitted flight's)" in ln]
    assert len(held) == 1 and f"airspeed scale factor {100 * cal['estimate']:+.2f} %" in held[0], held
    assert "validation.bin" in rep["meta"]["validation flight"]
    for key, m in rep["methods"].items():
        pom = m["validation"]["proof_of_match"]
        assert pom["all_pass"] and all(g["name"].startswith("v") for g in pom["segments"]), (key, pom)
    assert max(_worst(rep).values()) <= 3.0, _worst(rep)
