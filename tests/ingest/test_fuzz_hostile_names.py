"""Fuzz the hostile-content class of issue 44 (hypothesis, >= 1000 inputs per format).

CSV column names, MCAP topic and field names and the log's file name drawn from control
characters, Markdown and HTML syntax and script addresses. Whatever the reader does with
them, every text that reaches a person - fsid fields and fsid check as the terminal shows
them, the findings' messages, report.md's facts and findings, report.html made from it, a
refusal's message - holds no control character and no live link, image, tag or attribute.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import Writer

from pipeline.cli import main
from pipeline.conditioning.checks import run_checks
from pipeline.errors import describe, visible
from pipeline.ingest.readers import LogReadError, read_log
from pipeline.outputs.html import markdown_html
from pipeline.outputs.report import report_markdown

pytestmark = pytest.mark.slow

N_EXAMPLES = int(os.environ.get("FSID_FUZZ_EXAMPLES", "1000"))
FUZZ = settings(
    max_examples=N_EXAMPLES, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck)
)
#: control characters a terminal or a viewer acts on (C0, DEL, C1)
CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")


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


@pytest.fixture(scope="module")
def tmp(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz_hostile")


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
