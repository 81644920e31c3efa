"""run.rrd: passes `rerun rrd verify`, and rerun's own reader (rerun.chunk.RrdReader) finds
the documented entity paths with the right sample counts and time lines; `fsid view` errors
and serving the web viewer."""

from __future__ import annotations

import collections
import os
import re
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import estimators
from estimators.datasets import longitudinal_example
from pipeline.outputs.recording import write_recording
from pipeline.outputs.recording_layout import SEGMENT_GAP, entity_part, segment_starts
from pipeline.validation import validate

rr = pytest.importorskip("rerun")
import rerun.chunk as rc  # noqa: E402

N = 400  # samples per segment
DT = 0.02


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """OEM on two 3211 segments, a third held out; recording with an extra data channel."""
    ex = longitudinal_example(1, n=N, dt=DT, segments=3)
    res = estimators.OutputError(ex.model).fit(ex.segments[:2])
    v = validate(res, held_out=ex.segments[2:], truth=ex.truth)
    extra = pd.DataFrame({"h": np.linspace(5000, 5010, N)}, index=pd.Index(ex.segments[0].t, name="t"))
    out = tmp_path_factory.mktemp("rec")
    path = write_recording(out / "run.rrd", {"oem": res}, {"oem": v}, truth=ex.truth, data=extra)
    return ex, res, v, path


def _rerun_cli() -> str:
    from pipeline.commands.view import rerun_binary

    return rerun_binary()


def _read(path: Path) -> tuple[dict[str, int], dict[str, list], set[str]]:
    """Temporal sample count per entity, their record batches, and static entities."""
    counts: dict[str, int] = collections.Counter()
    batches: dict[str, list] = collections.defaultdict(list)
    static: set[str] = set()
    for ch in rc.RrdReader(path).stream():
        if ch.is_static:
            static.add(ch.entity_path)
            continue
        counts[ch.entity_path] += ch.num_rows
        batches[ch.entity_path].append(ch.to_record_batch())
    return dict(counts), batches, static


