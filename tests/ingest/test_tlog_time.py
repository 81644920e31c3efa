"""The .tlog time base (pipeline.ingest.readers.tlog_time) on a telemetry log written with pymavlink
whose link delivers packets in bursts, one out of order and one twice, with an autopilot
reboot and a 32-bit ``time_usec`` that wraps: every sample must land at its autopilot stamp.
"""

from __future__ import annotations

import json
import os
import struct

import numpy as np
import pytest

from pipeline.ingest.readers.tlog import read_tlog

RATE = 20.0  # Hz, samples per message type
BURST = 0.5  # s, the link delivers what it buffered every 0.5 s
T_UTC = 1.7e9  # s, receive clock at the first packet


def _flight(tmp_path, *, garbage: bool = False):
    """Write the .tlog; returns its path and the truth: per boot the ATTITUDE stamps [s]
    and rolls, the SERVO stamps (time_usec, wrapping), the VFR_HUD airspeeds."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import ardupilotmega as mav

    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    packets = []  # (send time on the UTC clock, bytes)
    att_at = []  # positions of the ATTITUDE packets
    truth = {"att": [], "roll": [], "servo": [], "air": []}
    boots = [(4290.0, 0.0, 200), (5.0, 30.0, 100)]  # (boot time at start, UTC start, samples)
    for b0, u0, n in boots:
        att, roll, air = [], [], []
        for i in range(n):
            tb, tu = b0 + i / RATE, T_UTC + u0 + i / RATE
            r = 0.1 * np.sin(0.7 * i / RATE) + 1e-4 * i
            ms = int(round(tb * 1e3))
            usec = int(round(tb * 1e6)) % 2**32  # SERVO_OUTPUT_RAW.time_usec: uint32
            if garbage and i == 50 and b0 > 1000:
                ms = 1  # a reset stamp in mid-flight
            att_at.append(len(packets))
            packets.append((tu, m.attitude_encode(ms, r, 0.0, 0.0, 0.0, 0.0, 0.0).pack(m)))
            packets.append(
                (tu + 1e-4, m.servo_output_raw_encode(usec, 0, 1500 + i % 50, 1500, 1500, 1500, 0, 0, 0, 0).pack(m))
            )
            packets.append((tu + 2e-4, m.vfr_hud_encode(20.0 + 0.01 * i, 20.0, 0, 50, 100.0, 0.0).pack(m)))
            if i % 20 == 0:
                packets.append((tu + 3e-4, m.heartbeat_encode(1, 3, 81, 5 if b0 > 1000 else 10, 4).pack(m)))
            att.append(round(tb * 1e3) * 1e-3)  # the sample time, stamp or not
            roll.append(r)
            air.append(20.0 + 0.01 * i)
        truth["att"].append(np.array(att))
        truth["roll"].append(np.array(roll))
        truth["air"].append(np.array(air))
    # the link: bursts every BURST s, 1 ms apart; ATTITUDE 12 and 14 swap places, ATTITUDE
    # 10 is heard twice
    order = list(range(len(packets)))
    a, b = att_at[12], att_at[14]
    order[a], order[b] = order[b], order[a]
    order.insert(order.index(att_at[10]) + 1, att_at[10])
    out = bytearray()
    last = {}
    for k in order:
        ts, pkt = packets[k]
        arrive = np.ceil((ts - T_UTC) / BURST) * BURST + T_UTC
        arrive = max(arrive, last.get("t", 0.0) + 1e-3)
        last["t"] = arrive
        out += struct.pack(">Q", int(round(arrive * 1e6))) + pkt
    p = tmp_path / "bursts.tlog"
    p.write_bytes(bytes(out))
    return p, truth


def test_bursts_reorder_repeats_reboot_and_wrap(tmp_path):
    p, truth = _flight(tmp_path)
    raw = read_tlog(p)
    att, srv, hud = raw.tables["ATTITUDE"], raw.tables["SERVO_OUTPUT_RAW"], raw.tables["VFR_HUD"]
    n1, n2 = truth["att"][0].size, truth["att"][1].size
    # the repeat is dropped, the swapped packets go back in place
    assert len(att) == n1 + n2 and "1 repeats dropped" in raw.time_base
    assert np.all(np.diff(att.t) > 0)
    assert np.allclose(att["roll"], np.concatenate(truth["roll"]), atol=1e-7)
    assert "1 autopilot reboot(s)" in raw.time_base
    for k, sl in enumerate((slice(0, n1), slice(n1, None))):
        # within a boot the times are the autopilot's stamps: 0.05 s apart exactly, where
        # the receive stamps came 0.5 s apart in bursts
        assert np.allclose(np.diff(att.t[sl]), 1 / RATE, atol=1e-6)
        assert np.allclose(att.t[sl] - att.t[sl][0], truth["att"][k] - truth["att"][k][0], atol=1e-6)
        # SERVO_OUTPUT_RAW's 32-bit time_usec wrapped at 4294.967 s in the first boot
        assert np.allclose(srv.t[sl], att.t[sl], atol=1e-5)
        # VFR_HUD has no stamp: at the ATTITUDE stamp sent just before it
        assert np.allclose(hud.t[sl], att.t[sl], atol=1e-6)
        assert np.allclose(hud["airspeed"][sl], truth["air"][k], atol=1e-4)
    # the second boot follows the first on the receive clock (30 s after its start)
    assert att.t[n1] - att.t[0] == pytest.approx(30.0, abs=BURST)
    assert [m for _, m in raw.modes] == ["FBWA", "AUTO"]
    assert raw.modes[1][0] == pytest.approx(att.t[n1], abs=1e-6)
    # on the receive stamps the same log is bursty
    recv = read_tlog(p, time_base="log").tables["ATTITUDE"]
    assert np.min(np.diff(recv.t)) < 0.01 and np.max(np.diff(recv.t)) >= BURST - 0.01


def test_a_reset_stamp_is_not_trusted(tmp_path):
    """ATTITUDE 50 of the first boot says 1 ms since boot: it is placed by the stamps sent
    before it, not 4292 s back."""
    p, truth = _flight(tmp_path, garbage=True)
    raw = read_tlog(p)
    att = raw.tables["ATTITUDE"]
    assert "1 stamps more than 5 s off" in raw.time_base
    n1 = truth["att"][0].size
    assert np.all(np.diff(att.t[:n1]) > 0)
    assert np.allclose(att.t[:n1] - att.t[0], truth["att"][0] - truth["att"][0][0], atol=1e-3)


def test_time_base_choices(tmp_path):
    from pipeline.ingest.rawlog import LogReadError
    from pipeline.ingest.readers.synth import encode_tlog

    p, _ = _flight(tmp_path)
    with pytest.raises(LogReadError, match="time_base must be"):
        read_tlog(p, time_base="utc")
    # a log whose messages carry no stamp: "auto" keeps the receive times and says so,
    # "boot" is an error
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink.dialects.v20 import ardupilotmega as mav

    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    q = tmp_path / "nostamps.tlog"
    q.write_bytes(
        b"".join(
            struct.pack(">Q", int((T_UTC + i * 0.1) * 1e6)) + m.vfr_hud_encode(20.0, 20.0, 0, 50, 100.0, 0.0).pack(m)
            for i in range(10)
        )
    )
    raw = read_tlog(q)
    assert raw.time_base.endswith("no autopilot stamps found")
    assert raw.tables["VFR_HUD"].t[0] == pytest.approx(T_UTC, abs=1e-6)
    with pytest.raises(LogReadError, match="no message carries an autopilot stamp"):
        read_tlog(q, time_base="boot")
    # the synthetic log of the ingest tests: stamps and receive times agree
    s = tmp_path / "s.tlog"
    s.write_bytes(encode_tlog(n=100))
    a, b = read_tlog(s), read_tlog(s, time_base="log")
    assert np.allclose(a.tables["ATTITUDE"].t, b.tables["ATTITUDE"].t, atol=1e-6)


def test_time_base_option_of_read_log_and_the_cli(tmp_path, capsys):
    """``read_log(time_base=)`` and ``fsid check --time-base``: the receive times on request,
    a time base the format does not offer is one line and exit code 2."""
    from pipeline.cli import main
    from pipeline.ingest.readers import LogReadError, read_log

    p, truth = _flight(tmp_path)
    auto, recv = read_log(p), read_log(p, time_base="log")
    assert read_log(p, time_base=None).channels["phi"].t.tolist() == auto.channels["phi"].t.tolist()
    t_auto, t_recv = auto.channels["phi"].t, recv.channels["phi"].t
    d_auto, d_recv = np.diff(t_auto), np.diff(t_recv)
    assert np.sum(np.abs(d_auto - 0.05) > 1e-5) == 1  # the stamps: 20 Hz exactly
    assert np.sum(np.abs(d_recv - 0.05) > 1e-3) > 100  # but for the reboot; the
    assert "receive" in recv.meta["time_base"]  # link's bursts
    with pytest.raises(LogReadError, match=r"time base 'header' does not apply to a tlog log"):
        read_log(p, time_base="header")
    out = tmp_path / "chk"
    assert main(["check", str(p), "--time-base", "log", "--no-compat", "--out", str(out)]) == 0
    assert json.loads((out / "checks.json").read_text())["source"]["time_base"].startswith("tlog receive")
    assert main(["check", str(p), "--time-base", "header", "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not apply to a tlog log" in err[0]
