"""pipeline.problems.windows.usable_segments: the one place that cuts segment windows out of the
multi-rate frame, leaves out found segments with gaps and refuses a given one with one clear
message; pipeline.problems.windows.multirate_frame: slower outputs at their own samples."""

import numpy as np
import pandas as pd
import pytest

from pipeline.errors import FsidError
from pipeline.ingest.flightdata import SegmentSpec
from pipeline.problems import usable_segments


def _frame():
    t = np.arange(0.0, 10.0, 0.01)
    q = np.where(np.arange(t.size) % 4 == 0, np.sin(t), np.nan)  # a 25 Hz output
    return pd.DataFrame({"t": t, "q": q, "de": np.cos(t)})


def test_windows_keep_sparse_outputs_and_span_the_segment():
    spec = SegmentSpec("a", 2.0, 3.0)
    _, _, frames = usable_segments(_frame(), [spec], ["q"], ["de"], 0, "elevator maneuver")
    w = frames[id(spec)]
    assert w["t"].iloc[0] == pytest.approx(2.0) and w["t"].iloc[-1] == pytest.approx(3.0)
    assert w["q"].notna().sum() == 26 and not w["de"].isna().any()


def test_a_nan_input_or_too_few_output_samples_is_one_line():
    df = _frame()
    df.loc[250, "de"] = np.nan
    with pytest.raises(FsidError, match=r"segment b \(2.00-3.00 s\) has gaps or NaN in \['de'\]"):
        usable_segments(df, [SegmentSpec("b", 2.0, 3.0)], ["q"], ["de"], 0, "elevator maneuver")
    with pytest.raises(FsidError, match=r"\['q'\]: cut it or fix the log"):
        usable_segments(_frame(), [SegmentSpec("c", 2.0, 2.3)], ["q"], ["de"], 0, "elevator maneuver")


def test_a_found_segment_that_is_unusable_is_left_out_and_named():
    """A maneuver found in the log (kind auto or mode) whose window has a gap - detected in
    a hover, where no angle of attack can be rebuilt, or in a telemetry dropout - is left
    out with a note, and the others are fitted; a segment the user gave by time range still
    stops with the error, and too few usable segments is one line naming those left out."""
    df = _frame()
    df.loc[250, "de"] = np.nan
    a, b, c = (
        SegmentSpec("a", 0.5, 1.5, "auto", axis="de"),
        SegmentSpec("b", 2.0, 3.0, "auto", axis="de"),
        SegmentSpec("c", 5.0, 7.0, "mode", mode="FBWA"),
    )
    keep, notes, frames = usable_segments(df, [a, b, c], ["q"], ["de"], 1, "elevator maneuver")
    assert keep == [a, c] and set(frames) == {id(a), id(c)}
    assert notes == ["segment b (2.00-3.00 s) has gaps or NaN in ['de']: left out"]
    with pytest.raises(FsidError, match=r"segment t \(2.00-3.00 s\) has gaps or NaN in \['de'\]: cut it"):
        usable_segments(df, [a, SegmentSpec("t", 2.0, 3.0)], ["q"], ["de"], 1, "elevator maneuver")
    with pytest.raises(
        FsidError,
        match=r"found 2 elevator maneuver segment\(s\), 1 usable, but need "
        r"at least 2 .* - segment b \(2.00-3.00 s\) has gaps",
    ):
        usable_segments(df, [a, b], ["q"], ["de"], 1, "elevator maneuver")


