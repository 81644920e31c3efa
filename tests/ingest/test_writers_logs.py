"""flight.mcap, flight.bin and truth.json read back with the mcap library and pymavlink."""

from __future__ import annotations

import json
from collections import defaultdict

import numpy as np
import pytest

from pipeline.outputs.writers import write_dataflash, write_mcap, write_truth_json
from sim.sensors import lever_arm_signals
from tests._simdata import flown, written

NAME = "sensor_errors_calm"  # lever arms, biases, scale factors and a delay


@pytest.fixture(scope="module")
def mcap_messages():
    from mcap.reader import make_reader

    out = defaultdict(list)
    with open(written(NAME) / "flight.mcap", "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        for _schema, channel, message in reader.iter_messages():
            out[channel.topic].append((message.log_time, json.loads(message.data)))
    return summary, out


@pytest.fixture(scope="module")
def bin_messages():
    from pymavlink.DFReader import DFReader_binary

    log = DFReader_binary(str(written(NAME) / "flight.bin"))
    msgs = defaultdict(list)
    while True:
        m = log.recv_msg()
        if m is None:
            break
        msgs[m.get_type()].append(m.to_dict())
    log.close()
    return msgs


def _col(rows, key):
    return np.array([r[key] for r in rows], dtype=float)


def _truth_at(r, sensor, t):
    """Noise-free value each channel of ``sensor`` should see at times t, with the
    sensor's lever arm, delay, bias and scale factor (everything but noise/quantisation)."""
    spec = r.scenario.sensors[sensor]
    src = lever_arm_signals(r.truth, spec)
    tt = r.truth["t"].to_numpy()
    return {
        c: (1 + spec.scale[i]) * np.interp(np.maximum(t - spec.delay, 0), tt, src[c]) + spec.bias[i]
        for i, c in enumerate(spec.channels)
    }, spec


def _within_noise(meas, want, sd, what):
    res = meas - want
    assert abs(res.mean()) < 5 * sd / np.sqrt(len(res)) + 1e-6, what
    assert res.std() == pytest.approx(sd, rel=0.1), what


def test_mcap_topics_schemas_units_and_rates(mcap_messages):
    summary, msgs = mcap_messages
    r = flown(NAME)
    topics = {c.topic: c for c in summary.channels.values()}
    assert set(topics) == {f"/sensors/{k}" for k in r.sensors} | {"/controls", "/truth"}
    for topic, ch in topics.items():
        schema = summary.schemas[ch.schema_id]
        assert schema.encoding == "jsonschema" and ch.message_encoding == "json"
        units = json.loads(ch.metadata["units"])
        props = json.loads(schema.data)["properties"]
        if topic == "/truth":
            assert set(units) == set(r.truth.columns) and units["alpha"] == "rad" and units["thrust"] == "N"
            assert set(props["truth"]["properties"]) == set(r.truth.columns) - {"t"}
        else:
            assert set(props) == set(units)
    assert json.loads(topics["/sensors/imu"].metadata["units"])["q"] == "rad/s"
    assert json.loads(topics["/controls"].metadata["units"])["thrust"] == "N"
    for name, df in r.sensors.items():
        rows = msgs[f"/sensors/{name}"]
        assert len(rows) == len(df)
        t = np.array([m["t"] for _, m in rows])
        assert np.array_equal(t, df["t"].to_numpy())
        assert np.array_equal(np.array([lt for lt, _ in rows]), np.round(t * 1e9).astype(np.int64))
        assert float(topics[f"/sensors/{name}"].metadata["rate_hz"]) == pytest.approx(1 / np.diff(t).mean())
        for c in df.columns:  # JSON keeps every float bit
            assert np.array_equal(np.array([m[c] for _, m in rows]), df[c].to_numpy()), (name, c)
    truth_rows = msgs["/truth"]
    assert len(truth_rows) == len(r.truth.iloc[::2])  # 50 Hz of a 100 Hz flight
    tr = np.array([m["truth"]["CL"] for _, m in truth_rows])
    assert np.array_equal(tr, r.truth["CL"].to_numpy()[::2])
    # log times are in order across topics
    allt = sorted(lt for rows in msgs.values() for lt, _ in rows)
    assert allt[0] == 0 and allt[-1] == int(r.scenario.duration * 1e9)


def test_mcap_sensor_values_match_truth_within_the_noise_model(mcap_messages):
    _, msgs = mcap_messages
    r = flown(NAME)
    for sensor in ("imu", "airdata", "baro"):
        rows = [m for _, m in msgs[f"/sensors/{sensor}"]]
        t = _col(rows, "t")
        want, spec = _truth_at(r, sensor, t)
        for i, c in enumerate(spec.channels):
            sd = np.sqrt(spec.noise[i] ** 2 + spec.quant[i] ** 2 / 12)
            _within_noise(_col(rows, c), want[c], sd, (sensor, c))


def test_bin_has_the_ardupilot_layouts_units_and_params(bin_messages):
    m = bin_messages
    fmts = {f["Name"]: f for f in m["FMT"]}
    assert fmts["IMU"]["Format"] == "QBffffffIIfBBHH"
    assert fmts["IMU"]["Columns"] == "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"
    assert fmts["ARSP"]["Format"] == "QBffcffBBffB" and fmts["AOA"]["Format"] == "Qff"
    assert fmts["BARO"]["Format"] == "QBffcfIffB" and fmts["RCOU"]["Format"] == "QHHHHHHHHHHHHHH"
    units = {chr(u["Id"]) if isinstance(u["Id"], int) else u["Id"]: u["Label"] for u in m["UNIT"]}
    assert units["E"] == "rad/s" and units["o"] == "m/s/s" and units["d"] == "deg" and units["Y"] == "us"
    fmtu = {u["FmtType"]: u["UnitIds"] for u in m["FMTU"]}
    assert fmtu[fmts["IMU"]["Type"]] == "s#EEEooo--O--zz"
    params = {p["Name"]: p["Value"] for p in m["PARM"]}
    assert params["SERVO2_FUNCTION"] == 19 and params["SERVO1_FUNCTION"] == 4 and params["SERVO4_FUNCTION"] == 21
    assert params["SERVO2_MIN"] == 1100 and params["SERVO2_TRIM"] == 1500 and params["SERVO2_MAX"] == 1900
    assert all(params[f"FSID_TRAVEL_{a}"] == 30.0 for a in ("DE", "DA", "DR"))
    assert params["FSID_ARSP_TAS"] == 1
    assert params["FSID_MAX_THRUST"] == flown(NAME).aircraft.max_thrust
    r = flown(NAME)
    for name, sensor in (
        ("IMU", "imu"),
        ("ATT", "attitude"),
        ("ARSP", "airdata"),
        ("AOA", "airdata"),
        ("BARO", "baro"),
        ("RCOU", "surfaces"),
        ("GPS", "gps"),
        ("CTUN", "attitude"),
    ):
        t = _col(m[name], "TimeUS") * 1e-6
        assert len(t) == len(r.sensors[sensor]), name
        assert np.allclose(np.diff(t), 1 / r.meta["sensors"][sensor]["rate_hz"]), name


def test_bin_values_match_sensors_and_truth(bin_messages):
    m = bin_messages
    r = flown(NAME)
    imu = r.sensors["imu"]
    for f, c in (("GyrX", "p"), ("GyrY", "q"), ("AccZ", "az")):
        np.testing.assert_allclose(_col(m["IMU"], f), imu[c], rtol=1e-6, atol=1e-6)
    t_imu = _col(m["IMU"], "TimeUS") * 1e-6
    want, spec = _truth_at(r, "imu", t_imu)
    for f, c, i in (("GyrY", "q", 4), ("AccX", "ax", 0)):
        _within_noise(_col(m["IMU"], f), want[c], np.sqrt(spec.noise[i] ** 2 + spec.quant[i] ** 2 / 12), f)
    # airspeed: ARSP.Airspeed holds TAS by default; CTUN.As is EAS and As * E2T is TAS
    t_ad = _col(m["ARSP"], "TimeUS") * 1e-6
    t_ct = _col(m["CTUN"], "TimeUS") * 1e-6
    tas = _col(m["ARSP"], "Airspeed")
    np.testing.assert_allclose(tas, r.sensors["airdata"]["V"], rtol=2e-6)
    eas = _col(m["CTUN"], "As")
    np.testing.assert_allclose(eas * _col(m["CTUN"], "E2T"), np.interp(t_ct, t_ad, tas), rtol=2e-5)
    assert 0.98 < np.median(eas / np.interp(t_ct, t_ad, tas)) < 0.995  # 150 m: rho < 1.225
    want, spec = _truth_at(r, "airdata", t_ad)
    _within_noise(tas, want["V"], spec.noise[0], "V")
    _within_noise(np.deg2rad(_col(m["AOA"], "AOA")), want["alpha"], spec.noise[1], "AOA")
    t_att = _col(m["ATT"], "TimeUS") * 1e-6
    want, spec = _truth_at(r, "attitude", t_att)
    _within_noise(np.deg2rad(_col(m["ATT"], "Pitch")), want["theta"], spec.noise[1], "ATT.Pitch")
    assert np.max(np.abs(_col(m["BARO"], "Alt") - r.sensors["baro"]["h"])) < 1e-4
    gps = m["GPS"]
    t_g = _col(gps, "TimeUS") * 1e-6
    assert np.max(np.abs(_col(gps, "Lat") - np.interp(t_g, r.truth["t"], r.truth["lat"]))) < 2e-7
    np.testing.assert_allclose(_col(gps, "VZ"), r.sensors["gps"]["vd"], atol=1e-5)


def test_rcou_pwm_maps_back_to_the_commanded_deflections(bin_messages):
    """The ArduPilot convention of the ingest map: x = (PWM - TRIM)/(MAX - TRIM);
    da = +x*travel, de = -x*travel, dr = -x*travel; throttle = (PWM - MIN)/(MAX - MIN).
    The sim flies whole-microsecond commands, so RCOU holds exactly what was flown (to a
    thousandth of a microsecond: the log's TimeUS is rounded) after t = 0, the trim point,
    whose deflections are JSBSim's continuous trim solution."""
    m = bin_messages
    r = flown(NAME)
    p = {q["Name"]: q["Value"] for q in m["PARM"]}
    t = _col(m["RCOU"], "TimeUS") * 1e-6
    for ch, axis, sign in ((1, "da", 1), (2, "de", -1), (4, "dr", -1)):
        travel = np.deg2rad(p[f"FSID_TRAVEL_{axis.upper()}"])
        step = travel / 400
        assert r.meta["servo"]["step_deg"][axis] == pytest.approx(np.rad2deg(step))
        n = next(k for k in range(1, 17) if p.get(f"SERVO{k}_FUNCTION") == {1: 4, 2: 19, 4: 21}[ch])
        pwm = _col(m["RCOU"], f"C{n}")
        x = (pwm - p[f"SERVO{n}_TRIM"]) / (p[f"SERVO{n}_MAX"] - p[f"SERVO{n}_TRIM"])
        defl = sign * x * travel
        want = np.interp(t, r.truth["t"], r.truth[f"{axis}_cmd"])
        flown_ = t > 0
        assert np.max(np.abs(defl - want)[flown_]) <= 1e-3 * step, axis
        assert np.max(np.abs(want / step - np.round(want / step))[flown_]) < 1e-3, axis
        assert np.ptp(want) > np.deg2rad(3), axis  # the maneuvers are in there
    thr = (_col(m["RCOU"], "C3") - p["SERVO3_MIN"]) / (p["SERVO3_MAX"] - p["SERVO3_MIN"])
    assert np.max(np.abs(thr - np.interp(t, r.truth["t"], r.truth["throttle"]))[t > 0]) <= 1e-6


def test_truth_json_holds_the_truth_set_and_errors():
    d = json.loads((written(NAME) / "truth.json").read_text())
    r = flown(NAME)
    assert d["seed"] == r.scenario.seed and d["scenario"]["name"] == NAME
    assert d["derivatives"] == r.aircraft.derivatives
    assert d["aircraft"]["propulsion"]["max_thrust_N"] == r.aircraft.max_thrust
    assert d["sensors"]["airdata"]["delay_s"] == 0.04
    assert d["sensors"]["imu"]["bias"]["ax"] == 0.12
    assert [x["name"] for x in d["maneuvers"]] == [x[0] for x in r.maneuvers]
    assert d["trim"]["alpha"] == r.trim["alpha"] and "jsbsim" in d["versions"]


def test_same_seed_gives_byte_identical_logs(tmp_path):
    import sim

    a = written("default")
    res = sim.fly(sim.load_scenario(flown("default").scenario.path))
    write_mcap(tmp_path / "flight.mcap", res)
    write_dataflash(tmp_path / "flight.bin", res)
    write_truth_json(tmp_path / "truth.json", res)
    for f in ("flight.mcap", "flight.bin", "truth.json"):
        assert (a / f).read_bytes() == (tmp_path / f).read_bytes(), f
    other = sim.fly(sim.load_scenario(flown("default").scenario.path), seed=5)
    write_dataflash(tmp_path / "other.bin", other)
    assert (tmp_path / "other.bin").read_bytes() != (a / "flight.bin").read_bytes()


def test_fsid_simulate_cli(tmp_path, capsys):
    from pipeline.cli import main

    assert main(["simulate", "default", "--out", str(tmp_path / "run"), "--seed", "3"]) == 0
    out = capsys.readouterr().out
    for f in ("flight.mcap", "flight.bin", "truth.json"):
        assert (tmp_path / "run" / f).stat().st_size > 1000 and f in out
    assert json.loads((tmp_path / "run" / "truth.json").read_text())["seed"] == 3
    assert main(["simulate", "no_such_scenario", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not found" in err
    bad = tmp_path / "bad.toml"
    bad.write_text(
        'aircraft = "%s"\nduration_s = 10\n[trim]\naltitude_m = 100\nairspeed_kts = 50\n'
        % (flown("default").aircraft.path)
    )
    assert main(["simulate", str(bad), "--out", str(tmp_path / "y")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "trim.airspeed_kts: wrong unit" in err


def test_bin_can_carry_equivalent_airspeed(tmp_path):
    from pymavlink.DFReader import DFReader_binary

    r = flown("default")
    write_dataflash(tmp_path / "eas.bin", r, airspeed="eas")
    log = DFReader_binary(str(tmp_path / "eas.bin"))
    arsp, ctun = [], []
    while (m := log.recv_msg()) is not None:
        if m.get_type() == "ARSP":
            arsp.append(m.Airspeed)
        elif m.get_type() == "CTUN":
            ctun.append(m.E2T)
    log.close()
    tas = np.array(arsp) * np.array(ctun)  # same rate (50 Hz): airdata and attitude
    np.testing.assert_allclose(tas, r.sensors["airdata"]["V"], rtol=2e-5)
    with pytest.raises(ValueError, match="airspeed"):
        write_dataflash(tmp_path / "x.bin", r, airspeed="ias")


def test_mixed_tails_decode_to_the_same_deflections(tmp_path):
    """A flying wing's elevons (SERVOn_FUNCTION 77/78) and a V-tail (79/80) carry the same
    flight: the built-in map's ``mix`` takes the elevator as the mean of the two surfaces
    and the aileron / rudder as half their difference, to within the whole-microsecond
    rounding of each output (one PWM step, travel/400). Without the mix the elevator had
    come from output 2, an elevon, because the map's default channel was used."""
    from pipeline.ingest.readers import read_log

    r = flown(NAME)
    write_dataflash(tmp_path / "conv.bin", r)
    ref = read_log(tmp_path / "conv.bin")
    for tail, mixed in (("elevons", ("de", "da")), ("vtail", ("de", "dr"))):
        write_dataflash(tmp_path / f"{tail}.bin", r, tail=tail)
        fd = read_log(tmp_path / f"{tail}.bin")
        for axis in ("de", "da", "dr"):
            step = r.aircraft.travel(axis) / 400
            np.testing.assert_array_equal(fd[axis].t, ref[axis].t)
            assert np.max(np.abs(fd[axis].values - ref[axis].values)) <= step * (1.0 if axis in mixed else 1e-9), (
                tail,
                axis,
            )
            assert np.ptp(fd[axis].values) > np.deg2rad(3)
            assert fd[axis].source.startswith("mix of SERVOn_FUNCTION") == (axis in mixed), fd[axis].source
        assert fd.meta["servo_travel"][mixed[0]]["from"] == "log parameter FSID_TRAVEL_DE"
    with pytest.raises(ValueError, match="tail"):
        write_dataflash(tmp_path / "x.bin", r, tail="canard")


@pytest.mark.slow
@pytest.mark.parametrize("compression, chunk_size", [("lz4", None), ("none", 20_000), ("zstd", 300)])
def test_mcap_bytes_as_the_mcap_writer_writes_them(tmp_path, monkeypatch, compression, chunk_size):
    """write_mcap assembles chunks, indexes and summary itself (batched); the same messages
    through mcap.writer.Writer one by one give the same file, byte for byte (several
    chunks with a small chunk size, every compression)."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    import pipeline.outputs.writers.mcap_json as mj

    if chunk_size:
        monkeypatch.setattr(mj, "CHUNK_SIZE", chunk_size)
    r = flown(NAME)
    write_mcap(tmp_path / "ours.mcap", r, compression=compression)
    ours = (tmp_path / "ours.mcap").read_bytes()
    with open(tmp_path / "ours.mcap", "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        msgs = [
            (m.channel_id, m.log_time, m.publish_time, m.sequence, m.data)
            for _, _, m in reader.iter_messages(log_time_order=False)
        ]
        meta = list(reader.iter_metadata())
    assert len(summary.chunk_indexes) > (3 if chunk_size else 1)
    with open(tmp_path / "theirs.mcap", "wb") as fh:
        w = Writer(
            fh,
            compression=getattr(CompressionType, compression.upper()),
            **({"chunk_size": chunk_size} if chunk_size else {}),
        )
        w.start(profile="", library="fsid-sim")
        for cid, ch in summary.channels.items():
            sc = summary.schemas[ch.schema_id]
            assert w.register_schema(name=sc.name, encoding=sc.encoding, data=sc.data) == ch.schema_id
            assert (
                w.register_channel(
                    topic=ch.topic, message_encoding=ch.message_encoding, schema_id=ch.schema_id, metadata=ch.metadata
                )
                == cid
            )
        for cid, log_time, pub, seq, data in msgs:
            w.add_message(channel_id=cid, log_time=log_time, publish_time=pub, data=data, sequence=seq)
        w.add_metadata(meta[0].name, meta[0].metadata)
        w.finish()
    assert len(msgs) == sum(summary.statistics.channel_message_counts.values())
    assert ours == (tmp_path / "theirs.mcap").read_bytes()
