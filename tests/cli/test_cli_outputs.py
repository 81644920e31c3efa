"""The command line's version flag, and output files others can read."""

from __future__ import annotations

import os
import re
import stat
from importlib import metadata

import pytest

from pipeline.cli import main
from pipeline.paths import atomic_path, atomic_write_text


def test_version_prints_the_installed_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"fsid {metadata.version('fsid')}"


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def test_atomic_files_are_readable_by_others(tmp_path, umask_022):
    text = atomic_write_text(tmp_path / "report.md", "x\n")
    with atomic_path(tmp_path / "run.rrd") as tmp:
        tmp.write_bytes(b"rrd")
    for path in (text, tmp_path / "run.rrd"):
        assert stat.S_IMODE(path.stat().st_mode) == 0o644, oct(path.stat().st_mode)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_atomic_files_follow_a_stricter_umask(tmp_path):
    old = os.umask(0o077)
    try:
        path = atomic_write_text(tmp_path / "private.json", "{}\n")
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600


@pytest.mark.parametrize("command", ["check", "estimate"])
def test_a_directory_given_as_a_log_is_named_so_before_any_output(command, tmp_path, capsys):
    folder = tmp_path / "logs"
    folder.mkdir()
    out = tmp_path / "out"
    assert main([command, str(folder), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is a directory" in err and "not found" not in err, err
    assert not out.exists()
    assert main([command, str(folder / "missing.bin"), "--out", str(out)]) == 2
    assert "not found" in capsys.readouterr().err


def test_a_failed_estimate_leaves_error_txt_in_its_folder(tmp_path, capsys):
    log = tmp_path / "flight.bin"
    log.write_bytes(b"")  # an empty download
    out = tmp_path / "out"
    assert main(["estimate", str(log), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    text = (out / "error.txt").read_text()
    assert text.startswith("fsid estimate failed: ") and "empty" in text, text
    assert err.endswith(text.splitlines()[0].removeprefix("fsid estimate failed: ")), (err, text)
    assert "no other output was written" in text
    assert stat.S_IMODE((out / "error.txt").stat().st_mode) & 0o044 == 0o044


def test_an_error_stands_on_its_own_line_after_an_open_stage(monkeypatch, capsys):
    import sys

    import pipeline.commands.check as check_command
    from pipeline.errors import FsidError
    from pipeline.jobs.progress import Progress

    def failing_stage(args):
        Progress(3, stream=sys.stderr).stage("ingest flight.bin")
        raise FsidError("flight.bin: no IMU channels; give a map")

    monkeypatch.setattr(check_command, "run", failing_stage)
    assert main(["check", "flight.bin"]) == 2
    assert (
        capsys.readouterr().err == "[1/3] ingest flight.bin ...\nfsid: error: flight.bin: no IMU channels; give a map\n"
    )


def test_canonical_csv_keeps_epoch_time_to_the_microsecond(tmp_path):
    import numpy as np
    import pandas as pd

    t = 1.7e9 + np.arange(0.0, 20.0, 0.01)  # an epoch-stamped log at 100 Hz
    p = 0.1 * np.sin(2.0 * (t - t[0]))
    log = tmp_path / "epoch.csv"
    pd.DataFrame({"t": t, "p": p}).to_csv(log, index=False, float_format="%.6f")
    out = tmp_path / "out"
    assert main(["check", str(log), "--out", str(out), "--no-compat"]) == 0
    back = pd.read_csv(out / "canonical.csv")
    assert back["t"].nunique() == len(back) > 1500
    assert np.allclose(np.diff(back["t"]), np.median(np.diff(back["t"])), atol=1e-5)


def test_numpy_runtime_warnings_stay_off_the_command_line(monkeypatch, capsys):
    import numpy as np

    import pipeline.commands.check as check_command

    def noisy(args):
        np.log(np.array([-1.0, 0.0]))  # invalid value, divide by zero
        return 0

    monkeypatch.setattr(check_command, "run", noisy)
    assert main(["check", "x.bin"]) == 0
    assert "Warning" not in capsys.readouterr().err


@pytest.mark.slow
def test_ctrl_c_says_where_it_stopped_and_marks_the_partial_outputs(tmp_path):
    import signal
    import subprocess
    import sys
    import threading
    import time
    from pathlib import Path

    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "pipeline.cli", "run", "scenarios/default.toml", "--out", str(out)],
        cwd=Path(__file__).resolve().parents[2],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    err: list[str] = []
    reader = threading.Thread(target=lambda: err.extend(iter(lambda: proc.stderr.read(1), "")), daemon=True)
    reader.start()
    deadline = time.monotonic() + 120
    while "in JSBSim ..." not in "".join(err) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=60)
    reader.join(timeout=10)
    text = "".join(err)
    assert proc.returncode == 130, text
    last = text.strip().splitlines()[-1]
    assert last.startswith("fsid: interrupted during [2/") and "JSBSim" in last, text
    marker = (out / "INTERRUPTED.txt").read_text()
    assert marker.startswith("fsid run was interrupted (Ctrl-C) during [2/"), marker
    assert not (out / "report.md").exists()


def test_a_refit_inside_a_stage_leaves_where_stopped_to_the_job(capsys):
    import io

    from pipeline.jobs.progress import Progress, quiet_progress, where_stopped

    job = Progress(4, stream=io.StringIO())
    job.stage("fit oem on longitudinal")
    refit = quiet_progress()
    refit.stage("refit")
    refit.done()
    assert where_stopped() == "during [1/4] fit oem on longitudinal"
    job.done()
    assert where_stopped() == "after [1/4] fit oem on longitudinal"


@pytest.mark.slow
def test_fsid_run_counts_its_stages_once(tmp_path, capsys):
    """One progress count for the flight and the estimate job: the total never changes
    and the stages run 1..N."""
    assert main(["run", "longitudinal_3211_calm", "--out", str(tmp_path / "run")]) == 0
    counts = re.findall(r"^\[(\d+)/(\d+)\]", capsys.readouterr().err, flags=re.M)
    totals = {int(n) for _, n in counts}
    assert len(totals) == 1, totals
    assert [int(k) for k, _ in counts] == list(range(1, totals.pop() + 1))
