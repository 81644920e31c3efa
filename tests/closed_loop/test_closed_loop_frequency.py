"""Closed loop: frequency-domain output and equation error (``--method fdoe``, ``fdls``) on
the simulated longitudinal 3-2-1-1 flight, through the command line as a user runs it: the
band from the inputs' spectra and the held trim terms said in the report, the short-period
derivatives within 3 reported std of the truth, the reported std the larger of the
reference's bound and the sandwich, and the time-domain proof of match computed."""

import json

import pytest

pytest.importorskip("jsbsim")


def test_fdoe_through_fsid_run(tmp_path):
    from pipeline.cli import main

    out = tmp_path / "run"
    args = ["run", "scenarios/longitudinal_3211_calm.toml", "--method", "fdoe", "--method", "fdls"]
    assert main([*args, "--no-figures", "--quiet", "--out", str(out)]) == 0
    methods = json.loads((out / "report.json").read_text())["methods"]
    m = methods["fdoe"]
    assert m["converged"] and m["std_method"] == "crb|sandwich"
    notes = " ".join(m["validation"]["problem"]["notes"])
    assert "frequency-domain output error on" in notes and "trim terms held" in notes and "Cm0" in notes
    ps = m["parameters"]
    for n in ("CLalpha", "CLde", "Cmalpha", "Cmq", "Cmde"):
        assert abs(ps[n]["error_in_std"]) < 3.0, (n, ps[n])
    assert "Cm0" not in ps  # held: no estimate of its own
    assert m["validation"]["proof_of_match"]["segments"]
    assert "std (CRB or sandwich)" in (out / "report.md").read_text()
    ls = methods["fdls"]
    assert ls["std_method"] == "crb|sandwich" and ls["verdict"]["level"] != "FAIL"
    assert "frequency-domain equation error on" in " ".join(ls["validation"]["problem"]["notes"])
    for n in ("CLalpha", "CLde", "Cmalpha", "Cmq", "Cmde"):
        assert abs(ls["parameters"][n]["error_in_std"]) < 3.0, (n, ls["parameters"][n])
    assert "Cm0" not in ls["parameters"]
