"""Fuzz the hostile classes of issue 44 (hypothesis, >= 1000 inputs each).

Time jumps: one record of a small valid log of every format gets a time stamp moved by a
drawn amount (seconds to 2^63 us, forward and back; NaN and infinities in a CSV). The log is
read, checked and put on the 100 Hz grid ``fsid check`` writes: the only exception allowed
out is the documented LogReadError, and the grid is bounded by the number of samples, never
by the span of the stamps (:func:`pipeline.ingest.sampling.uniform_grid`).

Hostile content: CSV column names, MCAP topic and field names and the log's file name drawn
from control characters, Markdown and HTML syntax and script addresses. Whatever the reader
does with them, every text that reaches a person - the findings' messages as the terminal
prints them, report.md's facts and findings, report.html made from it, a refusal's
message - holds no control character and no live link, image, tag or attribute.
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import Writer
from test_fuzz_readers import SEEDS, _df_offsets

from pipeline.cli import main
from pipeline.conditioning.checks import findings_to_json, run_checks
from pipeline.errors import describe, visible
from pipeline.ingest.readers import LogReadError, read_log
from pipeline.ingest.sampling import GRID_GAP_S
from pipeline.outputs.html import markdown_html
from pipeline.outputs.report import report_markdown

pytestmark = pytest.mark.slow

N_EXAMPLES = int(os.environ.get("FSID_FUZZ_EXAMPLES", "1000"))
FUZZ = settings(
    max_examples=N_EXAMPLES, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck)
)
RATE_HZ = 100.0
#: control characters a terminal or a viewer acts on (C0, DEL, C1)
CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")


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
        findings = run_checks(fd)
        findings_to_json(findings, fd)
        df = fd.resample(RATE_HZ, span="union")
        assert len(df) <= _grid_bound(fd), (len(df), _grid_bound(fd))
        assert np.all(np.isfinite(df["t"].to_numpy()))

    run()
    assert len(seen) >= N_EXAMPLES


# ---------------------------------------------------------------- hostile content

TOKENS = [
    "![x](/etc/passwd)",
    '"onerror="alert(1)',
    "[c](javascript:alert(1))",
    "<script>alert(1)</script>",
    "<img src=x onerror=alert(1)>",
    "\x1b[31m",
    "\x1b]8;;http://x\x07",
    "\x9b2J",
    "\r",
    "\x00",
    "|",
    "`",
    "&amp;",
    "<!--",
    "javascript:",
    "data:text/html,",
]
HOSTILE = st.lists(
    st.one_of(st.sampled_from(TOKENS), st.text(st.characters(codec="utf-8", exclude_characters="\n"), max_size=6)),
    min_size=1,
    max_size=4,
).map("".join)
#: file names cannot hold "/" or NUL, and stay short
FILE_NAME = HOSTILE.map(lambda s: s.replace("/", "_").replace("\x00", "_")[:80])


def _hostile_log(fmt: str, names: list[str]) -> bytes:
    if fmt == "csv":
        cols = ["t", "p", *(n.replace(",", ";").replace('"', "'") or "x" for n in names)]
        rows = [
            ",".join(f"{0.02 * i:.2f}" if j == 0 else f"{0.1 * i:.3f}" for j in range(len(cols))) for i in range(20)
        ]
        return ("\n".join([",".join(cols), *rows]) + "\n").encode("utf-8", "surrogatepass")
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "h.mcap"
        with open(p, "wb") as fh:
            w = Writer(fh)
            w.start()
            sid = w.register_schema(name=names[0], encoding="jsonschema", data=b'{"type": "object"}')
            for k, topic in enumerate(["/imu", *names]):
                cid = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
                for i in range(20):
                    msg = {"t": 0.02 * i, "p": 0.1 * i, **{n: float(i) for n in names}}
                    w.add_message(cid, log_time=int(2e7 * i) + k, publish_time=0, data=json.dumps(msg).encode())
            w.finish()
        return p.read_bytes()


def _clean(text: str, where: str) -> None:
    assert not CONTROL.search(text), (where, text)


def _clean_html(page: str) -> None:
    assert not re.search(r"<(img|script|iframe|object|embed)\b", page, re.I), page
    assert not re.search(r"<[^>]*\son\w+\s*=", page, re.I), page
    for href in re.findall(r'(?:href|src)="([^"]*)"', page):
        assert re.match(r"(https?://|data:image/png;base64,|[\w.-]+(/[\w.-]+)*$)", href), href


@pytest.mark.parametrize("fmt", ["csv", "mcap"])
def test_fuzz_hostile_names_never_reach_a_reader_raw(fmt, tmp, capsys):
    seen = []

    @FUZZ
    @given(st.lists(HOSTILE, min_size=1, max_size=3, unique=True), FILE_NAME)
    def run(names, file_name):
        seen.append(1)
        try:
            data = _hostile_log(fmt, names)
        except (UnicodeEncodeError, ValueError):  # a name the format itself cannot hold
            return
        folder = tmp / f"h{len(seen) % 2}"
        folder.mkdir(exist_ok=True)
        for old in folder.iterdir():
            old.unlink()
        p = folder / f"{file_name or 'x'}.{fmt}"
        try:
            p.write_bytes(data)
        except OSError:  # a name the file system refuses
            return
        main(["fields", str(p)])  # the log's tables and fields as the terminal shows them
        printed = capsys.readouterr()
        _clean(printed.out + printed.err, "fsid fields")
        try:
            fd = read_log(p, segments=[])
        except LogReadError as exc:
            assert not exc.internal, f"reader bug caught by the safety net: {exc.__cause__!r}"
            _clean(visible(describe(exc)), "refusal")
            return
        findings = run_checks(fd)
        for f in findings:
            _clean(visible(f"{f.check} {f.channel or ''}: {f.message}"), "terminal")
        meta = {"log": str(p), "aircraft": names[0], **{k: v for k, v in fd.meta.items() if isinstance(v, str)}}
        checks = {"summary": {"pass": 0, "warn": 0, "fail": 0}, "findings": [f.as_dict() for f in findings]}
        md = report_markdown({"meta": meta, "methods": {}, "checks": checks})
        _clean(md, "report.md")
        page = markdown_html(md, folder)
        _clean(page, "report.html")
        _clean_html(page)

    run()
    assert len(seen) >= N_EXAMPLES


@pytest.mark.parametrize("fmt", ["csv", "mcap"])
def test_hostile_names_through_fsid_check(fmt, tmp_path, capsys):
    """``fsid check`` end to end on fewer drawn names (each a whole check): the terminal,
    error.txt and the files it writes hold no raw control character."""

    @settings(max_examples=40, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
    @given(st.lists(HOSTILE, min_size=1, max_size=2, unique=True), FILE_NAME)
    def run(names, file_name):
        try:
            data = _hostile_log(fmt, names)
        except (UnicodeEncodeError, ValueError):
            return
        p = tmp_path / f"{file_name or 'x'}.{fmt}"
        try:
            p.write_bytes(data)
        except OSError:
            return
        out = tmp_path / "out"
        main(["check", str(p), "--no-compat", "--out", str(out)])
        printed = capsys.readouterr()
        _clean(printed.out + printed.err, "fsid check")
        for name in ("error.txt", "checks.json"):
            if (out / name).exists():
                _clean((out / name).read_text(), name)
        p.unlink()

    run()