def test_rrd_verify(run):
    *_, path = run
    assert path.name == "run.rrd" and path.stat().st_size > 0
    assert not [p for p in path.parent.iterdir() if p.name.endswith(".tmp")]
    p = subprocess.run([_rerun_cli(), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    assert "verified without error" in p.stderr + p.stdout


def test_entity_paths_and_sample_counts(run):
    ex, res, v, path = run
    counts, _, static = _read(path)
    n_fit = 2 * N
    for o in res.outputs:
        assert counts[f"/outputs/{o}/measured"] == n_fit
        assert counts[f"/outputs/{o}/oem"] == n_fit
        assert counts[f"/residuals/oem/{o}"] == n_fit
        assert counts[f"/match/{o}/measured"] == N
        assert counts[f"/match/{o}/oem"] == N
        judged = o in {"alpha", "theta", "q", "ax", "az"}
        assert (f"/match/{o}/upper" in counts) == judged
        if judged:
            assert counts[f"/match/{o}/upper"] == counts[f"/match/{o}/lower"] == N
        n_f = v["arrays"]["psd"]["f"].size
        assert counts[f"/spectra/oem/{o}"] == n_f
    for i in res.model.inputs:
        assert counts[f"/inputs/{i}"] == n_fit
    n_it = len(res.history)
    for name in res.free_names:
        base = f"/params/{entity_part(name)}"
        assert counts[f"{base}/oem"] == n_it
        assert counts[f"{base}/oem/upper"] == counts[f"{base}/oem/lower"] == n_it
        assert counts[f"{base}/truth"] == n_it
    n_w = v["arrays"]["freq"]["f"].size
    for o in v["frequency"]["outputs"]:
        base = f"/freq_response/{o}/de"
        assert counts[f"{base}/coherence"] == n_w
        for q in ("mag_db", "phase_deg"):
            for k in ("data", "oem", "oem_linear"):
                assert counts[f"{base}/{q}/{k}"] == n_w
    assert counts["/data/h"] == N
    assert counts["/inverse/oem/de"] == N and "/inverse/oem/thrust" not in counts  # excited only
    assert {"/README", "/summary/oem", "/outputs/q/measured"} <= static  # docs + series styles
    assert rc.RrdReader(path).blueprints()  # default layout sent


def test_time_lines_and_values(run):
    ex, res, v, path = run
    _, batches, _ = _read(path)
    (b,) = batches["/outputs/q/measured"]  # one send_columns call -> one chunk
    t = b.column("t").cast("int64").to_numpy() / 1e9
    seg = b.column("segment").to_numpy()
    z = np.concatenate(b.column("Scalars:scalars").to_pylist())
    # the example's segments all start at t = 0, so they are laid end to end with a 1 s gap
    span = (N - 1) * DT
    expect_t = np.concatenate([ex.segments[0].t, ex.segments[1].t + span + SEGMENT_GAP])
    np.testing.assert_allclose(t, expect_t, atol=1e-9)
    np.testing.assert_array_equal(seg, np.repeat([0, 1], N))
    q = res.outputs.index("q")
    np.testing.assert_allclose(
        z, np.concatenate([ex.segments[0].z[:, q], ex.segments[1].z[:, q]]), rtol=1e-12, atol=1e-15
    )
    (m,) = batches["/match/q/measured"]
    tm = m.column("t").cast("int64").to_numpy() / 1e9
    assert tm[0] == pytest.approx(2 * (span + SEGMENT_GAP))
    assert set(m.column("segment").to_numpy()) == {2}
    (p,) = batches["/params/Cmq/oem"]
    np.testing.assert_array_equal(p.column("iteration").to_numpy(), res.history["iteration"].to_numpy())
    vals = np.concatenate(p.column("Scalars:scalars").to_pylist())
    assert vals[-1] == pytest.approx(res.params["Cmq"])
    (f,) = batches["/spectra/oem/q"]
    fm = f.column("frequency").to_numpy()
    np.testing.assert_array_equal(fm, np.round(v["arrays"]["psd"]["f"] * 1000).astype(int))


def test_segment_starts_keep_log_time_when_disjoint():
    a, b = np.arange(10.0, 20.0, 0.1), np.arange(30.0, 40.0, 0.1)
    assert segment_starts([a, b]) == [0.0, 0.0]
    offs = segment_starts([a, a])
    assert offs[0] == pytest.approx(-10.0) and offs[1] == pytest.approx(-10.0 + a[-1] - a[0] + SEGMENT_GAP)
    assert entity_part("bias_az[0]") == "bias_az_0_"


def test_view_missing_recording_is_one_line_error(tmp_path, capsys):
    from pipeline.cli import main

    assert main(["view", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0] and "fsid run" in err[0]
    assert main(["view", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert str(tmp_path / "run.rrd") in err


def test_view_command_lines(tmp_path):
    from pipeline.commands.view import command, has_display, web_url

    rrd = tmp_path / "run.rrd"
    native = command(rrd, web=False)
    assert native[1:] == [str(rrd)]
    web = command(rrd, web=True, web_port=1234, grpc_port=5678)
    assert "--serve-web" in web and web[web.index("--web-viewer-port") + 1] == "1234"
    assert web[web.index("--port") + 1] == "5678" and web[web.index("--bind") + 1] == "127.0.0.1"
    assert has_display({"DISPLAY": ":0"}) and has_display({"WAYLAND_DISPLAY": "wayland-0"})
    assert not has_display({})
    assert web_url(1234, 5678) == "http://127.0.0.1:1234/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A5678%2Fproxy"


def _ignore_sigint():
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _block_sigint():
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})


def _start_view(run_dir: Path, launcher=None) -> subprocess.Popen:
    """``fsid view RUN_DIR`` on free ports without a display, in its own process group
    (``launcher``: run in the child before exec)."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    return subprocess.Popen(
        [sys.executable, "-m", "pipeline.cli", "view", str(run_dir), "--web-port", "0", "--grpc-port", "0"],
        cwd=Path(__file__).resolve().parents[2],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        start_new_session=True,
        preexec_fn=launcher,
    )


@pytest.mark.slow
@pytest.mark.parametrize(
    "launcher", [None, _ignore_sigint, _block_sigint], ids=["plain", "sigint-ignored", "sigint-blocked"]
)
def test_view_serves_web_viewer_without_display(run, launcher):
    """fsid view serves the web viewer and stops on Ctrl-C - also when started with SIGINT
    ignored or blocked (inherited across exec from a script's background job or a test
    runner's worker: it had then never stopped, and was killed after 30 s)."""
    *_, path = run
    proc = _start_view(path.parent, launcher)
    try:
        line = proc.stdout.readline()
        m = re.search(r"(http://127\.0\.0\.1:(\d+)/\?url=\S+)", line)
        assert m, line
        deadline = time.monotonic() + 30
        status = None
        while time.monotonic() < deadline and status != 200:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{m.group(2)}/", timeout=2) as r:
                    status = r.status
            except OSError:
                time.sleep(0.3)
        assert status == 200
    finally:
        proc.send_signal(signal.SIGINT)  # fsid view stops its rerun child on Ctrl-C
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0


@pytest.mark.slow
def test_view_ends_its_rerun_server_on_sigterm(run):
    """kill (SIGTERM) stops fsid view and the rerun server it started: no process of its
    group is left holding the ports."""
    *_, path = run
    proc = _start_view(path.parent)
    try:
        line = proc.stdout.readline()
        assert "serving" in line, line
        time.sleep(2.0)  # the rerun child is up
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0
    deadline = time.monotonic() + 10
    alive = True
    while alive and time.monotonic() < deadline:
        try:
            os.killpg(proc.pid, 0)
            time.sleep(0.2)
        except ProcessLookupError:
            alive = False
    if alive:
        os.killpg(proc.pid, signal.SIGKILL)
    assert not alive, "the rerun server outlived fsid view"


def test_several_methods_and_filter_trajectories(run, tmp_path):
    """OEM + EKF + a regression: measured once, one entity per method, the EKF parameter
    trajectory on t with +/- std, truth on both iteration and t."""
    from estimators.equation_error import LeastSquares
    from estimators.filters.ekf import EKF

    ex, res, v, _ = run
    segs = ex.segments[:2]
    ekf = EKF(ex.model, measurement_noise=dict(zip(ex.model.outputs, ex.noise_std))).fit(segs)
    X = pd.DataFrame(
        {"alpha": segs[0].z[:, 1], "q": segs[0].z[:, 3], "de": segs[0].u[:, 0]}, index=pd.Index(segs[0].t, name="t")
    )
    ls = LeastSquares(intercept=True, response="qdot").fit(X, segs[0].z[:, 4])
    results = {"oem": res, "ekf": ekf, "ls": ls}
    vals = {"oem": v, "ekf": validate(ekf, held_out=ex.segments[2:], truth=ex.truth), "ls": validate(ls)}
    assert vals["ls"]["modes"] is None and vals["ekf"]["proof_of_match"] is not None
    path = write_recording(tmp_path / "run.rrd", results, vals, truth=ex.truth)
    p = subprocess.run([_rerun_cli(), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    counts, batches, _ = _read(path)
    assert counts["/outputs/q/measured"] == counts["/outputs/q/ekf"] == 2 * N
    assert counts["/outputs/qdot/ls"] == N and "/outputs/q/ls" not in counts
    # the regression keeps no Segment objects: its data is a segment of its own ("#0")
    assert counts["/outputs/qdot/measured"] == 3 * N
    assert counts["/match/q/oem"] == counts["/match/q/ekf"] == N
    assert counts["/params/Cmq/ekf"] == counts["/params/Cmq/ekf/upper"] == 2 * N
    assert counts["/params/Cmq/oem"] == len(res.history)
    assert counts["/params/Cmq/truth"] == len(res.history) + 2
    assert counts["/params/q/ls"] == len(ls.history) if len(ls.history) else "/params/q/ls" not in counts
    (b,) = batches["/params/Cmq/ekf"]
    last = np.concatenate(b.column("Scalars:scalars").to_pylist())[-1]
    assert last == pytest.approx(ekf.params["Cmq"])
    assert set(b.column("segment").to_numpy()) == {0, 1}


def test_segment_layout_across_axes():
    """Segments of several results (axes) from one log keep log time and one index each;
    overlapping ones (synthetic, all from t = 0) are laid end to end."""
    from types import SimpleNamespace

    from pipeline.outputs.recording_layout import SegmentLayout

    def seg(t0, n, name):
        t = t0 + np.arange(n) * 0.1
        return pd.DataFrame({"y": np.zeros(n)}, index=pd.Index(t, name="t")), SimpleNamespace(name=name)

    (p1, s1), (p2, _), (p3, s3) = seg(10, 101, "de_0"), seg(40, 101, "de_1"), seg(25, 51, "da_0")
    results = {
        "lon": SimpleNamespace(predicted=[p1], segments=[s1]),
        "lat": SimpleNamespace(predicted=[p3], segments=[s3]),
    }
    vals = {"lon": {"arrays": {"match": [{"t": p2.index.to_numpy(), "name": "de_1"}]}}}
    lay = SegmentLayout(results, vals)
    assert [lay.place(p.index, n) for p, n in ((p1, "de_0"), (p2, "de_1"), (p3, "da_0"))] == [
        (0.0, 0),
        (0.0, 1),
        (0.0, 2),
    ]
    # synthetic maneuvers all starting at 0: end to end in order of appearance, 1 s apart
    (q1, r1), (q2, r2) = seg(0, 101, "a"), seg(0, 51, "b")
    lay = SegmentLayout({"m": SimpleNamespace(predicted=[q1, q2], segments=[r1, r2])}, {})
    assert lay.place(q1.index, "a") == (0.0, 0)
    assert lay.place(q2.index, "b") == (pytest.approx(10.0 + SEGMENT_GAP), 1)
    o, k = lay.place(q2.index, "late")  # unseen: appended after the end
    assert k == 2 and o == pytest.approx(10.0 + SEGMENT_GAP + 5.0 + SEGMENT_GAP)
