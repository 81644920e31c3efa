"""Memory bounded by the data, not by its timestamps (issue 44, item 1).

One record of an ArduPilot .bin stamped 1e13 us late (a flipped byte does that), a CSV with
one time jump of 1e9 s, and grid rates that are no rates: the work of ``fsid check`` is
bounded by the samples in the log. The peak memory of the damaged log's check, in a child
process under an address-space limit, stays under 3x the clean log's; an absurd rate is
refused with its reason before any work."""

from __future__ import annotations

import os
import resource
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from _dataflash import late_record
from _simdata import flown

from pipeline.cli import main
from pipeline.ingest.flightdata import Channel, FlightData
from pipeline.outputs.writers import write_dataflash

pytestmark = pytest.mark.slow

#: the address space a child may take: far above a clean check, far below the machine
LIMIT = 6 * 2**30


def _peak_rss(args: list[str]) -> tuple[int, float]:
    """(exit code, peak resident memory in MB) of ``fsid args`` in a child process limited
    to LIMIT bytes of address space."""

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))

    code = (
        "import resource, sys\n"
        "from pipeline.cli import main\n"
        "rc = main(sys.argv[1:])\n"
        "print('PEAK', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n"
        "sys.exit(rc)\n"
    )
    p = subprocess.run(
        [sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
        preexec_fn=limit,
        env={**os.environ, "NUMBA_DISABLE_JIT": os.environ.get("NUMBA_DISABLE_JIT", "0")},
        timeout=600,
    )
    peak = [int(line.split()[1]) for line in p.stdout.splitlines() if line.startswith("PEAK")]
    assert peak, (p.returncode, p.stdout[-2000:], p.stderr[-2000:])
    assert "Traceback" not in p.stderr, p.stderr[-3000:]
    return p.returncode, peak[0] / 1024.0


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("hostile_time")
    clean = d / "clean.bin"
    write_dataflash(clean, flown("default"))
    late = d / "late.bin"
    late_record(clean, late)
    return clean, late


def test_one_late_stamp_in_a_bin_keeps_memory_bounded(logs, tmp_path):
    clean, late = logs
    rc0, clean_mb = _peak_rss(["check", str(clean), "--out", str(tmp_path / "clean")])
    rc1, late_mb = _peak_rss(["check", str(late), "--out", str(tmp_path / "late")])
    assert rc0 == 0 and rc1 in (0, 1, 2, 3), (rc0, rc1)
    assert late_mb < 3.0 * clean_mb, (clean_mb, late_mb)
    assert late.read_bytes() != clean.read_bytes()  # the damage is there, and the inputs stay


def test_resample_grid_skips_a_time_jump():
    """A channel pair at 100 Hz for 60 s with one sample 1e9 s later: the grid holds the
    data's samples, not 5e10 rows, and the jump's sample is on it."""
    t = np.arange(6000) / 100.0
    t2 = np.r_[t, 1e9]
    fd = FlightData(
        channels={"q": Channel(t2, np.r_[np.sin(t), 0.5], "rad/s"), "de": Channel(t2, np.r_[np.cos(t), 0.1], "rad")}
    )
    df = fd.resample(50.0)
    assert 3000 <= len(df) < 3100 and df["t"].iloc[-1] == pytest.approx(1e9)
    assert np.all(np.diff(df["t"].to_numpy()[:3000]) == pytest.approx(0.02))
    # the samples near the data are the data's
    np.testing.assert_allclose(df["q"].to_numpy()[:2990], np.interp(df["t"].to_numpy()[:2990], t, np.sin(t)), atol=2e-3)


@pytest.mark.parametrize("rate", ["1e9", "0", "-5", "nan"])
def test_absurd_rates_refused_with_the_reason(logs, tmp_path, capsys, rate):
    clean, _ = logs
    with pytest.raises(SystemExit) as e:  # argparse's usage error, before any work
        main(["check", str(clean), "--rate", rate, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--rate" in err and "not a number above 0" in err, err
    assert not (tmp_path / "out").exists()


def test_csv_with_a_time_jump(tmp_path):
    """A CSV log whose clock jumps 1e9 s once: read and checked within the memory limit."""
    r = flown("default")
    T = r.truth
    df = pd.DataFrame({c: T[c].to_numpy() for c in ("t", "p", "q", "r", "ax", "ay", "az", "de", "da", "dr", "V")})
    df.loc[df.index[len(df) // 2] :, "t"] += 1e9
    path = tmp_path / "jump.csv"
    df.to_csv(path, index=False)
    rc, mb = _peak_rss(["check", str(path), "--out", str(tmp_path / "out")])
    assert rc in (0, 1, 2, 3) and mb < 2000, (rc, mb)


def test_a_full_disk_is_one_line(logs, tmp_path):
    """Writes beyond a file size limit (RLIMIT_FSIZE; SIGXFSZ ignored, so the write fails
    as on a full disk): one line naming the file and what to do, exit 2, no traceback."""
    import signal

    clean, _ = logs

    def small_files():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, 64 * 1024))

    p = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", "check", str(clean), "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        preexec_fn=small_files,
        timeout=600,
    )
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr[-2000:]
    line = [s for s in p.stderr.splitlines() if s.startswith("fsid: error:")]
    assert line and "cannot write" in line[0] and "--out" in line[0], p.stderr
