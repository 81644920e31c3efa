"""Time windows and the time base: a channel's rate comes from its sample stamps (a log
paused between maneuvers keeps its rate, no false jitter, the compatibility stage runs),
times are seconds from the log's start with the absolute start stated once, and ``fsid
estimate --segments`` fits the windows given in those seconds (``--no-holdout``: all of
them)."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import build_parser, main
from pipeline.commands import estimate as estimate_command
from pipeline.commands.arguments import segment_items
from pipeline.conditioning.checks import run_checks
from pipeline.conditioning.compatibility import reconstruct
from pipeline.errors import FsidError
from pipeline.ingest.flightdata import FlightData, merge_overlapping
from pipeline.ingest.readers import read_log

pytest.importorskip("jsbsim")
from _simdata import written  # noqa: E402

#: a Unix-epoch start (2024-03-09 16:00:00 UTC) for logs stamped in calendar time
EPOCH = 1710000000.0
GAP_S = 30.0


def _default() -> tuple[Path, FlightData]:
    d = written("default")
    return d, read_log(d / "flight.mcap")


def _with_gaps(fd: FlightData) -> FlightData:
    """The flight cut into its maneuver windows with a GAP_S pause (no samples) between
    each two: the logger stopped between maneuvers."""
    wins = [(s.t0, s.t1) for s in merge_overlapping(fd.segments)]
    chans = {}
    for k, c in fd.channels.items():
        parts = [
            (c.t[(c.t >= a) & (c.t <= b)] + i * GAP_S, c.values[(c.t >= a) & (c.t <= b)])
            for i, (a, b) in enumerate(wins)
        ]
        chans[k] = replace(c, t=np.concatenate([p[0] for p in parts]), values=np.concatenate([p[1] for p in parts]))
    return FlightData(chans, dict(fd.meta), [])


@pytest.mark.slow
def test_gaps_between_maneuvers_keep_the_rate_and_raise_no_jitter():
    """Six maneuvers 30 s apart: every channel keeps its native rate ((n - 1) / span read
    the 100 Hz IMU as about 20 Hz: a 25 Hz one fell under the compatibility stage's 20 Hz),
    no jitter warning, the gaps reported as gaps, found windows never span one, and the
    compatibility stage runs on the IMU's own rate instead of being skipped as telemetry."""
    _, fd = _default()
    gapped = _with_gaps(fd)
    for k in ("p", "az", "V", "phi", "de"):
        assert gapped[k].rate_hz == pytest.approx(fd[k].rate_hz, rel=1e-3), k
        assert (len(gapped[k]) - 1) / np.ptp(gapped[k].t) < 0.3 * fd[k].rate_hz  # what the span said
    fs = run_checks(gapped)
    assert not [f for f in fs if f.check == "jitter"]
    gaps = [f for f in fs if f.check == "gaps" and f.channel == "q"]
    assert gaps and GAP_S <= gaps[0].value < GAP_S + 2.0
    holes = gapped.gaps(["q"])
    assert len(holes) == 5 and all(GAP_S <= b - a < GAP_S + 2.0 for a, b in holes)
    found = gapped.find_segments()
    assert len({s.axis for s in found}) == 3
    assert all(not (s.t0 < a and s.t1 > b) for s in found for a, b in holes)
    # with its maneuvers found, every pause lies between them: said, not warned
    gapped.segments = found
    between = [f for f in run_checks(gapped) if f.check == "gaps"]
    assert between and all(f.status == "pass" and "between the maneuvers" in f.message for f in between)
    res = reconstruct(gapped, max_segments=2, estimate=("bias_p", "bias_q", "bias_r"), wind=False)
    assert res.settings["rate_hz"] == pytest.approx(100.0)
    assert np.all(np.abs(res.params[["bias_p", "bias_q", "bias_r"]].to_numpy()) < 0.01)


def test_an_epoch_stamped_log_reads_from_zero_and_states_its_start(tmp_path):
    """A CSV stamped in Unix time: channels, segments and canonical.csv in seconds from
    its start; where that is (UTC) in meta and checks.json, canonical.csv's t_abs column
    on the log's clock; fsid check --segments in those seconds."""
    _, fd = _default()
    df = fd.resample(50.0, ["p", "q", "r", "ax", "ay", "az", "V", "de", "da", "dr"])
    log = tmp_path / "epoch.csv"
    df.assign(t=(df["t"] + EPOCH).map("{:.6f}".format)).to_csv(log, index=False, float_format="%.9g")
    back = read_log(log)
    assert back["p"].t[0] == 0.0 and back.meta["t0_abs"] == pytest.approx(EPOCH)
    assert back.meta["t0_kind"] == "epoch UTC"
    assert np.allclose(back["p"].t, df["t"] - df["t"].iloc[0], atol=2e-6)
    out = tmp_path / "check"
    assert main(["check", str(log), "--out", str(out), "--no-compat", "--segments", "2:5,auto_de_1"]) == 0
    doc = json.loads((out / "checks.json").read_text())
    assert "2024-03-09T16:00:00" in doc["source"]["start"] and doc["source"]["t0_kind"] == "epoch UTC"
    segs = doc["source"]["segments"]
    assert [(s["name"], s["t0"], s["t1"]) for s in segs][0] == ("time_2-5s", 2.0, 5.0)
    assert segs[1]["name"] == "auto_de_1" and 5.0 < segs[1]["t0"] < 20.0
    header, row = (out / "canonical.csv").read_text().splitlines()[:2]
    assert header.startswith("t,t_abs,") and row.startswith(f"0.000000,{EPOCH:.6f},")
    canon = read_log(out / "canonical.csv")
    assert canon["p"].t[0] == 0.0 and np.allclose(canon["p"].values[:50], back.resample(50.0, ["p"])["p"][:50])


def test_segments_parse_as_ranges_and_names():
    assert segment_items("10:30, 45.5:70,auto_de_1") == [(10.0, 30.0), (45.5, 70.0), "auto_de_1"]
    for bad, words in (("10-30:x", "not T0:T1"), ("30:10", "below"), ("1:2,,", "empty item")):
        with pytest.raises(FsidError, match=words):
            segment_items(bad)
    args = build_parser().parse_args(["estimate", "x.bin", "--segments", "1.5:8.5,auto_de_1", "--no-holdout"])
    opts = estimate_command.options(args)
    assert opts.segments == [(1.5, 8.5), "auto_de_1"] and opts.hold_out is False


def test_chosen_segments_name_their_axes_and_refuse_bad_ones():
    _, fd = _default()
    chosen = fd.chosen_segments([(22.0, 29.0), "auto_de_1"])
    assert [(s.name, s.axis) for s in chosen] == [("time_22-29s", "da"), ("time_22-29s", "dr"), ("auto_de_1", "de")]
    with pytest.raises(FsidError, match="outside the log"):
        fd.chosen_segments([(70.0, 80.0)])
    with pytest.raises(FsidError, match="auto_de_0"):
        fd.chosen_segments(["elevator"])


def test_estimate_fits_the_windows_given_in_seconds_from_the_start(tmp_path):
    """fsid estimate's job on an epoch-stamped log with --segments in seconds from its
    start (one range, one found maneuver by name) and --no-holdout: equation error fits
    exactly those two windows, holds none out, and the report states the absolute start."""
    from pipeline.jobs.estimate import estimate
    from pipeline.jobs.options import EstimateOptions

    d, fd = _default()
    df = fd.resample(100.0, ["p", "q", "r", "ax", "ay", "az", "phi", "theta", "psi", "V", "alpha", "beta", "h"])
    df = df.join(fd.resample(100.0, ["de", "da", "dr", "thrust"]).drop(columns="t"))
    log = tmp_path / "flight.csv"
    df.assign(t=(df["t"] + EPOCH).map("{:.6f}".format)).to_csv(log, index=False, float_format="%.9g")
    shutil.copy(d / "truth.json", tmp_path / "truth.json")
    opts = EstimateOptions(
        methods=["ls"],
        model="longitudinal",
        compat=False,
        input_dynamics="off",
        quiet=True,
        segments=[(1.5, 8.5), "auto_de_1"],
        hold_out=False,
    )
    est = estimate(log, opts)
    (res,) = est.results.values()
    assert [s.name for s in res.segments] == ["time_1.5-8.5s", "auto_de_1"]
    assert res.segments[0].t[0] == pytest.approx(1.5, abs=0.011) and res.segments[0].t[-1] <= 8.5
    (v,) = est.validations.values()
    assert v["proof_of_match"] is None and not v["errors"]
    assert "2024-03-09T16:00:00" in est.meta["time"]
    assert abs(float(res.params["Cmq"]) + 3.6) < 4 * float(res.std["Cmq"])


def test_a_window_across_a_gap_is_refused_with_its_times(tmp_path):
    """A range given across a logging pause: one clear error naming the window in seconds
    from the start, not a fit across 30 s without data."""
    from pipeline.ingest.constants import AircraftConstants
    from pipeline.problems import longitudinal_problem

    d, fd = _default()
    gapped = _with_gaps(fd)
    ac = AircraftConstants.from_truth(json.loads((d / "truth.json").read_text()))
    a, b = gapped.gaps(["q"])[0]
    specs = gapped.chosen_segments([(a - 2.0, b + 2.0), "auto_de_1"])
    with pytest.raises(FsidError, match=f"{a - 2.0:.2f}-{b + 2.0:.2f} s"):
        longitudinal_problem(gapped, ac, segments=[s for s in specs if s.axis == "de"], hold_out=0)
