"""Nothing from a log reaches a reader raw (issue 44, item 2): text from data goes into
report.md as text (md_text), report.html embeds only the PNGs inside the report's folder
and links only to http(s) addresses or inside the folder, and the terminal and error.txt
see control characters as escapes."""

from __future__ import annotations

import base64
import html
import re

from pipeline.errors import FsidError, describe, visible
from pipeline.outputs.html import markdown_html
from pipeline.outputs.markdown import md_text
from pipeline.outputs.report import report_markdown

HOSTILE = [
    '![x"onerror="alert(1)](report.md).bin',
    "[click](javascript:alert%281%29).bin",
    "![x](/etc/passwd)",
    "<script>alert(1)</script>",
    "name | with | pipes\x1b[31m",
]


def _report(meta):
    return report_markdown({"meta": meta, "methods": {}})


def test_data_in_report_md_is_text():
    md = _report({"log": HOSTILE[0], "aircraft": HOSTILE[2], "mode": HOSTILE[1], "note": HOSTILE[3]})
    body = "\n".join(md.splitlines()[1:])
    for bad in ("![", "](", "<script", "[click]"):
        assert bad not in body, (bad, body)
    page = markdown_html(md)
    assert "<img" not in page and "<a " not in page and "<script" not in page
    # and reads back as what it was
    assert HOSTILE[0] in html.unescape(page) and HOSTILE[1] in html.unescape(page)
    assert "\x1b" not in md_text(HOSTILE[4]) and "&#124;" in md_text(HOSTILE[4])


def test_html_attribute_injection_escaped(tmp_path):
    page = markdown_html('text ![x"onerror="alert(1)](report.md) more', tmp_path)
    assert not re.search(r"<[^>]*\sonerror=", page), page


def test_html_links_only_http_or_inside(tmp_path):
    page = markdown_html(
        "[a](javascript:alert%281%29) [b](https://example.org/x) [c](figures/f.png) [d](../up.txt) "
        "[e](file:///etc/passwd) [f](/etc/passwd)",
        tmp_path,
    )
    hrefs = re.findall(r'href="([^"]*)"', page)
    assert hrefs == ["https://example.org/x", "figures/f.png"], hrefs


def test_html_embeds_only_pngs_inside_the_folder(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP SECRET")
    out = tmp_path / "run"
    (out / "figures").mkdir(parents=True)
    png = b"\x89PNG\r\n\x1a\n" + b"\0" * 16
    (out / "figures" / "ok.png").write_bytes(png)
    (tmp_path / "outside.png").write_bytes(png)
    (out / "fake.png").write_bytes(b"TOP SECRET")
    (out / "link.png").symlink_to(tmp_path / "outside.png")
    md = "\n\n".join(
        f"![{n}]({p})"
        for n, p in [
            ("ok", "figures/ok.png"),
            ("abs", str(secret)),
            ("up", "../outside.png"),
            ("fake", "fake.png"),
            ("link", "link.png"),
            ("etc", "/etc/passwd"),
        ]
    )
    page = markdown_html(md, out)
    assert page.count("data:image/png;base64,") == 1
    assert base64.b64encode(b"TOP SECRET").decode() not in page


def test_control_characters_made_visible():
    assert visible("aircraft \x1b[2J\u202egnp.exe") == "aircraft \\x1b[2J\\u202egnp.exe"
    assert "\x1b" not in describe(FsidError("topic \x1b]0;owned\x07 missing"))
