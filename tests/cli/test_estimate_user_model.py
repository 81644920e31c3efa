"""``fsid estimate LOG --model FILE.py:NAME``: a user model on a simulated log written by the
product's own writers (no mocks), its one-line errors, and where the built-in models get
the aircraft and the sensor positions from (pipeline.ingest.aircraft)."""

import json
import shutil
import textwrap

import pytest

from pipeline.cli import main
from pipeline.errors import FsidError
from pipeline.ingest.aircraft import aircraft_for_log
from pipeline.ingest.readers import read_log

ROOT = __import__("pathlib").Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "scenarios"

pytestmark = pytest.mark.slow
UAV = SCENARIOS / "aircraft" / "uav_small.toml"

#: the linear short-period model of estimators.models.short_period with the vane and IMU
#: positions, written as a user would: a function of the aircraft constants and the log
MODEL_FILE = '''
import numpy as np
from numba.extending import register_jitable      # helpers called from f/g: compiled too
from estimators import Model, Parameter
from estimators.models import short_period
from estimators.models.short_period import DEFAULTS


@register_jitable
def _accels(alpha, q, de, p, c):
    qbar = 0.5 * c.rho * c.V * c.V
    qhat = q * c.cbar / (2.0 * c.V)
    az = -qbar * c.S / c.m * (p.CLalpha * alpha + p.CLq * qhat + p.CLde * (de - p.de0))
    qdot = qbar * c.S * c.cbar / c.Iyy * (p.Cmalpha * alpha + p.Cmq * qhat + p.Cmde * (de - p.de0))
    return az, qdot


def f(x, u, p, c):
    alpha, q = x
    (de,) = u
    az, qdot = _accels(alpha, q, de, p, c)
    return q + az / c.V, qdot


def g(x, u, p, c):
    alpha, q = x
    (de,) = u
    az, qdot = _accels(alpha, q, de, p, c)
    return alpha - q * c.x_vane / c.V, q, az - qdot * c.x_imu   # at the vane / the IMU


def short_period_user(ac, fd):
    h = float(np.nanmean(fd["h"].values))
    rho = 1.225 * (1.0 - 0.0065 * h / 288.15) ** 4.2559              # ISA troposphere
    c = {"m": ac.mass, "Iyy": ac.Iyy, "S": ac.S, "cbar": ac.cbar, "rho": rho,
         "V": float(np.nanmean(fd["V"].values)),
         "x_vane": ac.airdata[0], "x_imu": ac.imu[0]}
    params = [Parameter(n, v, free=n != "CLq") for n, v in DEFAULTS.items()]
    params.append(Parameter("de0", 0.0, per_segment=True))          # trim elevator
    return Model(states=["alpha", "q"], inputs=["de"], outputs=["alpha", "q", "az"],
                 parameters=params, constants=c, f=f, g=g, output_biases=["alpha", "az"],
                 name="short_period_user")


# a Model object whose output qdot no logger records
with_qdot = short_period({"m": 13.5, "Iyy": 1.135, "S": 0.55, "cbar": 0.19, "rho": 1.2, "V": 30.0})
NOT_A_MODEL = 3
'''


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """longitudinal_3211_calm flown once: flight.mcap, flight.bin, truth.json in one folder,
    and the user model file next to it."""
    import sim
    from pipeline.outputs.writers import write_dataflash, write_mcap, write_truth_json

    out = tmp_path_factory.mktemp("sim")
    result = sim.fly(sim.load_scenario(SCENARIOS / "longitudinal_3211_calm.toml"), seed=4, workdir=out / ".jsbsim")
    write_mcap(out / "flight.mcap", result)
    write_dataflash(out / "flight.bin", result, airspeed="eas")
    write_truth_json(out / "truth.json", result)
    (out / "sp_user.py").write_text(MODEL_FILE)
    return out


def _estimate(capsys, *args):
    code = main(["estimate", *map(str, args), "--quiet"])
    return code, capsys.readouterr().err.strip().splitlines()


