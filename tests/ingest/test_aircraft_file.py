"""The aircraft file (pipeline.ingest.aircraft_file): what a real aircraft's owner knows, no
derivative table; ``fsid aircraft init`` writes its template, the pipeline reads it back,
``fsid estimate --aircraft`` takes it; the scenario truth sets stay aircraft files."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

import sim
from pipeline.cli import main
from pipeline.errors import FsidError
from pipeline.ingest.aircraft import aircraft_for_log, servo_travel_for
from pipeline.ingest.aircraft_file import read_aircraft_file
from pipeline.outputs.writers import write_mcap

ROOT = Path(__file__).resolve().parents[2]
TRUTH_SETS = sorted((ROOT / "scenarios" / "aircraft").glob("*.toml"))

#: uav_small as its owner would describe it: no [derivatives], no [limits]
OWNER = """
name = "uav_owner"
[geometry]
S_m2 = 0.55
b_m = 2.8956
cbar_m = 0.18994
[mass]
mass_kg = 13.5
Ixx_kgm2 = 0.8244
Iyy_kgm2 = 1.135
Izz_kgm2 = 1.759
Ixz_kgm2 = 0.1204
[propulsion]
thrust_per_throttle_N = 40.0
[servos]
de_deg_per_unit = 30.0
[apriori]
Cmq = { value = -5.0, std = 2.0, source = "DATCOM" }
CLalpha = { value = 3.4, rel_std = 0.1 }
"""


def test_init_writes_a_template_the_pipeline_reads_back(tmp_path, capsys):
    path = tmp_path / "my.toml"
    assert main(["aircraft", "init", str(path)]) == 0
    assert f"wrote {path}" in capsys.readouterr().out
    af = read_aircraft_file(path)
    c = af.constants
    assert (c.S, c.b, c.cbar, c.mass, c.Iyy, c.Ixz) == (0.55, 2.0, 0.28, 5.5, 0.55, 0.0)
    assert c.max_thrust == 26.0 and c.thrust_table == ((0.0, 0.25, 0.5, 0.75, 1.0), (0.0, 4.0, 11.0, 19.0, 26.0))
    np.testing.assert_allclose(c.thrust(np.array([0.125, 0.6, 1.0])), [2.0, 14.2, 26.0])
    assert c.apriori["Cmq"] == {"value": -12.0, "std": 4.0, "source": "DATCOM"}
    assert c.apriori["Clp"]["std"] == pytest.approx(0.135)  # rel_std 0.3 of 0.45
    assert c.reversed_inputs == () and c.unstable is False and not af.truth_set
    assert af.servo_travel == {
        "de": (20.0, "de_travel_deg"),
        "da": (18.0, "da_travel_deg"),
        "dr": (25.0, "dr_travel_deg"),
    }
    # what fsid estimate takes from it: constants with the sensor positions, servo travel
    ac, name, truth = aircraft_for_log(tmp_path / "x.mcap", path, None, required=True, say=lambda s: None)
    assert name == "my_aircraft" and truth is None
    assert ac.airdata == (0.45, 0.0, -0.05) and ac.imu == (0.02, 0.0, 0.01)
    assert servo_travel_for(tmp_path / "x.mcap", path)["da"] == (18.0, "aircraft TOML [servos] da_travel_deg")
    # an existing file is kept unless --force; the check command reads it back
    assert main(["aircraft", "init", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists" in err[0] and "--force" in err[0]
    assert main(["aircraft", "init", str(path), "--force"]) == 0
    assert main(["aircraft", "check", str(path)]) == 0
    out = capsys.readouterr().out
    assert "Cmq < 0" in out and "Cmq -12 +- 4" in out


@pytest.mark.parametrize("path", TRUTH_SETS, ids=lambda p: p.stem)
def test_truth_sets_stay_aircraft_files(path):
    """Every scenario truth set reads as an aircraft file with the simulator's numbers; its
    derivative table declares the signs (uav_small's CYdr < 0, uav_unstable's Cmalpha > 0)."""
    af, tr = read_aircraft_file(path), sim.load_aircraft(path)
    c = af.constants
    assert af.truth_set and af.name == tr.name
    assert (c.mass, c.Ixx, c.Iyy, c.Izz, c.Ixz, c.S, c.b, c.cbar, c.max_thrust) == (
        tr.mass,
        tr.Ixx,
        tr.Iyy,
        tr.Izz,
        tr.Ixz,
        tr.S,
        tr.b,
        tr.cbar,
        tr.max_thrust,
    )
    signs = c.expected_signs()
    for name, sign in signs.items():
        assert np.sign(tr.derivatives[name]) == sign, name
    assert signs["Cmq"] == -1 and ("Cmalpha" in signs)


def _with(table: str, body: str) -> str:
    """OWNER with ``[table]`` replaced by (or, absent, given) ``body``; table "" puts
    ``body`` first (top-level keys)."""
    if not table:
        return body + OWNER
    parts = OWNER.split("\n[")
    kept = [p for p in parts[1:] if not p.startswith(table + "]")]
    return "\n[".join([parts[0], *kept]) + f"\n[{table}]\n{body}"


@pytest.mark.parametrize(
    "table, body, where, words",
    [
        ("geometry", "S_m2 = 0.5\ncbar_m = 0.2\n", "geometry.b_m", "missing"),
        ("geometry", "S_m2 = 0.5\nb_m = 2\ncbar_m = 0.2\nb_ft = 6\n", "geometry.b_ft", "write it as b_m"),
        ("mass", "mass_kg = -1\nIxx_kgm2 = 1\nIyy_kgm2 = 1\nIzz_kgm2 = 1\n", "mass.mass_kg", "> 0"),
        ("signs", "de = 'up is positive'\n", "signs.de", "'trailing edge down positive' or"),
        ("apriori", "Cmq = { value = -5.0 }\n", "apriori", "'std' or 'rel_std'"),
        ("apriori", "Cmqq = { value = -5.0, std = 1 }\n", "apriori.Cmqq", "unknown derivative"),
        ("propulsion", "throttle = [0, 0.5, 0.4]\nthrust_N = [0, 5, 9]\n", "propulsion.throttle", "rise"),
        ("propulsion", "max_thrust_N = 20\nthrottle = [0, 1]\nthrust_N = [0, 20]\n", "propulsion", "not both"),
        ("servos", "de_travel_deg = 20\nde_deg_per_unit = 25\n", "servos.de_deg_per_unit", "give one"),
        ("", "statically_unstable = 'yes'\n", "statically_unstable", "true or false"),
        ("", "stall_speed_mps = -3\n", "stall_speed_mps", "above 0"),
        (
            "mass",
            "mass_kg = 13\nIxx_kgm2 = 0.8\nIyy_kgm2 = 1.1\nIzz_kgm2 = 1.7\nIxz_kgm2 = 1.5\n",
            "mass.Ixz_kgm2",
            "Ixz^2 >= Ixx Izz",
        ),
    ],
)
def test_a_bad_aircraft_file_is_one_clear_error(tmp_path, table, body, where, words):
    p = tmp_path / "bad.toml"
    p.write_text(_with(table, body))
    with pytest.raises(FsidError) as e:
        read_aircraft_file(p)
    msg = str(e.value)
    assert f"aircraft file {p}: {where}:" in msg and words in msg and "\n" not in msg, msg


def test_the_stall_speed_is_read(tmp_path):
    p = tmp_path / "micro.toml"
    p.write_text(_with("", "stall_speed_mps = 3.5\n"))
    assert read_aircraft_file(p).constants.stall_speed == 3.5


def test_declared_conventions_and_instability(tmp_path):
    p = tmp_path / "ac.toml"
    p.write_text(
        _with("", "statically_unstable = true\n").replace(
            "[apriori]", "[signs]\nde = 'Trailing-edge up positive'\ndr = 'trailing edge left positive'\n[apriori]"
        )
    )
    c = read_aircraft_file(p).constants
    assert c.unstable and c.reversed_inputs == ("de",) and c.stall_speed is None
    signs = c.expected_signs()
    assert "Cmalpha" not in signs and signs["Cmde"] == 1 and signs["CLde"] == -1 and signs["Cndr"] == -1


@pytest.fixture(scope="module")
def owner_flight(tmp_path_factory):
    """longitudinal_3211_calm flown once, written as flight.mcap with no truth.json next to
    it (a log as a real aircraft's), and the owner's aircraft file."""
    out = tmp_path_factory.mktemp("owner")
    scen = sim.load_scenario(ROOT / "scenarios" / "longitudinal_3211_calm.toml")
    write_mcap(out / "flight.mcap", sim.fly(scen, seed=4, workdir=out / ".jsbsim"))
    (out / "owner.toml").write_text(textwrap.dedent(OWNER))
    return out


@pytest.mark.slow
def test_estimate_takes_an_aircraft_file_without_derivatives_or_limits(owner_flight, tmp_path, capsys):
    out = tmp_path / "o"
    args = ["estimate", str(owner_flight / "flight.mcap"), "--aircraft", str(owner_flight / "owner.toml")]
    fast = ["--model", "longitudinal", "--method", "ls", "--no-compat", "--input-dynamics", "off", "--quiet"]
    assert main([*args, *fast, "--out", str(out)]) == 0, capsys.readouterr().err
    rep = json.loads((out / "report.json").read_text())
    assert rep["meta"]["aircraft"] == "uav_owner" and "truth" not in rep["meta"]
    (m,) = rep["methods"].values()
    pl = m["validation"]["plausibility"]
    assert set(pl["apriori"]) == {"Cmq", "CLalpha"} and pl["apriori"]["Cmq"]["apriori"] == -5.0
    assert pl["signs"]["Cmq"]["expected"] == -1 and not pl["signs"]["Cmq"]["flag"]
    assert m["verdict"]["level"] in ("PASS", "CHECK"), m["verdict"]  # a sound fit of a sound aircraft
    # --priors with an aircraft file that has no [apriori]: one line, non-zero
    bare = tmp_path / "bare.toml"
    bare.write_text(textwrap.dedent(OWNER).split("[apriori]")[0])
    capsys.readouterr()
    code = main(["estimate", str(owner_flight / "flight.mcap"), "--aircraft", str(bare), *fast, "--priors"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "--priors" in err[0] and "[apriori]" in err[0], err
