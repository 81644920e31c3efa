"""``fsid fields``: a log's tables and fields, and what the channel map makes of them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.jobs.fields import list_fields

LOGS = Path(__file__).resolve().parents[3] / "shared" / "data" / "logs"


def _csv(path: Path) -> Path:
    t = np.arange(0.0, 2.0, 0.02)
    rows = ["t,q,de,V,wing_temp"] + [f"{x:.2f},{0.1 * np.sin(x):.5f},{0.02 * x:.4f},25.0,12.5" for x in t]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_canonical_columns_are_mapped_and_others_listed(tmp_path):
    lf = list_fields(_csv(tmp_path / "flight.csv"))
    (table,) = lf.tables
    assert table.samples == 100
    assert table.rate_hz == pytest.approx(50.0)
    assert table.fields["q"] == "q" and table.fields["de"] == "de"
    assert table.fields["wing_temp"] == ""  # no canonical channel of that name
    assert set(lf.filled) == {"q", "de", "V"}
    assert lf.filled["q"][1] == "rad/s"


def test_the_command_prints_json_and_text(tmp_path, capsys):
    log = _csv(tmp_path / "flight.csv")
    assert main(["fields", str(log), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["format"] == "csv" and doc["channels"]["V"]["unit"] == "m/s"
    assert main(["fields", str(log)]) == 0
    out = capsys.readouterr().out
    assert "q -> q" in out and "wing_temp" in out and "canonical channels filled (3)" in out


def test_a_directory_is_refused_with_one_line(tmp_path, capsys):
    assert main(["fields", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err


@pytest.mark.skipif(not (LOGS / "ardupilot_plane_ground_truncated.BIN").is_file(), reason="shared logs absent")
def test_a_real_ardupilot_log_shows_its_sources_and_what_is_missing(capsys):
    lf = list_fields(LOGS / "ardupilot_plane_ground_truncated.BIN")
    imu = next(t for t in lf.tables if t.name.startswith("IMU"))
    assert imu.fields["GyrX"] == "p" and imu.fields["AccZ"] == "az"
    assert imu.rate_hz == pytest.approx(45.1, rel=0.01)  # a 50 Hz logger that dropped samples: 45 a second
    assert "V" in lf.unfilled and "ARSP" in lf.unfilled["V"]
    assert main(["fields", str(LOGS / "ardupilot_plane_ground_truncated.BIN"), "--mapped-only"]) == 0
    out = capsys.readouterr().out
    assert "GyrX -> p" in out and "not filled by the map" in out