def test_user_model_output_error_from_the_log(flight, tmp_path, capsys):
    out = tmp_path / "o"
    code, err = _estimate(
        capsys,
        flight / "flight.mcap",
        "--model",
        f"{flight / 'sp_user.py'}:short_period_user",
        "--method",
        "oem",
        "--out",
        out,
    )
    assert code == 0, err
    rep = json.loads((out / "report.json").read_text())
    assert rep["meta"]["model"].endswith("sp_user.py:short_period_user")
    m = rep["methods"]["oem"]
    assert m["converged"]
    p = m["parameters"]
    assert {"CLalpha", "CLde", "Cmalpha", "Cmq", "Cmde", "de0[0]", "bias_az[1]"} <= set(p)
    doc = json.loads((flight / "truth.json").read_text())
    truth = doc["derivatives"]
    assert p["Cmq"]["truth"] == truth["Cmq"]  # truth.json next to the log -> report
    # The linear short-period model leaves out the airspeed and pitch-attitude changes the
    # 3-2-1-1s cause (phugoid onset, gravity): measured on this flight (seed 4) Cmalpha
    # -0.355 (truth -0.38, 7 %), Cmq -4.63 (-3.6, 29 %), Cmde -0.492 (-0.5, 2 %),
    # CLalpha 3.40 (3.45, 1.3 %), with Cramer-Rao std 0.0014 / 0.14 / 0.002 / 0.02, i.e.
    # model error, not noise. Bounds: about 1.5x the measured errors.
    for name, rel in (("CLalpha", 0.05), ("Cmalpha", 0.15), ("Cmq", 0.45), ("Cmde", 0.05)):
        est = p[name]["estimate"]
        assert abs(est / truth[name] - 1) < rel, (name, est, truth[name])
    assert p["de0[0]"]["estimate"] == pytest.approx(doc["trim"]["de"], abs=0.01)
    assert p["bias_az[0]"]["estimate"] == pytest.approx(-9.8, abs=0.1)
    assert (out / "report.md").stat().st_size > 0 and (out / "run.rrd").stat().st_size > 0


@pytest.mark.parametrize(
    "spec, words",
    [
        ("missing.py:short_period_user", ["missing.py", "not found"]),
        ("sp_user.py:nothing_here", ["defines no 'nothing_here'", "short_period_user"]),
        ("sp_user.py:NOT_A_MODEL", ["is a int, not an estimators.Model"]),
        ("sp_user.py:with_qdot", ["output(s) qdot not in the log", "the log has", "alpha"]),
        ("sp_user.py", ["path/to/file.py:name"]),
    ],
)
def test_user_model_errors_are_one_line(flight, tmp_path, capsys, spec, words):
    spec = str(flight / spec)
    code, err = _estimate(capsys, flight / "flight.mcap", "--model", spec, "--out", tmp_path / "o")
    assert code != 0
    assert len(err) == 1 and err[0].startswith("fsid: error:"), err
    for w in words:
        assert w in err[0], (w, err[0])


def test_equation_error_is_refused_for_a_user_model(flight, tmp_path, capsys):
    code, err = _estimate(
        capsys,
        flight / "flight.mcap",
        "--model",
        f"{flight / 'sp_user.py'}:short_period_user",
        "--method",
        "ls",
        "--out",
        tmp_path / "o",
    )
    assert code != 0 and len(err) == 1 and "not available for a user model" in err[0]


def test_builtin_model_needs_an_aircraft_without_truth_json(flight, tmp_path, capsys):
    shutil.copy(flight / "flight.mcap", tmp_path / "flight.mcap")  # no truth.json here
    code, err = _estimate(capsys, tmp_path / "flight.mcap", "--out", tmp_path / "o")
    assert code != 0 and len(err) == 1 and err[0].startswith("fsid: error:")
    assert "--aircraft" in err[0]


def _aircraft(tmp_path, extra=""):
    p = tmp_path / "ac.toml"
    p.write_text(UAV.read_text() + textwrap.dedent(extra))
    return p


