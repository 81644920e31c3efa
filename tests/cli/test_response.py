"""``fsid response``: frequency responses with coherence from a log, a transfer-function /
LOES fit, the files it writes, and its refusals."""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.commands.view import rerun_binary

pytest.importorskip("jsbsim")
from _simdata import written  # noqa: E402

LOGS = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "logs"


@pytest.fixture(scope="module")
def flight() -> Path:
    return written("longitudinal_3211_calm") / "flight.mcap"


def test_pitch_response_and_loes_fit_of_a_simulated_flight(flight, tmp_path):
    out = tmp_path / "r"
    args = ["response", str(flight), "--input", "de", "--output", "q", "--output", "az", "--fit", "1/2", "--delay"]
    assert main([*args, "--out", str(out), "--quiet"]) == 0
    doc = json.loads((out / "response.json").read_text())
    assert doc["inputs"] == ["de"] and doc["outputs"] == ["q", "az"] and doc["windows"].startswith("the airborne time")
    q = doc["pairs"]["q/de"]
    coh = np.array(q["coherence"], dtype=float)
    assert np.mean(coh >= 0.6) > 0.7  # a 3-2-1-1 flight: coherent over most of the band
    fit = doc["fits"]["q/de"]
    assert fit["J"] < 100  # CIFER's acceptance
    loes = fit["loes"]
    # the short period of the fit against the data's own peak: |q/de| peaks near omega_sp
    f = np.array(doc["f_hz"])
    peak = f[int(np.nanargmax(np.array(q["magnitude_db"], dtype=float)))]
    assert 0.6 < loes["omega_sp"] / (2 * np.pi * peak) < 1.6 and 0.1 < loes["zeta_sp"] < 1.0
    # the files, readable by others; the recording one rerun accepts
    for name in ("response.csv", "report.md", "report.html", "run.rrd", "figures/bode.png"):
        assert (out / name).is_file() and os.stat(out / name).st_mode & 0o044 == 0o044, name
    head = (out / "response.csv").read_text().splitlines()[0]
    assert head.startswith("f_hz,q/de magnitude_db,q/de phase_deg,q/de coherence,q/de random_error")
    md = (out / "report.md").read_text()
    assert "LOES: omega_sp" in md and doc["run_id"] in md
    verify = subprocess.run([rerun_binary(), "rrd", "verify", str(out / "run.rrd")], capture_output=True, text=True)
    assert verify.returncode == 0, verify.stderr


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--input", "elevator", "--output", "q"], "not a canonical channel"),
        (["--input", "de", "--output", "de"], "both --input and --output"),
        (["--input", "de", "--output", "q", "--delay"], "--delay needs --fit"),
        (["--input", "de", "--output", "q", "--fit", "3/2"], "0 <= M <= N"),
        (["--input", "de", "--output", "q", "--band", "5:1"], "is empty"),
    ],
)
def test_bad_requests_end_in_one_line(flight, tmp_path, capsys, extra, message):
    assert main(["response", str(flight), *extra, "--out", str(tmp_path / "r"), "--quiet"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "Traceback" not in err[0]


def test_a_channel_the_log_lacks_is_named(flight, tmp_path, capsys):
    assert main(["response", str(flight), "--input", "de", "--output", "qdot", "--out", str(tmp_path / "r")]) != 0
    err = capsys.readouterr().err
    assert "qdot not in the log" in err and "--map" in err
    assert "fsid response failed" in (tmp_path / "r" / "error.txt").read_text()


@pytest.mark.skipif(not (LOGS / "ardupilot_quadplane_sitl.tlog").is_file(), reason="shared real logs absent")
def test_a_real_tlog_with_gaps_in_its_grid(tmp_path):
    """A MAVLink telemetry log whose channels skip (the grid has holes): cut into stretches
    at the holes, and a roll response with a coherent band."""
    out = tmp_path / "r"
    log = LOGS / "ardupilot_quadplane_sitl.tlog"
    assert main(["response", str(log), "--input", "da", "--output", "p", "--out", str(out), "--quiet"]) == 0
    doc = json.loads((out / "response.json").read_text())
    assert len(doc["stretches"]) >= 2
    assert np.nanmax(np.array(doc["pairs"]["p/da"]["coherence"], dtype=float)) > 0.6
