"""Fuzz the time-jump class of issue 44 (hypothesis, >= 1000 inputs per format).

One record of a small valid log of every format gets a time stamp moved by a drawn amount
(seconds to 2^63 us, forward and back; NaN and infinities in a CSV). The log is read,
checked and put on the 100 Hz grid ``fsid check`` writes: the only exception allowed out is
the documented LogReadError, and the grid is bounded by the number of samples, never by the
span of the stamps (:func:`pipeline.ingest.sampling.uniform_grid`).
"""

from __future__ import annotations

import json
import math
import os
import struct
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import Writer
from test_fuzz_readers import SEEDS, _df_offsets

from pipeline.conditioning.checks import check_channel, check_file, findings_to_json, run_checks
from pipeline.ingest.readers import LogReadError, read_log
from pipeline.ingest.sampling import GRID_GAP_S

pytestmark = pytest.mark.slow

N_EXAMPLES = int(os.environ.get("FSID_FUZZ_EXAMPLES", "1000"))
FUZZ = settings(
    max_examples=N_EXAMPLES, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck)
)
RATE_HZ = 100.0
#: every this many inputs go through every check of fsid check
WHOLE_EVERY = 5


# ---------------------------------------------------------------- time jumps


def _tlog_offsets(data: bytes) -> list[int]:
    """Start of each packet of an encode_tlog byte string (8-byte stamp + MAVLink v2)."""
    out, i = [], 0
    while i + 10 <= len(data):
        out.append(i)
        i += 8 + data[i + 9] + 12
    return out


def _ulog_data_offsets(data: bytes) -> list[int]:
    """Offset of the timestamp of each data ('D') message of a ULog byte string."""
    out, i = [], 16
    while i + 3 <= len(data):
        size, kind = struct.unpack_from("<HB", data, i)
        if kind == ord("D"):
            out.append(i + 5)  # header (3) + msg_id (2): the uint64 timestamp first
        i += 3 + size
    return out


def _move_int(data: bytearray, at: int, fmt: str, delta_us: int) -> None:
    (v,) = struct.unpack_from(fmt, data, at)
    bits = 8 * struct.calcsize(fmt)
    struct.pack_into(fmt, data, at, (v + delta_us) % 2**bits)


def _mcap_with(t: list[float]) -> bytes:
    """The fuzz seed's IMU topic with the times ``t`` [s] (a message's log time clipped
    to what MCAP can hold)."""
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "s.mcap"
        with open(p, "wb") as fh:
            w = Writer(fh)
            w.start()
            sid = w.register_schema(name="imu", encoding="jsonschema", data=b'{"type": "object"}')
            cid = w.register_channel(topic="/imu", message_encoding="json", schema_id=sid)
            for i, ti in enumerate(t):
                ns = int(min(max(ti * 1e9, 0.0), 2**64 - 1)) if math.isfinite(ti) else 0
                msg = {"t": ti if math.isfinite(ti) else str(ti), "p": 0.1 * i, "q": 0.0, "r": 1.0}
                w.add_message(cid, log_time=ns, publish_time=ns, data=json.dumps(msg).encode())
            w.finish()
        return p.read_bytes()


JUMP_S = st.one_of(
    st.sampled_from([1e-3, 0.7, 60.0, 3600.0, 1e6, 1e9, 1e13, 2.0**63 * 1e-6]), st.floats(1e-3, 1e14)
).flatmap(lambda s: st.sampled_from([s, -s]))


@st.composite
def time_jumped(draw, fmt: str) -> bytes:
    """A fuzz seed with one or two records' time moved by a drawn jump."""
    data = bytearray(SEEDS[fmt]) if fmt != "mcap" else None
    for _ in range(draw(st.integers(1, 2))):
        jump = draw(JUMP_S)
        us = int(jump * 1e6)
        if fmt == "bin":
            recs = [o for o, _, mid in _df_offsets(bytes(data)) if mid != 0x80]
            _move_int(data, draw(st.sampled_from(recs)) + 3, "<Q", us)
        elif fmt == "tlog":
            offs = _tlog_offsets(bytes(data))
            o = draw(st.sampled_from(offs))
            if draw(st.booleans()):
                _move_int(data, o, ">Q", us)  # the ground station's receive stamp
            else:
                _move_int(data, o + 8 + 10, "<I", us // 1000)  # the autopilot's time_boot_ms (first field)
        elif fmt == "ulg":
            _move_int(data, draw(st.sampled_from(_ulog_data_offsets(bytes(data)))), "<Q", us)
        elif fmt == "csv":
            lines = bytes(data).decode().splitlines()
            i = draw(st.integers(1, len(lines) - 1))
            t, rest = lines[i].split(",", 1)
            t = float(t) if t.strip() else 0.0  # a line blanked by the draw before
            new = draw(st.sampled_from([repr(t + jump), "nan", "inf", "-inf", "1e300", ""]))
            lines[i] = f"{new},{rest}"
            data = bytearray(("\n".join(lines) + "\n").encode())
        else:
            t = [i * 0.02 for i in range(30)]
            i = draw(st.integers(0, len(t) - 1))
            t[i] = draw(st.sampled_from([t[i] + jump, math.nan, math.inf]))
            return _mcap_with(t)
    return bytes(data)


def _grid_bound(fd) -> int:
    """The most samples the union grid may hold: a few per sample (uniform_grid)."""
    total = sum(len(c) for c in fd.channels.values())
    return 4 * total + 1000 + total * int(2 * GRID_GAP_S * RATE_HZ + 2)


@pytest.fixture(scope="module")
def tmp(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz_hostile")


@pytest.mark.parametrize("fmt", sorted(SEEDS))
def test_fuzz_time_jumps_bounded(fmt, tmp):
    seen = []

    @FUZZ
    @given(time_jumped(fmt))
    def run(data):
        seen.append(len(data))
        p = tmp / f"j.{fmt}"
        p.write_bytes(data)
        try:
            fd = read_log(p, segments=[])
        except LogReadError as exc:
            assert not exc.internal, f"reader bug caught by the safety net: {exc.__cause__!r}"
            return
        # every input through the file and channel checks (time order, rate, gaps); every
        # WHOLE_EVERY-th through all of them (the segment and kinematic checks resample
        # stretches of the log: most of the time, not more of the time classes)
        if len(seen) % WHOLE_EVERY == 0:
            findings = run_checks(fd)
        else:
            findings = check_file(fd) + [f for k, c in fd.channels.items() for f in check_channel(k, c.t, c.values)]
        findings_to_json(findings, fd)
        df = fd.resample(RATE_HZ, span="union")
        assert len(df) <= _grid_bound(fd), (len(df), _grid_bound(fd))
        assert np.all(np.isfinite(df["t"].to_numpy()))

    run()
    assert len(seen) >= N_EXAMPLES