def test_sensor_positions_precedence(flight, tmp_path):
    said = []
    # 1. the aircraft TOML's [sensors] table beats truth.json next to the log
    ac_toml = _aircraft(
        tmp_path,
        """
        [sensors.airdata]
        position_m = [1.0, 0.0, 0.05]
        """,
    )
    fd_mcap = read_log(flight / "flight.mcap")
    ac, name, truth = aircraft_for_log(flight / "flight.mcap", ac_toml, fd_mcap, required=True, say=said.append)
    assert name == "uav_small" and truth is not None
    assert ac.airdata == (1.0, 0.0, 0.05)
    assert ac.imu == pytest.approx((0.10, 0.0, 0.02))  # 2. truth.json (sensors.imu)
    # no --aircraft: the aircraft and both positions from truth.json, and it says so
    said.clear()
    ac, _, _ = aircraft_for_log(flight / "flight.mcap", None, fd_mcap, required=True, say=said.append)
    assert ac.airdata == pytest.approx((0.8, 0.0, 0.0)) and ac.mass == 13.5
    assert any("truth.json" in s and "no --aircraft" in s for s in said)
    # 3. a .bin without truth.json: the IMU from ArduPilot's INS_POS1_X/Y/Z, the vane at the CG
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(flight / "flight.bin", alone / "flight.bin")
    fd_bin = read_log(alone / "flight.bin")
    assert fd_bin.params["INS_POS1_X"] == pytest.approx(0.10)
    said.clear()
    ac, _, truth = aircraft_for_log(alone / "flight.bin", UAV, fd_bin, required=True, say=said.append)
    assert truth is None
    assert ac.imu == pytest.approx((0.10, 0.0, 0.02)) and ac.airdata == (0.0, 0.0, 0.0)
    assert any("INS_POS1_X" in s for s in said)
    # 4. nothing known: zeros and a note that the vane is assumed at the CG
    shutil.copy(flight / "flight.mcap", alone / "flight.mcap")
    said.clear()
    ac, _, _ = aircraft_for_log(
        alone / "flight.mcap", UAV, read_log(alone / "flight.mcap"), required=True, say=said.append
    )
    assert ac.airdata == (0.0, 0.0, 0.0) and ac.imu == (0.0, 0.0, 0.0)
    assert any("vane/boom assumed at the CG" in s for s in said)
    # a user model needs no aircraft
    assert aircraft_for_log(alone / "flight.mcap", None, None, required=False) == (None, None, None)


def test_aircraft_sensor_table_is_checked(tmp_path):
    bad = _aircraft(
        tmp_path,
        """
        [sensors.airdata]
        position_m = [1.0, 0.0]
        """,
    )
    with pytest.raises(FsidError, match=r"sensors\.airdata\.position_m: must be \[x, y, z\]"):
        aircraft_for_log(tmp_path / "x.mcap", bad, None, required=True)


def test_proof_of_match_options_reach_the_report(flight, tmp_path, capsys):
    out = tmp_path / "o"
    code, err = _estimate(
        capsys,
        flight / "flight.mcap",
        "--model",
        f"{flight / 'sp_user.py'}:short_period_user",
        "--method",
        "oem",
        "--no-compat",
        "--band-rate",
        "0.05",
        "--band-accel",
        "0.2",
        "--proof-of-match",
        "air-data",
        "--out",
        out,
    )
    assert code == 0, err
    pm = json.loads((out / "report.json").read_text())["methods"]["oem"]["validation"]["proof_of_match"]
    assert pm["mode"] == "air-data" and pm["driven"] == ["alpha"]
    ch = pm["segments"][0]["channels"]
    assert ch["q"]["tolerance_display"] == pytest.approx(0.05)
    assert ch["az"]["tolerance_display"] == pytest.approx(0.2)
    assert ch["alpha"]["pass"] is None and ch["alpha"]["role"] == "drives the filter"
    # no model follows a pitch rate to 0.05 deg/s: the band is applied, not the default
    assert ch["q"]["pass"] is False and not pm["all_pass"]
    assert "Mode **air-data**" in (out / "report.md").read_text()


def test_a_non_positive_band_is_one_line(flight, tmp_path, capsys):
    code, err = _estimate(
        capsys, flight / "flight.mcap", "--model", "longitudinal", "--band-rate", "-1", "--out", tmp_path / "o"
    )
    assert code != 0 and len(err) == 1 and err[0].startswith("fsid: error:")
    assert "band rate_deg_s must be > 0" in err[0]


def test_progress_counts_every_stage_once(flight, tmp_path, capsys):
    """Without --quiet every stage prints '[n/N]': one total from the first line to the
    last (the stage of what the fits held as exact included, whatever the compatibility
    stage applies), n running 1..N."""
    import re

    code = main(
        [
            "estimate",
            str(flight / "flight.mcap"),
            "--model",
            f"{flight / 'sp_user.py'}:short_period_user",
            "--method",
            "oem",
            "--out",
            str(tmp_path / "o"),
        ]
    )
    err = capsys.readouterr().err
    assert code == 0, err
    stages = [(int(a), int(b)) for a, b in re.findall(r"^\[(\d+)/(\d+)\]", err, flags=re.M)]
    assert len(stages) >= 7, err
    assert {b for _, b in stages} == {len(stages)}, err
    assert [a for a, _ in stages] == list(range(1, len(stages) + 1)), err
    assert "uncertainty of what the fits held as exact" in err
    # the estimation stage counts its iterations on its line as they run
    line = next(ln for ln in err.splitlines() if "] estimate " in ln)
    ticks, n = re.search(r"\.\.\.((?: \d+)+) [\d.]+ s - converged in (\d+) iterations?", line).groups()
    assert ticks.split() == [str(k) for k in range(1, int(n) + 1)], line