def test_a_found_segment_on_the_ground_is_left_out():
    """A control check on the ground (airspeed below 5 m/s) found as a maneuver holds no
    flight dynamics: it is left out and named; the same span given by time range, or for a
    user model (a hovering vehicle's), is kept."""
    df = _frame()
    df["V"] = np.where(df["t"] < 4.0, 1.5, 25.0)
    a, b = SegmentSpec("a", 0.5, 1.5, "auto", axis="de"), SegmentSpec("b", 5.0, 7.0, "auto", axis="de")
    keep, notes, _ = usable_segments(df, [a, b], ["q"], ["de"], 0, "elevator maneuver")
    assert keep == [b]
    assert notes == [
        "segment a (0.50-1.50 s) is on the ground or hovering (airspeed below 5 m/s for 100% of it): left out"
    ]
    t = SegmentSpec("t", 0.5, 1.5)
    assert usable_segments(df, [t, b], ["q"], ["de"], 0, "elevator maneuver")[0] == [t, b]
    assert usable_segments(df, [a, b], ["q"], ["de"], 0, "m", airborne=False)[0] == [a, b]


@pytest.mark.slow
def test_the_longitudinal_problem_fits_the_usable_maneuvers():
    """The default scenario's log with the pitch rate lost over its first elevator
    maneuver (a dropout): that maneuver is left out, named in the problem notes, and the
    problem is built from the others (before: the axis failed)."""
    import json
    from dataclasses import replace

    pytest.importorskip("jsbsim")
    from _simdata import written

    from pipeline.ingest.constants import AircraftConstants
    from pipeline.ingest.flightdata import FlightData
    from pipeline.ingest.readers import read_log
    from pipeline.problems import longitudinal_problem

    d = written("default")
    fd = read_log(d / "flight.mcap")
    ac = AircraftConstants.from_truth(json.loads((d / "truth.json").read_text()))
    first = [s for s in fd.segments if s.axis == "de"][0]
    q = fd["q"]
    keep = (q.t < first.t0) | (q.t > first.t1)
    cut = FlightData(
        channels={**fd.channels, "q": replace(q, t=q.t[keep], values=q.values[keep])},
        meta=dict(fd.meta),
        segments=list(fd.segments),
    )
    full, part = longitudinal_problem(fd, ac, hold_out=0), longitudinal_problem(cut, ac, hold_out=0)
    names = lambda pb: [s.name for s in pb.specs + pb.held_specs]  # noqa: E731
    assert first.name in names(full) and names(part) == [n for n in names(full) if n != first.name]
    assert [n for n in part.notes if n.endswith("left out")] == [
        f"segment {first.name} ({first.t0:.2f}-{first.t1:.2f} s) has gaps or NaN in ['q']: left out"
    ]


def test_slow_outputs_off_the_grid_keep_every_sample():
    """A 10 Hz output (a GPS-rate rebuilt angle) whose stamps sit 4 ms off the 100 Hz grid of
    the fast outputs, with 1 ms jitter: every native sample is one grid sample, valued at
    its grid time, NaN in between. Keeping only samples within a quarter step of the grid
    (before) dropped nearly all of them."""
    from pipeline.ingest.flightdata import Channel, FlightData
    from pipeline.problems import multirate_frame

    rng = np.random.default_rng(3)
    tf = np.arange(0.0, 20.0, 0.01)
    ts = np.arange(0.2, 19.8, 0.1) + 0.004 + 0.001 * rng.uniform(-1, 1, 196)
    f = lambda t: np.sin(0.7 * t)  # noqa: E731
    fd = FlightData(
        channels={
            "q": Channel(t=tf, values=np.cos(tf), unit="rad/s"),
            "alpha": Channel(t=ts, values=f(ts), unit="rad"),
            "de": Channel(t=tf, values=0.1 * np.sin(tf), unit="rad"),
        }
    )
    df, rate = multirate_frame(fd, ["q", "alpha"], ["de"])
    assert rate == pytest.approx(100.0, rel=1e-3)
    a = df["alpha"].to_numpy()
    kept = np.isfinite(a)
    assert kept.sum() == ts.size and df["q"].notna().all()
    # each kept value is the channel at its grid time (linear between its samples: within
    # 6e-4 here; the first, before the first sample, takes that sample's value), which is
    # within half a step of a sample
    assert np.allclose(a[kept][1:], f(df["t"].to_numpy()[kept][1:]), atol=1e-3)
    assert np.max(np.abs(np.subtract.outer(df["t"].to_numpy()[kept], ts)).min(axis=1)) <= 0.005 + 1e-9


