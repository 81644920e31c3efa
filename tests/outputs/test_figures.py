"""The report's figures and report.html on a real output-error fit of the HFB-320-like example
(a held-out maneuver, the truth, a wrong model beside it): the job's last stage writes PNGs
that decode to the size drawn and carry real ink, links them from report.md in the method
sections, embeds them in report.html; a figure without its data is a note, not an error."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
from PIL import Image

import estimators
from estimators.datasets import longitudinal_example
from pipeline.jobs.progress import Progress
from pipeline.jobs.write import write_outputs
from pipeline.outputs.figures import section_markdown
from pipeline.outputs.figures.frequency import frequency_figures
from pipeline.outputs.figures.match import match_figures
from pipeline.outputs.figures.refs import NotDrawn, make
from pipeline.outputs.figures.style import DPI, WIDTH
from pipeline.outputs.html import markdown_html
from pipeline.validation import validate

IMAGE = re.compile(r"^!\[([^\]]*)\]\((figures/[^)]+\.png)\)$", re.M)


@pytest.fixture(scope="module")
def fits():
    """An output-error fit validated on a held-out maneuver, and the same result with Cmq
    off by half (a wrong model) validated likewise."""
    ex = longitudinal_example(0, segments=2)
    res = estimators.OutputError(ex.model).fit(ex.segments[:1])
    vals = res.values.copy()
    vals[res.names.index("Cmq")] *= 0.5
    off = dataclasses.replace(res, values=vals)
    return ex, {k: (r, validate(r, held_out=ex.segments[1:], truth=ex.truth)) for k, r in (("oem", res), ("off", off))}


@pytest.fixture(scope="module")
def run(fits, tmp_path_factory):
    """The fitting jobs' last stage on the OEM fit (method key "long-oem")."""
    ex, fitted = fits
    res, v = fitted["oem"]
    out = tmp_path_factory.mktemp("figures")
    write_outputs(out, {"long-oem": res}, {"long-oem": v}, ex.truth, Progress(1, quiet=True), checks=None, meta={})
    return out


def _ink(path) -> tuple[tuple[int, int], float, int]:
    """(size in px, fraction of pixels that are not the background, number of colours)."""
    img = np.asarray(Image.open(path).convert("RGB"))
    background = img[0, 0]
    ink = np.any(np.abs(img.astype(int) - background) > 40, axis=2).mean()
    packed = (img[..., 0].astype(np.int32) << 16) | (img[..., 1].astype(np.int32) << 8) | img[..., 2]
    return (img.shape[1], img.shape[0]), float(ink), int(np.unique(packed).size)


def test_report_md_links_figures_that_exist_and_are_not_blank(run):
    out = run
    md = (out / "report.md").read_text()
    links = IMAGE.findall(md)
    files = {p for _, p in links}
    assert len(files) >= 4, links
    kinds = {re.sub(r"^(long-oem|long)_", "", p.split("/")[1]) for p in files}
    assert {"timehist.png", "residuals.png", "match.png", "estimates.png", "modes.png", "freq.png"} <= kinds
    for p in files:
        size, ink, colours = _ink(out / p)
        assert size[0] == round(WIDTH * DPI), (p, size)  # the width every figure is drawn at
        assert 0.02 < ink < 0.6, (p, ink)  # lines, bands and text; not empty, not a solid block
        assert colours > 50, (p, colours)
        assert (out / p).stat().st_mode & 0o044 == 0o044  # readable by others, like every output
    assert not [p for p in (out / "figures").iterdir() if p.name.startswith(".")]  # no temp files left
    assert "Figure not drawn" not in md


def test_figures_sit_in_their_method_sections(run):
    out = run
    md = (out / "report.md").read_text()
    oem = md[md.index("## LONG-OEM") :]
    for sub, fig in (
        ("### Parameters", "figures/long_estimates.png"),
        ("### Fit and residuals", "figures/long-oem_timehist.png"),
        ("### Modes", "figures/long_modes.png"),
        ("### Proof of match", "figures/long-oem_match.png"),
        ("### Frequency response", "figures/long-oem_freq.png"),
    ):
        assert oem.index(sub) < oem.index(fig), (sub, fig)


