"""Data-quality checks: each injected defect is found (and only where it is), and
``fsid check`` writes checks.json plus canonical data that re-ingests."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from pipeline.cli import main
from pipeline.conditioning.checks import findings_to_json, run_checks
from pipeline.ingest.flightdata import Channel, FlightData, SegmentSpec
from pipeline.ingest.readers import read_log, read_raw
from pipeline.ingest.readers.synth import demo_dataflash


def _flight() -> FlightData:
    rng = np.random.default_rng(1)
    t = np.arange(0, 20, 0.01)  # 100 Hz
    ch = {
        "p": Channel(t, 0.05 * np.sin(t) + rng.normal(0, 0.01, t.size), "rad/s"),
        "q": Channel(t, np.degrees(0.5 * np.sin(t)), "rad/s"),  # deg/s in a rad/s field
        "r": Channel(t, np.where((t > 5) & (t < 6), np.nan, rng.normal(0, 0.01, t.size)), "rad/s"),
        "ax": Channel(np.delete(t, np.s_[700:900]), rng.normal(0, 0.1, t.size - 200), "m/s^2"),  # 2 s gap
        "ay": Channel(np.r_[t[:1000], t[999:]], rng.normal(0, 0.1, t.size + 1), "m/s^2"),  # duplicate
        "az": Channel(np.r_[t[:1000], t[990:]], rng.normal(-9.8, 0.1, t.size + 10), "m/s^2"),  # backwards
        "V": Channel(t, np.r_[np.full(1000, 25.0), 25 + rng.normal(0, 0.5, t.size - 1000)], "m/s"),  # stuck 10 s
        "alpha": Channel(t, np.clip(rng.normal(0.05, 0.05, t.size), -1, 0.1), "rad"),  # clipped at 0.1
        "phi": Channel(t[::25], rng.normal(0, 0.05, t[::25].size), "rad"),  # 4 Hz
        "de": Channel(t, np.where((t > 2) & (t < 6), np.radians(3) * np.sign(np.sin(4 * t)), 0.0), "rad"),
        "da": Channel(t, np.zeros(t.size), "rad"),
    }
    return FlightData(
        ch,
        {"damage": None, "unmapped": {"dr": "no RCOU messages"}},
        [SegmentSpec("man", 1.0, 8.0, "auto", axis="de"), SegmentSpec("short", 10.0, 12.0)],
    )


def _by(fs, check, channel):
    return [f for f in fs if f.check == check and f.channel == channel]


def test_each_defect_is_flagged_where_it_is():
    fs = run_checks(_flight())
    assert _by(fs, "units", "q")[0].status == "fail"
    assert not _by(fs, "units", "p")
    r_nan = _by(fs, "finite", "r")[0]
    assert r_nan.status == "warn" and r_nan.value == pytest.approx(99 / 2000) and r_nan.t0 == pytest.approx(5.01)
    gap = _by(fs, "gaps", "ax")[0]
    assert gap.t0 == pytest.approx(6.99) and gap.value == pytest.approx(2.01)
    assert _by(fs, "duplicate_times", "ay")[0].value == 1
    assert _by(fs, "time_order", "az")[0].status == "fail"
    stuck = _by(fs, "stuck", "V")[0]
    assert stuck.t0 == pytest.approx(0.0) and stuck.value == pytest.approx(9.99)
    assert _by(fs, "saturation", "alpha")[0].message.count("maximum 0.1") == 1
    slow = _by(fs, "rate", "phi")[0]
    assert slow.status == "warn" and slow.value == pytest.approx(4.0, rel=0.01)
    assert _by(fs, "rate", "p")[0].status == "pass"
    assert _by(fs, "missing", "dr")[0].status == "warn"
    # segments: the maneuver segment is excited on de, the short one is too short and idle
    exc = [f for f in fs if f.check == "excitation" and f.status == "pass"]
    assert exc and exc[0].channel == "de" and exc[0].t0 == 1.0
    assert [f.status for f in fs if f.check == "segment_duration"] == ["pass", "warn"]
    assert any(f.check == "excitation" and f.channel == "da" and "never" in f.message for f in fs)
    doc = json.loads(findings_to_json(fs, _flight()))
    assert doc["summary"]["fail"] == 2 and len(doc["findings"]) == len(fs)
    assert doc["source"]["channels"]["phi"]["samples"] == 80


def test_clean_channel_passes_everything():
    t = np.arange(0, 10, 0.01)
    fd = FlightData({"p": Channel(t, 0.1 * np.sin(3 * t), "rad/s")}, {})
    fs = [f for f in run_checks(fd, required=()) if f.channel == "p"]
    assert fs and all(f.status == "pass" for f in fs)


def test_fsid_check_cli_writes_checks_and_canonical_data(tmp_path, capsys):
    log = tmp_path / "demo.bin"
    log.write_bytes(demo_dataflash(n=400, seed=2))
    data = log.read_bytes()
    out = tmp_path / "out"
    assert main(["check", str(log), "--out", str(out), "--no-compat"]) == 0
    assert log.read_bytes() == data  # input untouched
    doc = json.loads((out / "checks.json").read_text())
    assert doc["source"]["format"] == "dataflash" and doc["source"]["map"] == "ardupilot_bin"
    assert doc["source"]["channels"]["p"]["samples"] == 400
    back = read_log(out / "canonical.csv")
    fd = read_log(log)
    ref = fd.resample(50.0, span="union")  # what canonical.csv holds
    assert np.allclose(back["p"].values, ref["p"].to_numpy(), rtol=1e-8, atol=1e-12)
    # seconds from the log's start; where that is on the log's clock stated once, above
    first = float(read_raw(log).tables["IMU[0]"].t[0])  # the log's first sample (1 s after boot)
    assert fd.meta["t0_abs"] == pytest.approx(first, abs=1e-6) and fd.meta["t0_kind"] == "boot"
    assert ref["t"].iloc[0] == 0.0 and np.allclose(back["p"].t, ref["t"].to_numpy())
    table = pd.read_csv(out / "canonical.csv")  # t_abs: the same instants on the log's own clock
    assert list(table.columns[:2]) == ["t", "t_abs"] and np.allclose(table["t_abs"] - table["t"], first, atol=1e-6)
    assert doc["source"]["t0_abs"] == pytest.approx(first)
    stated = f"times are seconds from the log's start; t = 0 is {first:.6f} s on the log's own clock (since boot)"
    assert doc["source"]["start"] == stated
    assert "wrote" in capsys.readouterr().out


def test_fsid_check_bad_input_is_one_line(tmp_path, capsys):
    bad = tmp_path / "x.bin"
    bad.write_bytes(b"\x00" * 100)
    assert main(["check", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("fsid: error:") and "x.bin" in err[0]
