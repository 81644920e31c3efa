"""``fsid live``: identification while flying, on a simulated flight's MAVLink telemetry
(pipeline.outputs.writers.tlog) - replayed from a .tlog, and sent over a real UDP socket on
localhost with 5 % of the packets dropped and the autopilot's time stamps jittered. The
replay's estimates are the truth's within their std; the stream's end where the whole-record
frequency-domain regression (estimators.FourierRegression) on the received samples is, to
1e-9; everything received is in received.tlog; the outputs are written. The stream is sent
at twice real time: the ingest places a telemetry log's samples on the autopilot's stamps
checked against the receive clock, which a much faster replay would not follow."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("jsbsim")

from _simdata import flown  # noqa: E402

from estimators import FourierRegression  # noqa: E402
from pipeline.ingest.aircraft import aircraft_for_log  # noqa: E402
from pipeline.ingest.readers import read_log  # noqa: E402
from pipeline.methods.live_equations import EQUATIONS, N_FREQUENCIES, equation_rows, rate_times, regression_constants  # noqa: E402
from pipeline.outputs.writers import write_truth_json  # noqa: E402
from pipeline.outputs.writers.tlog import tlog_packets, write_tlog  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TRUTH = {"Cmalpha": -0.38, "Cmq": -3.6, "Cmde": -0.5, "CLalpha": 3.45, "CLde": 0.36}


@pytest.fixture(scope="module")
def flight():
    return flown("longitudinal_3211_calm")


@pytest.fixture(scope="module")
def aircraft(tmp_path_factory):
    """uav_small with the scenario's sensor positions (an owner's aircraft file)."""
    p = tmp_path_factory.mktemp("ac") / "uav_small.toml"
    text = (ROOT / "scenarios" / "aircraft" / "uav_small.toml").read_text()
    p.write_text(
        text + "\n[sensors.airdata]\nposition_m = [0.80, 0.0, 0.0]\n[sensors.imu]\nposition_m = [0.10, 0.0, 0.02]\n"
    )
    return p


@pytest.mark.slow
def test_replay_estimates_hold_the_truth(flight, aircraft, tmp_path):
    from pipeline.cli import main

    log = tmp_path / "flight.tlog"
    write_tlog(log, flight)
    write_truth_json(tmp_path / "truth.json", flight)
    out = tmp_path / "live"
    assert main(["live", "--replay", str(log), "--speed", "max", "--quiet", "--out", str(out)]) == 0
    doc = json.loads((out / "live.json").read_text())
    assert doc["stopped"] == "end of the replay" and doc["duration_s"] == pytest.approx(75.0, abs=0.1)
    est = {p: v for d in doc["final"].values() for p, v in d.items()}
    assert set(doc["final"]) == {"Cm", "CL"}  # no lateral excitation: no lateral estimate
    for p, v in TRUTH.items():
        assert abs(est[p]["value"] - v) < 3 * est[p]["std"], (p, est[p], v)
    assert np.isfinite(est["Cmalpha"]["enough"]) and est["Cmalpha"]["enough"] < 20.0
    hist = (out / "live.csv").read_text().splitlines()
    assert hist[0] == "t,equation,parameter,value,std" and len(hist) > 70 * 8  # every second of flight
    for name in ("live.json", "live.csv", "report.md", "report.html", "live.rrd"):
        assert os.stat(out / name).st_mode & 0o044 == 0o044, name


def _jittered(packets, rng, drop=0.05, jitter_us=3000):
    """The packets less ``drop`` of them (not the parameters), the autopilot's stamps of the
    rest moved by up to +-``jitter_us`` (re-encoded, CRC and all)."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import ardupilotmega as mav

    enc = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    dec = mav.MAVLink(None)
    out = []
    for t, b in packets:
        msg = dec.parse_buffer(b)[0]
        if msg.get_type() != "PARAM_VALUE" and rng.random() < drop:
            continue
        if hasattr(msg, "time_usec"):
            msg.time_usec = max(0, msg.time_usec + int(rng.integers(-jitter_us, jitter_us)))
        out.append((t, msg.pack(enc)))
    return out


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_a_udp_stream_ends_where_the_whole_record_regression_is(flight, aircraft, tmp_path):
    # the first 30 s (two elevator 3-2-1-1s), sent at twice real time
    packets = [p for p in _jittered(tlog_packets(flight), np.random.default_rng(0)) if p[0] <= 30.0]
    port = _free_port()
    out = tmp_path / "live"
    cmd = [sys.executable, "-m", "pipeline.cli", "live", f"udpin:127.0.0.1:{port}", "--aircraft", str(aircraft)]
    proc = subprocess.Popen(
        [*cmd, "--idle", "3", "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT
    )
    try:
        line = proc.stdout.readline()  # "receiving ..." once the socket is open
        assert "receiving" in line, line + proc.stderr.read()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            t0 = time.monotonic()
            for k, (t, b) in enumerate(packets):
                s.sendto(b, ("127.0.0.1", port))
                if k % 50 == 0:
                    lag = t / 2.0 - (time.monotonic() - t0)
                    if lag > 0:
                        time.sleep(lag)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=30)
    assert proc.returncode == 0, stderr
    doc = json.loads((out / "live.json").read_text())
    assert doc["stopped"] == "no packet for 3 s"
    assert doc["packets"] >= 0.9 * len(packets)  # what arrived, all of it kept
    # the whole-record regression on the received samples, row for row
    fd = read_log(out / "received.tlog")
    ac, _, _ = aircraft_for_log(out / "received.tlog", aircraft, fd, required=True, say=lambda s: None)
    c = regression_constants(ac)
    f = np.linspace(0.1, 2.0, N_FREQUENCIES)
    for eq in EQUATIONS[:2]:
        t = rate_times(fd, eq)
        X, y = equation_rows(eq, fd, c, t)
        ok = np.all(np.isfinite(X), axis=1) & np.isfinite(y)
        Xd = pd.DataFrame(X[ok], columns=list(eq.parameters), index=pd.Index(t[ok], name="t"))
        ref = FourierRegression(frequencies=f, detrend="none", response_derivative=eq.derivative).fit(Xd, y[ok])
        got = doc["final"][eq.name]
        for p in eq.parameters:
            assert got[p]["value"] == pytest.approx(float(ref.params[p]), rel=1e-9), (eq.name, p)
    est = {p: v for d in doc["final"].values() for p, v in d.items()}
    for p in ("Cmalpha", "Cmde"):  # dropped and jittered samples: still the truth's
        assert abs(est[p]["value"] - TRUTH[p]) < 3 * est[p]["std"], (p, est[p], TRUTH[p])
    # the lift equation leaves out the thrust, the IMU's offset and the density at altitude
    # (this log has no height): a few per cent, more than its std over 30 s
    assert est["CLalpha"]["value"] == pytest.approx(TRUTH["CLalpha"], rel=0.05)
    assert doc["update_latency_s"] < 1.0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "give a MAVLink SOURCE"),
        (["udpin:127.0.0.1:1", "--replay", "x.tlog"], "one of them"),
        (["notasource", "--aircraft", "a.toml"], "not a MAVLink source"),
        (["udpin:127.0.0.1:1"], "needs --aircraft"),
        (["--replay", "missing.tlog"], "missing.tlog"),
        (["--replay", "x.tlog", "--speed", "fast"], "--speed"),
    ],
)
def test_bad_live_inputs_end_in_one_line(tmp_path, capsys, monkeypatch, args, message):
    from pipeline.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "x.tlog").write_bytes(b"")
    (tmp_path / "a.toml").write_text("")
    assert main(["live", *args, "--out", str(tmp_path / "o")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "Traceback" not in err[0], err