def test_wrong_model_shows_its_misses(fits, tmp_path):
    """The held-out prediction of the model with Cmq halved leaves samples outside the band,
    drawn in red: its proof-of-match figure has far more of that red than the right model's."""
    _, fitted = fits
    assert fitted["oem"][1]["proof_of_match"]["all_pass"]
    assert not fitted["off"][1]["proof_of_match"]["all_pass"]

    def red(key):
        (ref,) = match_figures(tmp_path, key, fitted[key][1])
        img = np.asarray(Image.open(tmp_path / ref.path.split("/")[1]).convert("RGB")).astype(int)
        return int(np.sum((np.abs(img - [214, 39, 40]) < 30).all(axis=2)))

    assert red("off") > 20 * max(red("oem"), 1)


def test_report_html_embeds_every_figure(run):
    out = run
    md = (out / "report.md").read_text()
    page = (out / "report.html").read_text()
    links = IMAGE.findall(md)
    assert page.count('src="data:image/png;base64,') == len({p for _, p in links})  # each file once
    assert page.count('<p class="figref"><a href="#fig-') == len(links) - len({p for _, p in links})
    assert page.count("<table>") == len(re.findall(r"^\|---", md, re.M))
    assert 'src="figures/' not in page  # nothing left to fetch: the page is one file
    assert (out / "report.html").stat().st_mode & 0o044 == 0o044


def test_missing_data_is_a_note_not_an_error(fits, tmp_path):
    _, fitted = fits
    res, v = fitted["oem"]
    bare = {k: x for k, x in v.items() if k != "arrays"}  # a validation without its arrays
    assert match_figures(tmp_path, "oem", bare) == [] and frequency_figures(tmp_path, "oem", bare) == []

    def missing(fig):
        raise NotDrawn("no held-out maneuver")

    def broken(fig):
        fig.subplots().plot([1, 2], [1])  # shapes differ: matplotlib raises

    note = make(tmp_path, "x", "fit", "a caption", (4, 3), missing)
    assert note.path is None and note.markdown() == ["Figure not drawn (a caption): no held-out maneuver.", ""]
    bad = make(tmp_path, "y", "fit", "another", (4, 3), broken)
    assert bad.path is None and bad.note.startswith("ValueError")
    assert not list(tmp_path.iterdir())
    lines = section_markdown([note, bad])["fit"]
    assert lines[0].startswith("Figure not drawn (a caption)") and lines[2].startswith("Figure not drawn (another)")


def test_markdown_html_converts_what_report_md_uses(tmp_path):
    (tmp_path / "f.png").write_bytes(b"\x89PNG\r\n\x1a\nxx")
    md = (
        "# Title <x>\n\n- a: 1\n- b: `x_[k]` **bold**\n\nline one\nline two\n\n"
        "| h1 | h2 |\n|---|---|\n| 1 | a<b |\n\n![cap & co](f.png)\n\n![gone](nope.png)\n\n```\nraw <code>\n```\n"
        "\n![again](f.png)\n"
    )
    page = markdown_html(md, tmp_path, "t")
    body = page[page.index("<body>") :]
    assert "<h1>Title &lt;x&gt;</h1>" in body
    assert "<ul>\n<li>a: 1</li>\n<li>b: <code>x_[k]</code> <strong>bold</strong></li>\n</ul>" in body
    assert "<p>line one line two</p>" in body
    assert "<thead><tr><th>h1</th><th>h2</th></tr></thead>" in body and "<td>a&lt;b</td>" in body
    assert '<figure id="fig-f_png"><img src="data:image/png;base64,iVBORw0KGgp4eA==" alt="cap &amp; co">' in body
    assert '<p class="figref"><a href="#fig-f_png">Figure above: again</a></p>' in body
    assert "<figcaption>cap &amp; co</figcaption>" in body
    assert '[figure missing: nope.png]' in body
    assert "<pre><code>raw &lt;code&gt;</code></pre>" in body
