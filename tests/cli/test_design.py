"""``fsid design``: orthogonal multisines for the flight and the accuracy they predict, from
an aircraft file; the prediction scales as it must (double the amplitude, half the std)."""

import json
import os

import numpy as np
import pandas as pd
import pytest

from pipeline.cli import main

AIRCRAFT = "scenarios/aircraft/uav_small.toml"


def _design(tmp_path, *extra: str) -> dict:
    out = tmp_path / "d"
    args = ["design", "--aircraft", AIRCRAFT, "--inputs", "de,da,dr", "--band", "0.1:2.0", "--duration", "20"]
    assert main([*args, "--speed", "20", "--quiet", "--out", str(out), *extra]) == 0
    return json.loads((out / "design.json").read_text()), out


@pytest.mark.slow  # a design and its prediction: the edit loop's tier goes without it
def test_design_writes_the_inputs_and_their_predicted_accuracy(tmp_path):
    doc, out = _design(tmp_path)
    U = pd.read_csv(out / "inputs.csv")
    assert list(U.columns) == ["t", "de", "da", "dr", "de_deg", "da_deg", "dr_deg"] and len(U) == 1001
    np.testing.assert_allclose(U[["de_deg", "da_deg", "dr_deg"]].abs().max(), 3.0)
    np.testing.assert_array_equal(U[["de", "da", "dr"]].iloc[[0, -1]].to_numpy(), 0.0)
    assert all(r <= 1.15 for r in doc["rpf"].values()) and len(doc["frequencies_hz"]["da"]) == 13
    lon, lat = doc["predicted"]["longitudinal"]["parameters"], doc["predicted"]["lateral"]["parameters"]
    assert {"CLalpha", "Cmalpha", "Cmq", "Cmde"} <= set(lon) and {"Clp", "Cnr", "Clda", "Cndr"} <= set(lat)
    assert lon["Cmalpha"]["value"] == pytest.approx(-0.38)  # the truth set's derivative
    assert all(0 < p["std"] < abs(p["value"]) for n, p in {**lon, **lat}.items() if n in ("Cmq", "Clp", "Cnr"))
    for name in ("inputs.csv", "design.json", "fsid_player.lua", "report.md", "report.html", "figures/inputs.png"):
        assert os.stat(out / name).st_mode & 0o044 == 0o044, name
    assert "Predicted accuracy" in (out / "report.md").read_text()
    # the player: the aircraft file gives no [servos], which the report says; the design's
    # harmonics in the script (its sequence is run in tests/outputs/test_lua_player.py)
    pl = doc["player"]
    assert pl["file"] == "fsid_player.lua" and pl["travel_deg"] == {"de": 30.0, "da": 30.0, "dr": 30.0}
    assert "assumed 30 deg for de, da, dr" in pl["travel_from"] and "Flying it" in (out / "report.md").read_text()
    lua = (out / "fsid_player.lua").read_text()
    assert "RCx_OPTION = 300" in lua and f"{doc['frequencies_hz']['da'][-1]:.17g}" in lua


@pytest.mark.slow  # two designs: the edit loop's tier goes without it
def test_twice_the_amplitude_halves_the_predicted_std(tmp_path):
    """The bounds scale as 1 / amplitude for a model linear in the inputs' small motion."""
    a, _ = _design(tmp_path / "a")
    b, _ = _design(tmp_path / "b", "--amplitude", "de=6deg,da=6deg,dr=6deg")
    for axis, names in (("longitudinal", ("Cmq", "Cmde", "CLalpha")), ("lateral", ("Clp", "Cnr", "Clda"))):
        for n in names:
            r = b["predicted"][axis]["parameters"][n]["std"] / a["predicted"][axis]["parameters"][n]["std"]
            assert 0.4 < r < 0.6, (axis, n, r)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--inputs", "de,throttle"], "design inputs are de, da, dr"),
        (["--inputs", "de", "--band", "2:1"], "0 <= LO < HI"),
        (["--inputs", "de,da,dr", "--band", "0.1:0.15"], "harmonics"),
        (["--inputs", "de", "--amplitude", "de=big"], "NAME=VALUE"),
    ],
)
def test_bad_designs_end_in_one_line(tmp_path, capsys, extra, message):
    base = ["design", "--aircraft", AIRCRAFT, "--band", "0.1:2.0", "--duration", "20", "--speed", "20"]
    args = base + extra if "--band" not in extra else [a for a in base if a not in ("--band", "0.1:2.0")] + extra
    assert main([*args, "--out", str(tmp_path / "d"), "--quiet"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


@pytest.mark.slow  # output error on the previous flight
def test_a_previous_flight_adds_its_information(tmp_path):
    """--log: what a flown 3-2-1-1 flight knows per derivative, and both flights together:
    their information added, so no combined std exceeds either flight's (where the two
    flights' correlations differ the two together can do much better than either)."""
    pytest.importorskip("jsbsim")
    from _simdata import written

    log = written("longitudinal_3211_calm") / "flight.mcap"
    doc, out = _design(tmp_path, "--log", str(log))
    lon = doc["predicted"]["longitudinal"]
    assert lon["previous"]["fit"] == "oem" and {"Cmq", "Cmalpha", "CLalpha"} <= set(lon["previous"]["derivatives"])
    for n in lon["previous"]["derivatives"]:
        p = lon["parameters"][n]
        assert p["combined_std"] <= min(p["std"], p["previous_std"]) * (1 + 1e-9), (n, p)
        assert p["gain"] == pytest.approx(p["previous_std"] / p["combined_std"])
    assert abs(lon["parameters"]["Cmq"]["previous_estimate"] - (-3.6)) < 0.5
    assert "previous" not in doc["predicted"]["lateral"]  # the flight flew no lateral maneuver
    assert "has no fit" in doc["previous_note"] and "previous flight std" in (out / "report.md").read_text()
