"""``fsid batch`` and ``fsid campaign`` on a real Dask cluster: a ``dask scheduler`` and two
``dask worker`` processes on localhost (``--scheduler``), and the default local cluster
(``--workers``). Three simulated logs and a damaged one: each log's report in its folder,
results.parquet with every log exactly once and the damaged one's reason; a rerun skips the
logs done; a worker killed in the middle of a task: the task runs again on the other and
results.parquet still has each log once. A campaign's rows are the same whatever the number
of workers."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

pytest.importorskip("jsbsim")
pytest.importorskip("distributed")

from _simdata import written  # noqa: E402

from pipeline.cli import main  # noqa: E402

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Three simulated flights (their truth.json next to them) and a damaged log."""
    d = tmp_path_factory.mktemp("logs")
    out = []
    for seed in (1, 2, 3):
        src = written("longitudinal_3211_calm", seed)
        (d / f"s{seed}").mkdir()
        for f in ("flight.mcap", "truth.json"):
            shutil.copy(src / f, d / f"s{seed}" / f)
        out.append(d / f"s{seed}" / "flight.mcap")
    bad = d / "damaged.bin"
    bad.write_bytes((written("longitudinal_3211_calm", 1) / "flight.bin").read_bytes()[:30000])
    return [*out, bad]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A dask scheduler and two single-threaded workers, as separate processes."""
    from distributed import Client

    d = tmp_path_factory.mktemp("dask")
    sched_file = d / "scheduler.json"
    procs = [
        subprocess.Popen(
            [
                str(BIN / "dask"),
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                str(sched_file),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    ]
    for _ in range(100):
        if sched_file.exists() and sched_file.stat().st_size:
            break
        time.sleep(0.1)
    address = json.loads(sched_file.read_text())["address"]
    workers = []
    for _ in range(2):
        workers.append(
            subprocess.Popen(
                [str(BIN / "dask"), "worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard"],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                cwd=ROOT,
            )
        )
    with Client(address, timeout=30) as c:
        c.wait_for_workers(2, timeout=60)
    yield address, workers, procs[0]
    for p in workers + procs:  # the cluster is the test's own: no graceful retirement needed
        if p.poll() is None:
            p.kill()
        p.wait(timeout=20)


def _batch(logs, out, *where):
    args = ["batch", *map(str, logs), "--method", "ls", "--no-figures", "--quiet", *where, "--out", str(out)]
    return main(args)


def test_batch_on_a_scheduler_then_the_rerun_skips(logs, cluster, tmp_path, capsys):
    out = tmp_path / "b"
    assert _batch(logs, out, "--scheduler", cluster[0]) == 0
    df = pd.read_parquet(out / "results.parquet")
    per_log = df.groupby("name")["status"].first()
    assert sorted(per_log.index) == ["damaged", "s1-flight", "s2-flight", "s3-flight"]
    assert per_log["damaged"] == "refused" and (out / "damaged" / "error.txt").exists()
    assert "can be identified" in df[df["name"] == "damaged"]["reason"].iloc[0]
    ok = df[df["status"] == "ok"]
    assert not ok.duplicated(["name", "method", "parameter"]).any()  # each log once
    assert set(ok["parameter"]) >= {"CLalpha", "Cmalpha", "Cmq", "Cmde"} and ok["estimate"].notna().all()
    assert (ok["verdict"].isin(["PASS", "CHECK", "FAIL"])).all() and ok["log_sha256"].str.len().eq(64).all()
    for n in ("s1-flight", "s2-flight", "s3-flight"):
        assert (out / n / "report.json").exists() and (out / n / "report.md").exists()
    md = (out / "batch.md").read_text()
    assert "3 estimated, 1 not" in md and (out / "batch.html").exists()
    assert any(p.name.startswith("batch_ls") for p in (out / "figures").iterdir())
    # the rerun: the three done are skipped, the damaged one tried again
    capsys.readouterr()
    assert (
        main(["batch", *map(str, logs), "--method", "ls", "--no-figures", "--scheduler", cluster[0], "--out", str(out)])
        == 0
    )
    assert "3 of 4 logs have results for the same input, options and version: skipped" in capsys.readouterr().out
    again = pd.read_parquet(out / "results.parquet")
    keep = ["name", "method", "parameter", "estimate", "std", "seconds"]
    pd.testing.assert_frame_equal(
        again[again["status"] == "ok"][keep].reset_index(drop=True), ok[keep].reset_index(drop=True)
    )
    # the local cluster gives the same estimates
    local = tmp_path / "local"
    assert _batch(logs[:1], local, "--workers", "1") == 0
    lo = pd.read_parquet(local / "results.parquet")
    mine = ok[ok["name"] == "s1-flight"][["parameter", "estimate"]].reset_index(drop=True)
    pd.testing.assert_frame_equal(lo[["parameter", "estimate"]].reset_index(drop=True), mine)


def test_a_campaign_is_the_same_on_any_number_of_workers(cluster, tmp_path):
    sc = ROOT / "scenarios" / "longitudinal_short_calm.toml"  # 26 s: the campaign's flights short
    a, b = tmp_path / "two", tmp_path / "one"
    base = ["campaign", str(sc), "--method", "ls", "--quiet"]
    assert main([*base, "--seeds", "1:8", "--scheduler", cluster[0], "--out", str(a)]) == 0
    # a local cluster of one worker: the same rows for the seeds it flies (3 of them: the
    # rows do not depend on which worker, or how many, flew a seed)
    assert main([*base, "--seeds", "2:4", "--workers", "1", "--out", str(b)]) == 0
    da, db = (pd.read_parquet(x / "campaign.parquet").drop(columns=["seconds"]) for x in (a, b))
    assert len(da) > 8 and (da["status"] == "ok").all() and sorted(set(da["seed"])) == list(range(1, 9))
    pd.testing.assert_frame_equal(da[da["seed"].between(2, 4)].reset_index(drop=True), db)
    s = pd.read_parquet(a / "campaign_summary.parquet")
    assert set(s.columns) >= {"bias_in_std", "empirical_over_reported", "coverage_2std"} and (s["flights"] == 8).all()
    assert "Monte Carlo campaign" in (a / "campaign.md").read_text()


def _batch_running(logs, address: str, out: Path, *, until: str, timeout: float = 180.0) -> subprocess.Popen:
    """``fsid batch`` of ``logs`` (ls, no figures) on the scheduler at ``address`` in a
    process of its own, returned once ``until`` (a glob under ``out``) matches: a task has
    started (``*/.fsid.lock``, a worker holds a log's folder) or finished (``results.parquet``)."""
    cmd = [sys.executable, "-m", "pipeline.cli", "batch", *map(str, logs), "--method", "ls", "--no-figures"]
    proc = subprocess.Popen(
        [*cmd, "--scheduler", address, "--out", str(out)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not any(out.glob(until)):
        time.sleep(0.05)
    assert any(out.glob(until)), f"nothing matched {until} in {timeout:g} s"
    return proc


def test_a_worker_killed_mid_task_runs_again_elsewhere(logs, cluster, tmp_path):
    address, workers, _ = cluster
    out = tmp_path / "k"
    proc = _batch_running(logs[:2], address, out, until="*/.fsid.lock", timeout=120)
    os.kill(workers[0].pid, signal.SIGKILL)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr
    df = pd.read_parquet(out / "results.parquet")
    assert sorted(df["name"].unique()) == ["s1-flight", "s2-flight"]
    assert (df["status"] == "ok").all(), df[df["status"] != "ok"]["reason"].tolist()
    assert not df.duplicated(["name", "method", "parameter"]).any()


def test_ctrl_c_leaves_a_consistent_results_file(logs, cluster, tmp_path):
    """Ctrl-C once a task has finished: exit 130, results.parquet readable with the finished
    logs, the report says where it stopped, INTERRUPTED.txt says it was interrupted."""
    out = tmp_path / "c"
    proc = _batch_running(logs[:3], cluster[0], out, until="results.parquet")
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=180)
    assert proc.returncode == 130, stderr
    df = pd.read_parquet(out / "results.parquet")
    assert (df["status"] == "ok").all() and 1 <= df["name"].nunique() <= 3
    assert not df.duplicated(["name", "method", "parameter"]).any()
    assert "interrupted" in (out / "batch.md").read_text() and (out / "INTERRUPTED.txt").exists()


def test_the_scheduler_gone_keeps_the_finished_results(logs, cluster, tmp_path):
    """Last in this module: it stops the cluster's scheduler."""
    address, _, scheduler = cluster
    out = tmp_path / "g"
    proc = _batch_running(logs[:3], address, out, until="results.parquet")
    scheduler.kill()
    stdout, stderr = proc.communicate(timeout=180)
    assert proc.returncode != 0
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "scheduler" in lines[0] and "Traceback" not in stderr, stderr
    df = pd.read_parquet(out / "results.parquet")
    assert (df["status"] == "ok").all() and df["name"].nunique() >= 1  # what finished is kept
