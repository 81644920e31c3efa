"""``fsid estimate --method ls --structure stepwise|mof``: equation error's regressions searched
for the structure the data ask for (pipeline.methods.structure): a lift curve that bends
(alpha^2, which the built-in model lacks) is found, a model term the data do not carry is
said not needed, and the report and its CLI say so."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from pipeline.methods.structure import structure_search
from pipeline.problems.regressions import Regression


def _problem(seed: int = 0) -> SimpleNamespace:
    rng = np.random.default_rng(seed)
    n = 1500
    a, qh, de = rng.uniform(-0.05, 0.25, n), rng.normal(0, 0.01, n), rng.normal(0, 0.05, n)
    CL = 0.25 + 4.8 * a - 5.0 * a**2 + 0.4 * de + 0.01 * rng.standard_normal(n)  # no CLq, a bend
    X = np.column_stack([np.ones(n), a, qh, de])
    return SimpleNamespace(
        regressions=[Regression("CL", ["CL0", "CLalpha", "CLq", "CLde"], X, CL, np.zeros(n, int), np.arange(n) * 0.02)]
    )


@pytest.mark.parametrize("how", ["stepwise", "mof"])
def test_the_bend_is_found_and_the_missing_rate_term_said_not_needed(how):
    st = structure_search(_problem(), how)["CL"]
    assert st["method"] == how and set(st["selected"]) == {"alpha", "alpha^2", "de"}, st["selected"]
    assert st["added"] == ["alpha^2"] and st["not_needed"] == ["CLq"]
    assert {"alpha^3", "alpha*de", "alpha*q"} <= set(st["candidates"])
    assert st["estimates"]["alpha^2"] == pytest.approx(-5.0, abs=4 * st["std"]["alpha^2"])
    assert st["steps"] and all("PSE" in s for s in st["steps"])


def test_structure_needs_equation_error(tmp_path, capsys):
    from pipeline.cli import main

    log = tmp_path / "x.csv"
    log.write_text("t,q\n0,0\n1,0\n")
    assert main(["estimate", str(log), "--structure", "stepwise", "--out", str(tmp_path / "o")]) != 0
    assert "add --method ls" in capsys.readouterr().err


@pytest.mark.slow
def test_the_report_shows_the_structure(tmp_path):
    pytest.importorskip("jsbsim")
    from _simdata import written

    from pipeline.cli import main

    # a lift curve that bends toward stall (CLalpha2 = -4, CLq = 0 in the truth set): the
    # search finds the bend and says the model's CLq is not needed; the pitching moment's
    # structure is the model's (benchmarks/structure_selection.py: 10 of 10 seeds)
    log = written("longitudinal_stall_bend") / "flight.mcap"
    out = tmp_path / "o"
    args = ["estimate", str(log), "--method", "ls", "--structure", "mof", "--no-figures", "--quiet"]
    assert main([*args, "--out", str(out)]) == 0
    st = json.loads((out / "report.json").read_text())["methods"]["ls"]["structure"]
    assert set(st) == {"CL", "CD", "Cm"}
    assert set(st["CL"]["selected"]) == {"alpha", "alpha^2", "de"} and st["CL"]["not_needed"] == ["CLq"]
    assert st["CL"]["estimates"]["alpha^2"] == pytest.approx(-4.0, abs=4 * st["CL"]["std"]["alpha^2"])
    assert set(st["Cm"]["selected"]) == {"alpha", "q", "de"}
    assert "### Model structure (multivariate orthogonal functions)" in (out / "report.md").read_text()
