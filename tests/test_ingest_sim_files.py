"""The built-in maps against what the sim's writers write: flight.bin and flight.mcap of
one flight must ingest to the same canonical channels (SI units), and the automatic
segments must find the scenario's maneuvers."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("jsbsim")
from pipeline.readers import read_log  # noqa: E402

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "sensor_errors_calm.toml"


@pytest.fixture(scope="module")
def files():
    if not SCENARIO.is_file():
        pytest.skip("scenario not available")
    from tests._simdata import flown, written

    d = written(SCENARIO.stem)          # flown and written once per session (shared)
    return (read_log(d / "flight.bin"), read_log(d / "flight.mcap"),
            json.loads((d / "truth.json").read_text()), flown(SCENARIO.stem))


def _at(a, b, name):
    return np.interp(b[name].t, a[name].t, a[name].values), b[name].values


def test_same_channels_same_values(files):
    fb, fm, truth, res = files
    assert set(fb.channels) == set(fm.channels) >= {"ax", "p", "phi", "V", "alpha", "beta", "h",
                                                   "vn", "de", "da", "dr", "throttle"}
    assert fb.meta["map"] == "ardupilot_bin" and fm.meta["map"] == "fsid_mcap"
    for name, tol in [("ax", 1e-5), ("az", 1e-5), ("p", 1e-6), ("r", 1e-6), ("phi", 1e-6),
                      ("alpha", 1e-6), ("beta", 1e-6), ("h", 1e-4), ("vn", 1e-5)]:
        a, b = _at(fb, fm, name)
        assert np.max(np.abs(a - b)) < tol, name
    # true airspeed: ArduPilot logs EAS, the map multiplies by CTUN.E2T
    a, b = _at(fb, fm, "V")
    assert np.max(np.abs(a - b)) < 1e-3 * np.max(b)
    # heading: ATT.Yaw is 0..360 deg, the MCAP +-pi
    a, b = _at(fb, fm, "psi")
    assert np.max(np.abs(np.angle(np.exp(1j * (a - b))))) < 1e-5
    # surfaces: RCOU is the commanded PWM (1 us = 30/400 deg), the MCAP the measured position
    for name in ("de", "da", "dr"):
        a, b = _at(fb, fm, name)
        assert np.max(np.abs(a - b)) < np.radians(0.3), name
        assert np.corrcoef(a, b)[0, 1] > 0.99, name
    assert fb["p"].rate_hz == pytest.approx(100.0) and fb["h"].rate_hz == pytest.approx(20.0)


def test_auto_segments_cover_the_maneuvers(files):
    fb, fm, truth, res = files
    for fd in (fb, fm):
        auto = [s for s in fd.segments if s.kind == "auto"]
        # maneuvers flown together (cross-controlled rudder doublets: rudder and aileron
        # over one window) are one segment per axis, in axis order
        mans = sorted((m for m in truth["maneuvers"] if m["axis"] in ("de", "da", "dr")),
                      key=lambda m: (m["t_start"], m["axis"]))
        assert len(auto) == len(mans)
        for s, m in zip(auto, mans):
            assert s.axis == m["axis"]
            assert s.t0 <= m["t_start"] and s.t1 >= m["t_end"]
            assert s.t1 - s.t0 < (m["t_end"] - m["t_start"]) + 6.0
