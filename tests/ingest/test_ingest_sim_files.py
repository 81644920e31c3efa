"""The built-in maps against what the sim's writers write: flight.bin and flight.mcap of
one flight must ingest to the same canonical channels (SI units), and the automatic
segments must find the scenario's maneuvers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("jsbsim")
from pipeline.ingest.readers import read_log  # noqa: E402

SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "sensor_errors_calm.toml"


@pytest.fixture(scope="module")
def files():
    if not SCENARIO.is_file():
        pytest.skip("scenario not available")
    from tests._simdata import flown, written

    d = written(SCENARIO.stem)  # flown and written once per session (shared)
    return (
        read_log(d / "flight.bin"),
        read_log(d / "flight.mcap"),
        json.loads((d / "truth.json").read_text()),
        flown(SCENARIO.stem),
    )


def _at(a, b, name):
    return np.interp(b[name].t, a[name].t, a[name].values), b[name].values


def test_same_channels_same_values(files):
    fb, fm, truth, res = files
    assert (
        set(fb.channels)
        == set(fm.channels)
        >= {"ax", "p", "phi", "V", "alpha", "beta", "h", "vn", "de", "da", "dr", "throttle"}
    )
    assert fb.meta["map"] == "ardupilot_bin" and fm.meta["map"] == "fsid_mcap"
    for name, tol in [
        ("ax", 1e-5),
        ("az", 1e-5),
        ("p", 1e-6),
        ("r", 1e-6),
        ("phi", 1e-6),
        ("alpha", 1e-6),
        ("beta", 1e-6),
        ("h", 1e-4),
        ("vn", 1e-5),
    ]:
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
        mans = sorted(
            (m for m in truth["maneuvers"] if m["axis"] in ("de", "da", "dr")), key=lambda m: (m["t_start"], m["axis"])
        )
        assert len(auto) == len(mans)
        for s, m in zip(auto, mans):
            assert s.axis == m["axis"]
            assert s.t0 <= m["t_start"] and s.t1 >= m["t_end"]
            assert s.t1 - s.t0 < (m["t_end"] - m["t_start"]) + 6.0


def test_aircraft_servo_travel_flies_and_decodes(tmp_path):
    """An aircraft whose servos move the elevator 25 deg and the rudder 40 deg at full PWM
    travel: the sim steps them by 25/400 and 40/400 deg, flight.bin logs FSID_TRAVEL_DE/DR,
    and the built-in map decodes RCOU with them - the decoded deflections are what was
    flown (after the trim point); a map default of 30 deg would put de 20 % off."""
    import sim
    from pipeline.outputs.writers import write_dataflash
    from tests._simdata import SCENARIOS, custom

    ac = (SCENARIOS / "aircraft" / "uav_small.toml").read_text()
    (tmp_path / "ac.toml").write_text(ac + "\n[servos]\nde_travel_deg = 25.0\ndr_travel_deg = 40.0\n")
    r = sim.fly(
        custom(
            {
                "aircraft": str(tmp_path / "ac.toml"),
                "duration_s": 8.0,
                "trim": {"altitude_m": 150.0, "airspeed_mps": 30.0},
                "maneuver": [
                    {
                        "name": "d",
                        "axis": "de",
                        "shape": "doublet",
                        "amplitude_deg": 2.0,
                        "pulse_s": 0.5,
                        "start_s": 2.0,
                    },
                    {
                        "name": "r",
                        "axis": "dr",
                        "shape": "doublet",
                        "amplitude_deg": 3.0,
                        "pulse_s": 0.5,
                        "start_s": 5.0,
                    },
                ],
            }
        )
    )
    assert r.meta["servo"]["travel_deg"] == {"de": 25.0, "da": 30.0, "dr": 40.0}
    write_dataflash(tmp_path / "flight.bin", r)
    fd = read_log(tmp_path / "flight.bin")
    assert fd.meta["servo_travel"]["de"] == {"deg": 25.0, "from": "log parameter FSID_TRAVEL_DE"}
    assert fd.meta["servo_travel"]["dr"]["deg"] == 40.0
    for axis, step_deg in (("de", 25.0 / 400), ("dr", 40.0 / 400)):
        ch = fd[axis]
        want = np.interp(ch.t, r.truth["t"], r.truth[f"{axis}_cmd"])
        late = ch.t > 0
        assert np.max(np.abs(ch.values - want)[late]) < 1e-6, axis
        k = np.rad2deg(want[late]) / step_deg
        assert np.max(np.abs(k - np.round(k))) < 1e-3, axis  # flown on the PWM steps
        assert np.ptp(want) > np.radians(3.5), axis


def _without(src: Path, dst: Path, drop: set[str]) -> Path:
    """A copy of the DataFlash log ``src`` without the messages named in ``drop`` (records
    are 0xA3 0x95 type, their lengths from the FMT records)."""
    data, out, i = src.read_bytes(), bytearray(), 0
    lens, names = {128: 89}, {128: "FMT"}
    while i < len(data) - 3:
        t = data[i + 2]
        if t == 128:
            lens[data[i + 3]], names[data[i + 3]] = data[i + 4], data[i + 5 : i + 9].rstrip(b"\0").decode()
        if names.get(t) not in drop:
            out += data[i : i + lens[t]]
        i += lens[t]
    dst.write_bytes(bytes(out))
    return dst


def test_airspeed_without_a_sensor_is_the_autopilots_estimate(files, tmp_path):
    """A log with no airspeed sensor (no ARSP): V is the map's fallback, ArduPilot's own
    estimate CTUN.As x E2T, said to be one; without CTUN either, V is missing and both
    reasons are named. A fallback of a fallback is a map error."""
    from pipeline.errors import FsidError
    from pipeline.ingest.maps import load_map
    from tests._simdata import written

    fb = files[0]
    src = written(SCENARIO.stem) / "flight.bin"
    fd = read_log(_without(src, tmp_path / "noarsp.bin", {"ARSP"}))
    a, b = _at(fb, fd, "V")
    assert np.max(np.abs(a - b)) < 1e-4 * np.max(a)
    assert fd["V"].derived.startswith("ArduPilot's airspeed estimate")
    assert "from the fallback CTUN.As x CTUN.E2T (ARSP[0].Airspeed, CTUN.E2T: no ARSP[0] messages)" in fd["V"].notes
    fd = read_log(_without(src, tmp_path / "noair.bin", {"ARSP", "CTUN"}))
    assert "V" not in fd.channels
    assert fd.meta["unmapped"]["V"] == "no ARSP[0] messages; fallback CTUN.As, CTUN.E2T: no CTUN messages"
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[map]\nextends = "ardupilot_bin"\n[channels.V]\nsource = "ARSP.Airspeed"\n'
        '[channels.V.fallback]\nsource = "CTUN.As"\n[channels.V.fallback.fallback]\n'
        'source = "X.y"\n'
    )
    with pytest.raises(FsidError, match=r"\[channels.V.fallback\] cannot have a fallback"):
        load_map(bad)


def test_velocity_without_the_ekf_is_the_gps_receivers(files, tmp_path):
    """A log without XKF1 (no EKF velocity): vn, ve, vd are the map's fallback, the GPS
    receiver's ground speed along its course and its vertical speed, said to be those; they
    equal what XKF1 held (the simulator logs the same GPS velocity in both). A transform
    the maps do not know is a map error."""
    from pipeline.errors import FsidError
    from pipeline.ingest.maps import load_map
    from tests._simdata import written

    fb = files[0]
    src = written(SCENARIO.stem) / "flight.bin"
    fd = read_log(_without(src, tmp_path / "noxkf.bin", {"XKF1"}))
    for c in ("vn", "ve", "vd"):
        a, b = _at(fb, fd, c)
        assert np.max(np.abs(a - b)) < 1e-4 * max(np.max(np.abs(a)), 1.0), c
        assert fd[c].derived.startswith("the GPS receiver's"), c
    assert np.ptp(fd["ve"].values) > 1.0  # the flight turns: east moves
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[map]\nextends = "ardupilot_bin"\n[channels.vn]\nsource = ["GPS.Spd", "GPS.GCrs"]\ntransform = "polr"\n'
    )
    with pytest.raises(FsidError, match="transform 'polr' unknown"):
        load_map(bad)
