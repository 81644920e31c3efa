"""Fuzz every reader with mutated small valid files (hypothesis).

Each format gets >= 1000 mutated inputs (truncation, flipped bytes, inserted/deleted
bytes, zeroed blocks, spliced garbage). The only exception allowed out of ``read_log`` is
the documented :class:`pipeline.ingest.readers.LogReadError`; and when a file is merely cut
short, every record that lies wholly before the cut is kept.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.ingest.flightdata import FlightData
from pipeline.ingest.readers import MIN_SAMPLES, LogReadError, read_log
from pipeline.ingest.readers.synth import demo_dataflash, encode_tlog, encode_ulog, write_json_mcap

pytestmark = pytest.mark.slow

N_EXAMPLES = int(os.environ.get("FSID_FUZZ_EXAMPLES", "1000"))
FUZZ = settings(
    max_examples=N_EXAMPLES, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck)
)


def _mcap_bytes() -> bytes:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "s.mcap"
        write_json_mcap(
            p,
            {
                "/imu": [{"t": i * 0.02, "p": 0.1 * i, "q": 0.0, "r": 1.0} for i in range(30)],
                "/baro": [{"t": i * 0.1, "h": 10.0} for i in range(6)],
            },
        )
        return p.read_bytes()


def _csv_bytes() -> bytes:
    t = np.arange(40) * 0.02
    return ("t,p,q,phi\n" + "\n".join(f"{a:.2f},{np.sin(a):.5f},{np.cos(a):.5f},0.1" for a in t) + "\n").encode()


SEEDS = {
    "bin": demo_dataflash(n=40, seed=1),
    "tlog": encode_tlog(n=20),
    "mcap": _mcap_bytes(),
    "ulg": encode_ulog(n=30),
    "csv": _csv_bytes(),
}


@st.composite
def mutated(draw, fmt: str):
    data = bytearray(SEEDS[fmt])
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["truncate", "flip", "insert", "delete", "zero", "splice"]))
        n = len(data)
        if n == 0:
            break
        i = draw(st.integers(0, n - 1))
        if kind == "truncate":
            del data[i:]
        elif kind == "flip":
            data[i] ^= 1 << draw(st.integers(0, 7))
        elif kind == "insert":
            data[i:i] = draw(st.binary(min_size=1, max_size=16))
        elif kind == "delete":
            del data[i : i + draw(st.integers(1, 16))]
        elif kind == "zero":
            k = draw(st.integers(1, 64))
            data[i : i + k] = bytes(len(data[i : i + k]))
        else:
            data[i : i + 8] = draw(st.binary(min_size=8, max_size=8))
    return bytes(data)


def _read(tmp: Path, fmt: str, data: bytes):
    p = tmp / f"f.{fmt}"
    p.write_bytes(data)
    try:
        fd = read_log(p, segments=[])
    except LogReadError as exc:
        assert exc.where is not None
        assert not exc.internal, f"reader bug caught by the safety net: {exc.__cause__!r}"
        return None
    assert isinstance(fd, FlightData)
    for ch in fd.channels.values():
        assert ch.t.shape == ch.values.shape
    return fd


@pytest.fixture(scope="module")
def tmp(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


@pytest.mark.parametrize("fmt", sorted(SEEDS))
def test_fuzz_only_documented_error(fmt, tmp):
    seen = []

    @FUZZ
    @given(mutated(fmt))
    def run(data):
        seen.append(len(data))
        _read(tmp, fmt, data)

    run()
    assert len(seen) >= N_EXAMPLES  # every mutated input was really read


def _df_offsets(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, length, id) of each record of a valid DataFlash byte string."""
    lengths = {0x80: 89}
    out, i = [], 0
    while i + 3 <= len(data):
        mid = data[i + 2]
        ln = lengths[mid]
        if mid == 0x80:
            lengths[data[i + 3]] = data[i + 4]
        out.append((i, ln, mid))
        i += ln
    return out


@settings(max_examples=150, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(st.integers(0, len(SEEDS["bin"]) - 1))
def test_truncated_bin_keeps_every_complete_record(tmp_path_factory, cut):
    data = SEEDS["bin"]
    tmp = tmp_path_factory.mktemp("cut")
    fd = _read(tmp, "bin", data[:cut])
    recs = _df_offsets(data)
    complete_imu0 = sum(
        1 for o, ln, mid in recs if mid == 0x10 and o + ln <= cut and data[o + 11] == 0
    )  # IMU instance byte (after TimeUS) == 0
    if fd is None:  # refused: no channel with MIN_SAMPLES samples
        assert complete_imu0 < MIN_SAMPLES
        return
    got = len(fd["p"]) if "p" in fd.channels else 0
    assert got == complete_imu0
    if cut < len(data) and any(o < cut < o + ln for o, ln, _ in recs):
        assert fd.meta["damage"] is not None and fd.meta["damage"]["offset"] < cut


@settings(max_examples=100, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(st.integers(0, len(SEEDS["tlog"]) - 1))
def test_truncated_tlog_keeps_every_complete_packet(tmp_path_factory, cut):
    data = SEEDS["tlog"]
    tmp = tmp_path_factory.mktemp("cut")
    fd = _read(tmp, "tlog", data[:cut])
    # walk the packets: 8-byte stamp + MAVLink v2 packet (len + 12, no signature)
    i, att = 0, 0
    while i + 10 <= len(data):
        ln = data[i + 9] + 12
        msgid = int.from_bytes(data[i + 8 + 7 : i + 8 + 10], "little")
        if i + 8 + ln <= cut and msgid == 30:  # ATTITUDE
            att += 1
        i += 8 + ln
    if fd is None:  # refused: no channel with MIN_SAMPLES samples
        assert att < MIN_SAMPLES
        return
    assert (len(fd["phi"]) if "phi" in fd.channels else 0) == att
