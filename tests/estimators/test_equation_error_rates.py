"""Equation error at any IMU rate: an IMU slower than the fits' >= 90 Hz grid (NaN between
its samples there) is differentiated over its own samples, so a 25 Hz IMU gives estimates
on both axes (before: 0 longitudinal rows, '0 samples for 4 parameters'), and the
frequency-domain validation reads the slow outputs between their samples (before: a
ValueError for every method)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from pipeline.ingest.constants import AircraftConstants
from pipeline.ingest.flightdata import FlightData
from pipeline.ingest.readers import read_log
from pipeline.methods.equation_error import equation_error
from pipeline.problems import lateral_problem, longitudinal_problem, longitudinal_regressions
from pipeline.validation import validate

pytest.importorskip("jsbsim")
from _simdata import written  # noqa: E402

IMU = ("p", "q", "r", "ax", "ay", "az")


def _slow_imu(fd: FlightData, step: int) -> FlightData:
    """The flight with its IMU channels keeping every ``step``-th sample only."""
    ch = {k: replace(c, t=c.t[::step], values=c.values[::step]) if k in IMU else c for k, c in fd.channels.items()}
    return FlightData(ch, dict(fd.meta), list(fd.segments))


@pytest.fixture(scope="module")
def flight():
    d = written("default")
    doc = json.loads((d / "truth.json").read_text())
    return read_log(d / "flight.mcap"), AircraftConstants.from_truth(doc), doc["derivatives"]


@pytest.mark.parametrize("build", [longitudinal_problem, lateral_problem], ids=["longitudinal", "lateral"])
def test_a_25_hz_imu_gives_equation_error_on_both_axes(flight, build):
    """The default flight's 100 Hz IMU kept at 25 Hz: the grid stays at 100 Hz, every
    regression has rows at the IMU's samples, and each derivative is within 3 std of the
    truth (every maneuver fitted); with the last maneuver held out, the validation computes
    every check, the frequency response and the proof of match included."""
    fd, ac, truth = flight
    slow = _slow_imu(fd, 4)
    assert slow["q"].rate_hz == pytest.approx(25.0)
    pb = build(slow, ac, hold_out=0)
    assert pb.rate_hz == pytest.approx(100.0)
    assert all(len(r.y) > 10 * len(r.names) for r in pb.regressions)
    res = equation_error(pb)
    free = [n for n, f in zip(res.names, res.free) if f and n in truth]
    assert len(free) >= 11
    z = {n: (float(res.params[n]) - truth[n]) / float(res.std[n]) for n in free}
    assert all(abs(x) < 3.0 for x in z.values()), str({n: round(x, 2) for n, x in z.items()})
    held = build(slow, ac, hold_out=1)
    v = validate(equation_error(held), held_out=held.held_out)
    assert v["errors"] == {} and v["proof_of_match"]["segments"]
    assert any(d["n_used"] > 0 for d in v["frequency"]["table"].values())


def test_pitch_moment_rows_sit_at_the_pitch_rates_own_samples():
    """A 25 Hz pitch rate on a 100 Hz grid with the elevator at every grid time: one row
    per rate sample (not 0, not 4 per sample), and Cm's elevator column is the elevator's
    mean over the span the rate is differentiated over (a step between two rate samples
    counts for the grid steps of the span it lasted)."""
    t = np.arange(0.0, 4.0, 0.01)
    q = np.where(np.arange(t.size) % 4 == 0, 0.1 * np.sin(2 * t), np.nan)
    de = np.where(t >= 2.015, 0.05, 0.0)  # a step 1.5 grid steps after a rate sample at 2.00
    df = pd.DataFrame({"t": t, "q": q, "V": 20.0, "alpha": 0.05, "de": de, "ax": 0.0, "az": -9.81})
    c = {"rho": 1.2, "m": 2.0, "S": 0.5, "cbar": 0.2, "Iyy": 0.1}
    regs = {r.coef: r for r in longitudinal_regressions([df], c, [np.zeros(t.size)])}
    assert len(regs["Cm"].y) == 100 == len(regs["CL"].y)
    de_cm = regs["Cm"].X[:, 3]
    k = 50  # the rate sample at 2.00 s: its span is 1.96-2.04 s, the step at 2.015 s
    assert de_cm[k] == pytest.approx(0.05 * 2 / 7, rel=1e-6)  # 2.02 and 2.03 of 1.97 ... 2.03
    assert regs["CL"].X[k, 3] == 0.0 and regs["CL"].X[k + 1, 3] == 0.05
