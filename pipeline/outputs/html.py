"""report.html: report.md as one self-contained HTML page (its PNG figures embedded as
base64 data URIs), to share as a single file.

The converter covers the Markdown report.md is written in, no more: ATX headings, pipe
tables (header, separator, rows), paragraphs, ``-``/``*`` and numbered lists, fenced code
blocks, and inline code, ``**bold**``, images ``![caption](path)`` and links. Everything
else is text, escaped; character references (report.md writes text from data that way,
:func:`pipeline.outputs.markdown.md_text`) stay references. An image that appears again (a
figure shared by several methods' sections) is embedded once; its repeats link to it.

Nothing in report.md can reach outside its folder: only PNG files inside the report's
folder are embedded, and links go only to http(s) addresses or to relative paths inside
the folder; any other target is shown as text."""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

from pipeline.paths import atomic_write_text

_CSS = """
body { font-family: -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; font-size: 14px;
       line-height: 1.45; color: #222; max-width: 1280px; margin: 2em auto; padding: 0 1.5em; }
h1, h2, h3 { line-height: 1.2; margin-top: 1.6em; }
h2 { border-bottom: 1px solid #ccc; padding-bottom: .2em; }
table { border-collapse: collapse; margin: .8em 0; font-size: 13px; }
th, td { border: 1px solid #ccc; padding: .25em .6em; text-align: left; vertical-align: top; }
th { background: #f3f3f3; }
tr:nth-child(even) td { background: #fafafa; }
code, pre { font-family: Menlo, Consolas, monospace; font-size: 12.5px; background: #f4f4f4; }
pre { padding: .6em; overflow-x: auto; }
figure { margin: 1em 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #e2e2e2; }
figcaption { color: #555; font-size: 13px; margin-top: .3em; }
.missing { color: #a00; }
.figref { font-size: 13px; }
"""
_HEADING = re.compile(r"^(#{1,6})\s+(.*)$")
_IMAGE_LINE = re.compile(r"^!\[([^\]]*)\]\(([^)\s]+)\)\s*$")
_BULLET = re.compile(r"^\s*[-*]\s+(.*)$")
_NUMBERED = re.compile(r"^\s*\d+[.)]\s+(.*)$")
_TABLE_SEP = re.compile(r"^\|?\s*:?-{3,}:?\s*(\|\s*:?-{3,}:?\s*)*\|?\s*$")


def write_html(path: str | Path, md_path: str | Path) -> Path:
    """Write ``path`` (report.html) from the Markdown file ``md_path``, its images read
    relative to the Markdown file's folder; atomically."""
    md_path = Path(md_path)
    text = md_path.read_text(encoding="utf-8")
    title = next((m.group(2) for m in map(_HEADING.match, text.splitlines()) if m), md_path.stem)
    return atomic_write_text(path, markdown_html(text, md_path.parent, title))


