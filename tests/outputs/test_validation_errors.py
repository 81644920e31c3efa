"""A validation check that raises costs its own result only: the error is recorded in the
validation (``errors``), lowers the verdict to CHECK when the check proves the fit, and
report.md says what failed and why where that check's result would be."""

from __future__ import annotations

import dataclasses
import json

import estimators
from estimators.datasets import longitudinal_example
from pipeline.outputs.report import write_report
from pipeline.validation import validate


def test_a_proof_of_match_that_raises_is_one_line_in_report_md(tmp_path):
    """A held-out maneuver whose measurements lack a channel of the model (z has 6 columns
    for 7 outputs): the proof of match raises; the fit, residuals, modes and frequency
    response are still computed, the verdict is CHECK with the reason, report.json keeps
    the error and report.md has it under the proof-of-match heading."""
    ex = longitudinal_example(0, segments=2)
    res = estimators.OutputError(ex.model).fit(ex.segments[:1])
    held = ex.segments[1]
    short = dataclasses.replace(held, z=held.z[:, :-1])
    v = validate(res, held_out=[short], truth=ex.truth)
    why = v["errors"]["proof_of_match"]
    assert why.startswith("ModelDefinitionError: ") and "z has 6 columns" in why
    assert v["proof_of_match"] is None and set(v["errors"]) == {"proof_of_match"}
    assert v["fit"]["tic_ok"] and v["modes"]["table"] and v["frequency"]["table"]
    assert v["verdict"]["level"] == "CHECK"
    assert v["verdict"]["reasons"] == [f"proof of match could not be computed ({why})"]
    md, js = write_report(tmp_path, {"oem": res}, {"oem": v}, truth=ex.truth)
    doc = json.loads(js.read_text())
    assert doc["methods"]["oem"]["validation"]["errors"] == {"proof_of_match": why}
    lines = md.read_text().splitlines()
    i = lines.index("### Proof of match")
    assert lines[i + 2] == f"**Proof of match: not computed** - {why}"
    assert "No held-out maneuver" not in md.read_text()
    # the good held-out maneuver: no error line anywhere
    ok = validate(res, held_out=[held], truth=ex.truth)
    assert ok["errors"] == {} and ok["proof_of_match"]["all_pass"]
    md2, _ = write_report(tmp_path / "ok", {"oem": res}, {"oem": ok}, truth=ex.truth)
    assert "not computed" not in md2.read_text()
