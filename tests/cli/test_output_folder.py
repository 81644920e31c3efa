"""One folder, one consistent result; inputs never overwritten; failures said where the
results are (issue 44, items 3-5). The output folder is checked and taken before any work:
a second fsid is refused while the first holds it, an earlier run's files are cleared (its
inputs kept), a log already there is not written over without --force, a run never writes
over its own input, and a failed check leaves error.txt."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest
import rerun.chunk as rc
from _simdata import flown

from pipeline.cli import main
from pipeline.errors import FsidError
from pipeline.outputs.writers import write_dataflash
from pipeline.paths import LOCK, new_run_dir, staged


def test_a_folder_held_by_a_live_fsid_is_refused(tmp_path, capsys):
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (tmp_path / LOCK).write_text(f"{holder.pid} fsid estimate\n")
        assert main(["simulate", "default", "--out", str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert "in use by another fsid (fsid estimate" in err and str(holder.pid) in err, err
        assert not (tmp_path / "flight.bin").exists()
    finally:
        holder.kill()
        holder.wait()
    # its process gone, the lock is stale: taken over
    assert new_run_dir("check", tmp_path) == tmp_path
    assert (tmp_path / LOCK).read_text().split()[0] == str(os.getpid())


def test_an_earlier_runs_files_are_cleared_but_not_the_inputs(tmp_path):
    for name in ("report.md", "report.json", "error.txt", "INTERRUPTED.txt", ".run.rrd.x1y2.tmp", "canonical.csv"):
        (tmp_path / name).write_text("old")
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "a.png").write_bytes(b"x")
    (tmp_path / "flight.bin").write_text("log")
    new_run_dir("estimate", tmp_path, inputs=[tmp_path / "flight.bin"])
    left = sorted(p.name for p in tmp_path.iterdir() if p.name != LOCK)
    assert left == ["flight.bin"], left
    # a run reading canonical.csv as its log: refused, the file kept
    (tmp_path / "canonical.csv").write_text("t,q\n0,0\n")
    with pytest.raises(FsidError, match="would write over this run's input"):
        new_run_dir("check", tmp_path, inputs=[tmp_path / "canonical.csv"])
    assert (tmp_path / "canonical.csv").read_text() == "t,q\n0,0\n"


def test_out_that_is_a_file_or_not_writable(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(FsidError, match="is a file, not a folder"):
        new_run_dir("check", f)
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK):  # root writes anywhere
            pytest.skip("this user can write into a read-only folder")
        with pytest.raises(FsidError, match="cannot write into the output folder"):
            new_run_dir("check", ro)
    finally:
        ro.chmod(0o700)


def test_simulate_does_not_write_over_a_log(tmp_path, capsys):
    (tmp_path / "flight.bin").write_bytes(b"my flight")
    assert main(["simulate", "default", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "already holds flight.bin" in err and "--force" in err, err
    assert (tmp_path / "flight.bin").read_bytes() == b"my flight"


def test_check_refuses_its_own_input_and_records_a_failure(tmp_path, capsys):
    src = tmp_path / "canonical.csv"
    src.write_text("t,q\n0,0\n0.01,0\n")
    assert main(["check", str(src), "--out", str(tmp_path)]) == 2
    assert "would write over this run's input" in capsys.readouterr().err
    assert src.read_text() == "t,q\n0,0\n0.01,0\n"
    # a damaged log: error.txt in the output folder says what failed
    bad = tmp_path / "junk.bin"
    bad.write_bytes(os.urandom(2000))
    out = tmp_path / "out"
    assert main(["check", str(bad), "--out", str(out)]) != 0
    assert (out / "error.txt").exists() and "fsid check failed" in (out / "error.txt").read_text()
    shutil.rmtree(out)


def _check(log, out) -> None:
    assert main(["check", str(log), "--no-compat", "--out", str(out)]) == 0


def test_every_file_of_a_run_carries_its_id(tmp_path, capsys):
    """Two runs into one folder: every file of the second carries the second's id (the
    recording's id too), none of the first's is left, and the folder is unlocked after."""
    log = tmp_path / "flight.bin"
    write_dataflash(log, flown("default"))
    out = tmp_path / "out"
    ids = []
    for _ in range(2):
        _check(log, out)
        rid = json.loads((out / "checks.json").read_text())["run_id"]
        (rec,) = rc.RrdReader(out / "check.rrd").recordings()
        assert rec.recording_id == rid
        ids.append(rid)
    assert ids[0] != ids[1] and ids[1].startswith("check-")
    assert sorted(p.name for p in out.iterdir()) == ["canonical.csv", "check.rrd", "checks.json"]
    capsys.readouterr()


def test_a_set_appears_whole_or_without_its_last_file(tmp_path):
    """staged(): a failure publishes what was written, without the file that says the set
    is whole; a process killed while writing leaves only the hidden folder, which the next
    run removes."""
    with pytest.raises(RuntimeError):
        with staged(tmp_path, "report.json") as stage:
            (stage / "report.md").write_text("partial")
            raise RuntimeError("figure failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.md"]
    with staged(tmp_path, "report.json") as stage:
        for name in ("report.json", "report.md", "run.rrd"):
            (stage / name).write_text("new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json", "report.md", "run.rrd"]
    assert (tmp_path / "report.md").read_text() == "new"
    killed = tmp_path / "killed"
    killed.mkdir()
    code = (
        "import os, sys; from pipeline.paths import staged\n"
        f"with staged({str(killed)!r}, 'report.json') as s:\n"
        "    (s / 'report.md').write_text('x'); (s / 'report.json').write_text('x'); os._exit(9)\n"
    )
    assert subprocess.run([sys.executable, "-c", code]).returncode == 9
    assert [p.name for p in killed.iterdir() if not p.name.startswith(".")] == []  # nothing a reader sees
    assert [p.name for p in killed.iterdir()]  # the hidden folder
    new_run_dir("estimate", killed)
    assert [p.name for p in killed.iterdir()] == [LOCK]