def markdown_html(md: str, base: str | Path | None = None, title: str = "report") -> str:
    """A complete HTML page of the Markdown text ``md``; images relative to ``base`` are
    embedded (a missing image is named in red instead)."""
    body = _blocks(md.splitlines(), Path(base) if base is not None else None)
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{html.escape(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n"
        + "\n".join(body)
        + "\n</body>\n</html>\n"
    )


def _blocks(lines: list[str], base: Path | None) -> list[str]:
    """The HTML blocks of the Markdown lines."""
    out: list[str] = []
    para: list[str] = []
    seen: set[str] = set()  # images already embedded: a repeat links to the first
    i = 0

    def flush() -> None:
        if para:
            out.append(f"<p>{_inline(' '.join(para), base)}</p>")
            para.clear()

    while i < len(lines):
        line = lines[i]
        if line.startswith("```"):
            flush()
            j = i + 1
            while j < len(lines) and not lines[j].startswith("```"):
                j += 1
            out.append("<pre><code>" + html.escape("\n".join(lines[i + 1 : j])) + "</code></pre>")
            i = j + 1
            continue
        if not line.strip():
            flush()
        elif m := _HEADING.match(line):
            flush()
            n = len(m.group(1))
            out.append(f"<h{n}>{_inline(m.group(2), base)}</h{n}>")
        elif m := _IMAGE_LINE.match(line):
            flush()
            out.append(_figure(m.group(1), m.group(2), base, seen))
        elif line.lstrip().startswith("|"):
            flush()
            j = i
            while j < len(lines) and lines[j].lstrip().startswith("|"):
                j += 1
            out.append(_table(lines[i:j], base))
            i = j
            continue
        elif _BULLET.match(line) or _NUMBERED.match(line):
            flush()
            pattern, tag = (_BULLET, "ul") if _BULLET.match(line) else (_NUMBERED, "ol")
            items = []
            while i < len(lines) and (m := pattern.match(lines[i])):
                items.append(f"<li>{_inline(m.group(1), base)}</li>")
                i += 1
            out.append(f"<{tag}>\n" + "\n".join(items) + f"\n</{tag}>")
            continue
        else:
            para.append(line.strip())
        i += 1
    flush()
    return out


def _cells(line: str) -> list[str]:
    """The cells of a pipe-table row."""
    s = line.strip()
    s = s[1:] if s.startswith("|") else s
    s = s[:-1] if s.endswith("|") else s
    return [c.strip() for c in s.split("|")]


def _table(lines: list[str], base: Path | None) -> str:
    """A table from pipe rows: a header when the second row is the separator."""
    rows = list(lines)
    head: list[str] = []
    if len(rows) >= 2 and _TABLE_SEP.match(rows[1].strip()):
        head, rows = _cells(rows[0]), rows[2:]
    out = ["<table>"]
    if head:
        out.append("<thead><tr>" + "".join(f"<th>{_inline(c, base)}</th>" for c in head) + "</tr></thead>")
    out.append("<tbody>")
    for r in rows:
        out.append("<tr>" + "".join(f"<td>{_inline(c, base)}</td>" for c in _cells(r)) + "</tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def _figure(caption: str, src: str, base: Path | None, seen: set[str]) -> str:
    """An image on its own line: the picture embedded with its caption under it; an image
    already embedded (a figure shared by several methods) links to its first place."""
    cap = html.escape(caption)
    anchor = "fig-" + re.sub(r"[^A-Za-z0-9_-]", "_", src)
    if src in seen:
        return f'<p class="figref"><a href="#{anchor}">Figure above: {cap}</a></p>'
    uri = _data_uri(src, base)
    if uri is None:
        return f'<p class="missing">[figure missing: {html.escape(src)}] {cap}</p>'
    seen.add(src)
    return f'<figure id="{anchor}"><img src="{uri}" alt="{cap}"><figcaption>{cap}</figcaption></figure>'


def _inside(src: str) -> bool:
    """Whether ``src`` is a relative path that stays inside the report's folder (no scheme,
    no root, no parent steps, no backslashes)."""
    if not src or re.match(r"^[A-Za-z][A-Za-z0-9+.-]*:", src) or src.startswith(("/", "~")) or "\\" in src:
        return False
    return ".." not in Path(src).parts


def _safe_href(href: str) -> bool:
    """Whether a link may point at ``href``: an http(s) address or a path inside the folder."""
    return bool(re.match(r"^https?://", href, re.IGNORECASE)) or _inside(href)


def _data_uri(src: str, base: Path | None) -> str | None:
    """A base64 data URI of the PNG file ``src`` (a path inside ``base``, the report's
    folder), None when it is anything else or cannot be read."""
    if base is None or not _inside(src) or not src.lower().endswith(".png"):
        return None
    path = base / src
    try:
        if not path.resolve().is_relative_to(base.resolve()):  # a link out of the folder
            return None
        data = path.read_bytes()
    except OSError:
        return None
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        return None
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


_CODE = re.compile(r"`([^`]+)`")
_BOLD = re.compile(r"\*\*(.+?)\*\*")
_INLINE_IMAGE = re.compile(r"!\[([^\]]*)\]\(([^)\s]+)\)")
_LINK = re.compile(r"\[([^\]]+)\]\(([^)\s]+)\)")
#: a character reference that html.escape turned into text: kept as a reference
_REFERENCE = re.compile(r"&amp;(#[0-9]{1,7}|#x[0-9A-Fa-f]{1,6}|lt|gt|amp|quot);")


def _inline(text: str, base: Path | None) -> str:
    """Escaped text with inline code, bold, images and links; code spans are left as they
    are written."""
    parts = _CODE.split(text)  # odd positions are code
    out = []
    for k, part in enumerate(parts):
        if k % 2:
            out.append(f"<code>{html.escape(part)}</code>")
            continue
        s = _REFERENCE.sub(r"&\1;", html.escape(part, quote=False))
        s = _BOLD.sub(r"<strong>\1</strong>", s)
        s = _INLINE_IMAGE.sub(lambda m: _inline_image(m.group(1), m.group(2), base), s)
        s = _LINK.sub(lambda m: _link(m.group(1), m.group(2)), s)
        out.append(s)
    return "".join(out)


def _link(text: str, href: str) -> str:
    """A link (``text`` already escaped) to ``href`` when it is safe (:func:`_safe_href`),
    else the text with its target shown."""
    target = html.unescape(href)
    if not _safe_href(target):
        return f"{text} ({html.escape(target)})"
    return f'<a href="{html.escape(target)}">{text}</a>'


def _inline_image(alt: str, src: str, base: Path | None) -> str:
    """An image inside a line of text, embedded when it is a PNG of the report's folder."""
    uri = _data_uri(html.unescape(src), base)
    alt = html.escape(html.unescape(alt))
    if uri is None:
        return f'<span class="missing">[image missing: {html.escape(html.unescape(src))}] {alt}</span>'
    return f'<img src="{uri}" alt="{alt}" style="max-width:100%">'
