"""check.rrd (``fsid check``) and the whole flight in run.rrd: `rerun rrd verify` accepts
them, and rerun's own reader (rerun.chunk.RrdReader; rerun-sdk 0.41 has no
rerun.dataframe) finds every canonical channel at its samples on ``t`` in seconds from the
log's start, the flight modes on /flight/mode, the maneuver windows and the findings at
their times, on a simulated flight and on the real logs in ../shared/data/logs."""

from __future__ import annotations

import collections
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.cli import main
from pipeline.ingest.flightdata import FlightData, SegmentSpec
from pipeline.ingest.readers import read_log

rr = pytest.importorskip("rerun")
import rerun.chunk as rc  # noqa: E402
from _simdata import written  # noqa: E402

LOGS = Path(os.environ.get("FSID_LOGS_DIR") or Path(__file__).resolve().parents[3] / "shared" / "data" / "logs")
REAL = ["ardupilot_plane_ground_truncated.BIN", "ardupilot_quadplane_sitl.tlog", "px4_vtol_ground_small.ulg"]


def _verify(path: Path) -> None:
    from pipeline.commands.view import rerun_binary

    p = subprocess.run([rerun_binary(), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    assert "verified without error" in p.stderr + p.stdout


def _read(path: Path) -> tuple[dict[str, dict[str, list]], dict[str, list]]:
    """Temporal columns per entity (t in s, then each component's rows, concatenated over
    chunks) and the static rows per entity."""
    cols: dict[str, dict[str, list]] = collections.defaultdict(lambda: collections.defaultdict(list))
    static: dict[str, list] = collections.defaultdict(list)
    for ch in rc.RrdReader(path).stream():
        b = ch.to_record_batch()
        if ch.is_static:
            static[ch.entity_path].append(b.to_pydict())
            continue
        for name in b.schema.names:
            if name == "t":
                cols[ch.entity_path]["t"] += list(b.column("t").cast("int64").to_numpy() / 1e9)
            elif ":" in name:
                cols[ch.entity_path][name.split(":")[1]] += b.column(name).to_pylist()
    return cols, static


def _check(log: Path, out: Path) -> tuple[FlightData, dict, dict, dict]:
    """fsid check LOG --out OUT (without the compatibility fit); the log as read, checks.json
    and check.rrd read back."""
    assert main(["check", str(log), "--out", str(out), "--no-compat"]) == 0
    path = out / "check.rrd"
    _verify(path)
    cols, static = _read(path)
    return read_log(log), json.loads((out / "checks.json").read_text()), cols, static


@pytest.fixture(scope="module")
def sim_check(tmp_path_factory):
    return _check(written("lateral_doublets_calm") / "flight.mcap", tmp_path_factory.mktemp("check"))


@pytest.mark.slow  # a simulated flight checked and recorded: the edit loop's tier goes without it
def test_check_rrd_holds_every_channel_at_its_samples_from_the_start(sim_check):
    fd, _, cols, static = sim_check
    t0 = fd.span[0]
    assert set(fd.channels) == {p.rsplit("/", 1)[1] for p in cols if p.startswith("/flight/channels/")}
    for name, ch in fd.channels.items():  # at most 100 Hz: every sample, none thinned
        c = cols[f"/flight/channels/{name}"]
        np.testing.assert_allclose(c["t"], ch.t - t0, atol=1e-9)
        np.testing.assert_allclose(np.concatenate(c["scalars"]), ch.values, rtol=1e-12, atol=1e-15)
    assert min(cols["/flight/channels/p"]["t"]) == 0.0
    (info,) = static["/flight/info"]
    assert "t = 0 is the log's first sample" in info["TextDocument:text"][0][0]
    assert static["/flight/channels/p"][0]["SeriesLines:names"] == [["p [rad/s]"]]  # legend with the unit


@pytest.mark.slow  # a simulated flight checked and recorded: the edit loop's tier goes without it
def test_check_rrd_modes_windows_and_findings(sim_check):
    fd, doc, cols, _ = sim_check
    t0 = fd.span[0]
    assert cols["/flight/mode"]["state"] == [["no modes logged"]]  # the simulator logs no modes
    wins = [s for s in fd.segments if s.kind == "auto"]
    assert {s.axis for s in wins} == {"da", "dr"}
    for axis in ("da", "dr"):
        mine = sorted((s for s in wins if s.axis == axis), key=lambda s: s.t0)
        track = cols[f"/flight/maneuvers/{axis}"]
        np.testing.assert_allclose(track["t"], [x - t0 for s in mine for x in (s.t0, s.t1)], atol=1e-9)
        assert track["state"] == [x for s in mine for x in ([s.name], [])]  # empty: the window ends
    f = cols["/flight/findings"]
    fs = doc["findings"]
    assert len(f["text"]) == len(fs) == sum(doc["summary"].values())
    level = {"pass": "INFO", "warn": "WARN", "fail": "ERROR"}
    assert sorted(x[0] for x in f["level"]) == sorted(level[x["status"]] for x in fs)
    at = sorted(x["t0"] - t0 if x["t0"] is not None else 0.0 for x in fs)
    np.testing.assert_allclose(sorted(f["t"]), at, atol=1e-9)
    excited = [x for x in f["text"] if x[0].startswith("PASS excitation da")]
    assert excited and "s]" in excited[0][0]  # with its span in s from the start


@pytest.mark.slow
@pytest.mark.parametrize("name", REAL)
def test_check_rrd_of_real_logs(name, tmp_path):
    log = LOGS / name
    if not log.is_file():
        pytest.skip(f"real log {name} not available")
    fd, doc, cols, static = _check(log, tmp_path / "out")
    t0 = fd.span[0]
    assert "/flight/mode" in cols and "/flight/info" in static
    for ch_name, ch in fd.channels.items():
        t = np.asarray(cols[f"/flight/channels/{ch_name}"]["t"])
        n_finite = int(np.sum(np.isfinite(ch.values) & np.isfinite(ch.t)))
        span = float(np.nanmax(ch.t) - np.nanmin(ch.t))
        if n_finite <= 200.0 * span + 1:
            assert t.size == n_finite
        else:  # thinned for display: at most 200 points per second, the extremes kept
            assert t.size <= 200.0 * span + 4 and t.size < n_finite
            v = np.concatenate(cols[f"/flight/channels/{ch_name}"]["scalars"])
            assert v.max() == np.nanmax(ch.values) and v.min() == np.nanmin(ch.values)
        assert t.min() >= -1e-9 and t.max() <= fd.span[1] - t0 + 1e-9
    assert len(cols["/flight/findings"]["text"]) == len(doc["findings"])
    if fd.modes:
        assert [s[0] for s in cols["/flight/mode"]["state"]] == [m for _, m in fd.modes]
        np.testing.assert_allclose(cols["/flight/mode"]["t"], [max(a - t0, 0.0) for a, _ in fd.modes], atol=1e-9)
    if name.endswith(".tlog"):  # the SITL flight's four modes
        assert [s[0] for s in cols["/flight/mode"]["state"]] == ["QLOITER", "CIRCLE", "GUIDED", "QLAND"]
    from pipeline.commands.view import rrd_path

    assert rrd_path(tmp_path / "out") == tmp_path / "out" / "check.rrd"  # fsid view opens it


def test_overlapping_windows_get_their_own_track():
    from pipeline.outputs.recording_flight import FlightRecord, window_tracks

    fd = FlightData()
    fd.segments = [
        SegmentSpec("a", 10.0, 30.0),
        SegmentSpec("b", 20.0, 40.0),
        SegmentSpec("c", 35.0, 50.0),
        SegmentSpec("auto_de_0", 1.0, 5.0, "auto", axis="de"),
        SegmentSpec("mode_0_X", 0.0, 100.0, "mode", mode="X"),  # a flight mode, no window
    ]
    tracks = {k: [s.name for s in v] for k, v in window_tracks(FlightRecord(fd)).items()}
    assert tracks == {"de": ["auto_de_0"], "time": ["a", "c"], "time_2": ["b"]}


def test_the_absolute_start_is_stated_from_the_log_clock():
    from pipeline.outputs.recording_flight import absolute_start

    moved = FlightData(meta={"t0_abs": 1.7e9, "t0_kind": "epoch UTC"})  # times moved to the start
    assert absolute_start(moved, 0.0) == (
        "t = 0 is the log's first sample, 2023-11-14T22:13:20.000 UTC (1700000000.000000 s Unix epoch)"
    )
    boot = FlightData(meta={"t0_abs": 123.25, "t0_kind": "boot"})
    assert absolute_start(boot, 0.0).endswith("123.250000 s on the log's own clock (boot)")
    raw = FlightData(meta={"time_base": "MCAP log_time (ns since 1970), in s"})  # times as logged
    assert absolute_start(raw, 1.7e9 + 0.5).endswith(": 2023-11-14T22:13:20.500 UTC")
    assert "UTC" not in absolute_start(FlightData(meta={"time_base": "boot time, in s"}), 12.0)


def test_display_thinning_keeps_extremes_and_order():
    from pipeline.outputs.recording_flight import display_samples

    t = np.arange(0.0, 10.0, 0.001)  # 1 kHz
    v = np.sin(2 * np.pi * 3 * t)
    v[4321] = 7.0  # one spike
    ts, vs = display_samples(t, v)
    assert ts.size <= 200 * 10 + 2 and np.all(np.diff(ts) > 0)
    assert vs.max() == 7.0 and ts[vs.argmax()] == t[4321]
    np.testing.assert_allclose(vs, np.interp(ts, t, v))  # samples of the channel, not averages
    t100 = np.arange(0.0, 10.0, 0.01)
    tt, vv = display_samples(t100[::-1], np.cos(t100)[::-1])  # slow: every sample, in time order
    np.testing.assert_array_equal(tt, t100)
    np.testing.assert_array_equal(vv, np.cos(t100))


def test_run_rrd_places_fits_on_the_whole_flight(tmp_path):
    """A fit's segments that are pieces of the flight sit at their time from the log's start
    on the flight's channels; overlapping ones are laid after the flight's end."""
    import estimators
    from estimators.datasets import longitudinal_example
    from pipeline.outputs.recording import write_recording
    from pipeline.outputs.recording_flight import FlightRecord, planned_maneuvers
    from pipeline.outputs.recording_layout import SEGMENT_GAP

    ex = longitudinal_example(1, n=200, dt=0.02, segments=2)
    start = 1000.0  # a log whose clock reads 1000 s at its first sample
    segs = [estimators.Segment(t=s.t + start + 10.0 * k, u=s.u, z=s.z, x0=s.x0) for k, s in enumerate(ex.segments)]
    res = estimators.OutputError(ex.model).fit(segs)
    t = start + np.arange(0.0, 30.0, 0.02)
    fd = FlightData.from_frame(pd.DataFrame({"t": t, "q": np.zeros(t.size)}))
    fd.segments = [SegmentSpec(f"auto_de_{k}", s.t[0], s.t[-1], "auto", axis="de") for k, s in enumerate(segs)]
    fd.meta["modes"] = [(start - 5.0, "MANUAL"), (start + 12.0, "FBWA")]
    plan = planned_maneuvers([("elevator_3211", "de", start + 1.0, start + 2.4), ("de_doublet", "de", 1012.0, 1013.0)])
    path = write_recording(tmp_path / "run.rrd", {"oem": res}, flight=FlightRecord(fd, plan=plan))
    _verify(path)
    cols, _ = _read(path)
    np.testing.assert_allclose(cols["/outputs/q/measured"]["t"], np.concatenate([s.t - start for s in segs]))
    np.testing.assert_allclose(cols["/flight/maneuvers/de"]["t"], [0.0, 3.98, 10.0, 13.98], atol=1e-9)
    assert cols["/flight/mode"]["state"] == [["MANUAL"], ["FBWA"]]
    assert cols["/flight/plan/de"]["state"] == [["elevator_3211"], [], ["de_doublet"], []]
    np.testing.assert_allclose(cols["/flight/plan/de"]["t"], [1.0, 2.4, 12.0, 13.0], atol=1e-9)
    moved = fd.from_log_start()  # the reader's times from the start: the plan keeps the log's clock
    assert moved.span[0] == 0.0 and moved.meta["t0_abs"] == start
    path = write_recording(tmp_path / "moved.rrd", {"oem": res}, flight=FlightRecord(moved, plan=plan))
    np.testing.assert_allclose(_read(path)[0]["/flight/plan/de"]["t"], [1.0, 2.4, 12.0, 13.0], atol=1e-9)
    np.testing.assert_allclose(cols["/flight/mode"]["t"], [0.0, 12.0])  # a mode set before the data: at 0
    assert "/flight/findings" not in cols  # none given
    fitted = cols["/flight/segments/fitted"]  # where the fits sit on the flight
    assert fitted["state"] == [["#0"], [], ["#1"], []]
    np.testing.assert_allclose(fitted["t"], [0.0, 3.98, 10.0, 13.98], atol=1e-9)
    res0 = estimators.OutputError(ex.model).fit(ex.segments)  # both from t = 0: laid end to end
    path = write_recording(tmp_path / "run0.rrd", {"oem": res0}, flight=FlightRecord(fd))
    cols, _ = _read(path)
    t_out = np.asarray(cols["/outputs/q/measured"]["t"])
    assert t_out.min() == pytest.approx(fd.span[1] - fd.span[0] + SEGMENT_GAP)


def test_view_opens_a_check_folder_and_says_what_to_do_without_one(tmp_path, capsys):
    from pipeline.commands.view import rrd_path

    (tmp_path / "check.rrd").write_bytes(b"x")
    assert rrd_path(tmp_path) == tmp_path / "check.rrd"
    (tmp_path / "run.rrd").write_bytes(b"x")
    assert rrd_path(tmp_path) == tmp_path / "run.rrd"  # a run's recording holds the flight too
    old = tmp_path / "old"
    old.mkdir()
    (old / "checks.json").write_text("{}")
    assert main(["view", str(old)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"fsid check LOG --out {old}" in err[0] and "fsid run" not in err[0]