@pytest.mark.parametrize(
    "fastest, grid",
    [
        (400.0, 200.0),
        (200.0, 200.0),
        (100.0, 100.0),
        (99.8, 99.8),
        (50.0, 100.0),
        (49.9, 99.8),
        (40.0, 120.0),
        (25.0, 100.0),
        (4.1, 90.2),
        (3.0, 90.0),
    ],
)
def test_the_grid_runs_at_least_at_90_hz(fastest, grid):
    """pipeline.ingest.flightdata.fit_grid_rate: the fastest output's rate up to MAX_RATE_HZ; a
    slower one's smallest whole multiple that reaches 90 Hz (a 100 Hz IMU whose stamps
    measure 99.8 Hz keeps its grid; it is not doubled)."""
    from pipeline.ingest.flightdata import fit_grid_rate
    from pipeline.problems import MAX_RATE_HZ

    assert fit_grid_rate(fastest, MAX_RATE_HZ) == pytest.approx(grid)


def test_a_25_hz_imu_is_compared_at_its_own_samples():
    """Every output at 25 Hz (an ArduPilot IMU): the grid runs at 100 Hz, the inputs at
    every grid time, each output at its own samples only (every 4th row), NaN in between."""
    from pipeline.ingest.flightdata import Channel, FlightData
    from pipeline.problems import multirate_frame

    ts, tu = np.arange(0.0, 10.0, 0.04), np.arange(0.0, 10.0, 0.04)
    fd = FlightData(
        channels={
            "q": Channel(t=ts, values=np.cos(ts), unit="rad/s"),
            "az": Channel(t=ts, values=np.sin(ts), unit="m/s^2"),
            "de": Channel(t=tu, values=0.1 * tu, unit="rad"),
        }
    )
    df, rate = multirate_frame(fd, ["q", "az"], ["de"])
    assert rate == pytest.approx(100.0)
    assert df["de"].notna().all() and np.allclose(df["de"], 0.1 * df["t"])
    for c in ("q", "az"):
        rows = np.flatnonzero(df[c].notna().to_numpy())
        assert np.array_equal(rows, np.arange(0, len(df), 4)), c
        assert np.allclose(df[c].to_numpy()[rows], np.cos(ts) if c == "q" else np.sin(ts))


def test_accelerometers_are_left_out_inside_a_step_ramp():
    """Where the fits' control input is a ramp standing in for a step between two slow
    samples (meta["input_steps"] of pipeline.conditioning.input_sampling.time_steps), the accelerometer
    samples strictly inside it are NaN (the model's control force is part of the way
    through the step, the aircraft's was not); the gyros and every other sample stay; a
    surface's applied delay moves its spans with it."""
    from pipeline.ingest.flightdata import Channel, FlightData
    from pipeline.problems import multirate_frame

    t = np.arange(0.0, 2.0, 0.01)
    chans = {
        "q": Channel(t=t, values=np.cos(t), unit="rad/s"),
        "az": Channel(t=t, values=np.sin(t), unit="m/s^2"),
        "de": Channel(t=t, values=np.zeros_like(t), unit="rad"),
    }
    steps = {"de": [[0.505, 0.515], [1.0, 1.04]]}
    df, _ = multirate_frame(FlightData(chans, {"input_steps": steps}), ["q", "az"], ["de"])
    blank = np.flatnonzero(df["az"].isna().to_numpy())
    assert np.allclose(df["t"].to_numpy()[blank], [0.51, 1.01, 1.02, 1.03])
    assert df["q"].notna().all()
    moved = {"input_steps": steps, "input_dynamics": {"de": {"delay_s": 0.02, "lag_s": 0.0}}}
    df, _ = multirate_frame(FlightData(chans, moved), ["q", "az"], ["de"])
    blank = np.flatnonzero(df["az"].isna().to_numpy())
    assert np.allclose(df["t"].to_numpy()[blank], [0.53, 1.03, 1.04, 1.05])
