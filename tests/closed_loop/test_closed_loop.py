"""Closed loop through the real-log path: scenario -> JSBSim -> flight.mcap/.bin -> ingest
-> output error -> validation, with the truth known (issue 6, calm air, longitudinal)."""

import json

import pytest

from pipeline.cli import main
from pipeline.jobs.scenario import run_scenario

SCENARIOS = __import__("pathlib").Path(__file__).resolve().parents[2] / "scenarios"


@pytest.fixture(scope="module")
def calm_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("calm")
    paths = run_scenario(SCENARIOS / "longitudinal_3211_calm.toml", out, seed=4, quiet=True)
    return out, paths, json.loads((out / "report.json").read_text())


def test_run_writes_every_output(calm_run):
    out, paths, _ = calm_run
    for name in ("flight.mcap", "flight.bin", "truth.json", "checks.json", "report.md", "report.json", "run.rrd"):
        assert (out / name).stat().st_size > 0, name
    assert set(paths) == {"report.md", "report.html", "report.json", "run.rrd"}
    checks = json.loads((out / "checks.json").read_text())
    assert set(checks) == {"flight.bin", "flight.mcap"}
    assert all(c["summary"]["fail"] == 0 for c in checks.values())


def test_longitudinal_oem_recovers_truth_from_the_log_files(calm_run):
    out, _, rep = calm_run
    assert rep["meta"]["log"] == "flight.mcap"
    m = rep["methods"]["oem"]
    assert m["converged"]
    derivs = {k: v for k, v in m["parameters"].items() if v.get("truth") is not None}
    assert len(derivs) == 11
    worst = {k: round(v["error_in_std"], 2) for k, v in derivs.items() if v["error_in_std"] > 3.0}
    assert not worst, f"derivatives more than 3 std from the truth: {worst}"
    # the bounds are honest, not inflated: well-excited derivatives are tight
    for name in ("CLalpha", "Cmalpha", "Cmq", "Cmde"):
        assert derivs[name]["rel_std_pct"] < 2.0, name
    assert m["verdict"]["ok"], m["verdict"]["reasons"]


def test_validation_on_the_held_out_maneuver(calm_run):
    _, _, rep = calm_run
    v = rep["methods"]["oem"]["validation"]
    assert v["proof_of_match"]["all_pass"]
    assert [s["name"] for s in v["proof_of_match"]["segments"]] == ["auto_de_2"]
    tic = {k: d["TIC"] for k, d in v["fit"]["per_output"].items()}
    assert max(tic.values()) < 0.1, tic
    modes = v["modes"]["table"]
    assert set(modes) == {"short period", "phugoid"}
    sp, ph = modes["short period"], modes["phugoid"]
    assert sp["stable"] and 0.2 < sp["zeta"] < 0.6 and 3.0 < sp["wn"] < 6.0  # rad/s
    assert ph["wn"] < 0.2 * sp["wn"]


def test_estimate_from_the_written_ardupilot_bin(calm_run, tmp_path):
    """The ArduPilot path of the same flight: ``fsid estimate flight.bin``. The .bin has no
    vane (its AOA/SSA are marked derived), so alpha comes from the GPS velocity and the
    attitude (pipeline.conditioning.flow_angles); the elevator is RCOU's whole-microsecond PWM, which
    is what the sim flew (with continuous deflections and RCOU rounding them, Cmde was 4.6
    and CLalpha 4.3 std off on seed 11). The aircraft file states its servo travel, as a
    user's must (without it 30 deg is assumed, with a warning)."""
    out = calm_run[0]
    ac = tmp_path / "uav.toml"
    ac.write_text(
        (SCENARIOS / "aircraft" / "uav_small.toml").read_text()
        + "\n[servos]\nde_travel_deg = 30.0\nda_travel_deg = 30.0\ndr_travel_deg = 30.0\n"
    )
    code = main(
        [
            "estimate",
            str(out / "flight.bin"),
            "--model",
            "longitudinal",
            "--aircraft",
            str(ac),
            "--out",
            str(tmp_path / "bin"),
            "--quiet",
        ]
    )
    assert code == 0
    rep = json.loads((tmp_path / "bin" / "report.json").read_text())
    assert rep["meta"]["servo_travel"]["de"] == {"deg": 30.0, "from": "aircraft TOML [servos] de_travel_deg"}
    assert rep["meta"]["flow_angles"]["status"] == "reconstructed"
    m = rep["methods"]["oem"]
    assert m["converged"]
    errs = {k: round(v["error_in_std"], 2) for k, v in m["parameters"].items() if v.get("truth") is not None}
    assert len(errs) == 11 and max(errs.values()) <= 3.0, errs
    assert m["validation"]["proof_of_match"]["all_pass"]


def test_bad_scenario_is_one_line_and_nonzero(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text((SCENARIOS / "default.toml").read_text().replace("duration_s", "duration_min"))
    code = main(["run", str(bad), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0
    assert len(err) == 1 and "duration" in err[0] and err[0].startswith("fsid: error:")


def test_estimate_on_a_log_without_maneuvers_says_so(tmp_path, capsys):
    log = SCENARIOS.parents[1] / "shared" / "data" / "logs" / "ardupilot_plane_ground_truncated.BIN"
    if not log.exists():
        pytest.skip("shared real logs absent")
    code = main(
        [
            "estimate",
            str(log),
            "--aircraft",
            str(SCENARIOS / "aircraft" / "uav_small.toml"),
            "--out",
            str(tmp_path / "o"),
            "--quiet",
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and err
    # the refusal of pipeline.conditioning.identifiability: a line per reason, on the ground first
    refusal = err[[k for k, line in enumerate(err) if line.startswith("fsid: error:")][0] :]
    assert refusal[0].endswith("can be identified:") and "on the ground" in refusal[1]
    assert "no control-input activity" not in " ".join(refusal)
