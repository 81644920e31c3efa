"""The proof of match on a second flight: a scenario's [validation_flight] (sim.scenario) and
``fsid estimate LOG --validate-with LOG2`` (pipeline.jobs.identify.identify(validation=...)): every
maneuver of the first log fitted, the model proved on the second's. Real JSBSim flights
written by the product's writers and read back."""

import copy
import json
import re

import pytest

import sim
from pipeline.cli import main
from pipeline.ingest.readers import read_log
from tests._simdata import SCENARIOS, custom, scenario

VALIDATION = {
    "duration_s": 20.0,
    "maneuver": [{"name": "check_3211", "axis": "de", "shape": "3211", "amplitude_deg": 1.5, "pulse_s": 0.4}],
}


def _with_validation(name: str, **extra) -> dict:
    raw = copy.deepcopy(scenario(name).raw)
    raw["validation_flight"] = {**copy.deepcopy(VALIDATION), **extra}
    return raw


def test_validation_flight_is_a_scenario_of_its_own():
    s = custom(_with_validation("longitudinal_3211_turbulence"), "with_validation")
    v = s.validation
    assert v is not None and v.validation is None
    assert v.name == f"{s.name}-validation" and v.seed == s.seed + 1
    assert v.duration == 20.0 and [m.name for m in v.maneuvers] == ["check_3211"]
    assert s.turbulence.model != "off" and v.turbulence.model == "off"  # calm by default
    # what it shares with the flight
    assert (v.altitude, v.airspeed, v.aircraft.name) == (s.altitude, s.airspeed, s.aircraft.name)
    assert v.raw["sensors"] == s.raw["sensors"] and set(v.sensors) == set(s.sensors)
    # another seed moves both flights, the validation flight keeping its offset
    assert s.with_seed(40).validation.seed == 41
    same = custom(_with_validation("longitudinal_3211_turbulence", turbulence="same", seed=7))
    assert same.validation.seed == 7
    assert same.validation.turbulence.model == s.turbulence.model
    assert same.validation.turbulence.severity == s.turbulence.severity
    assert scenario("default").validation is None


@pytest.mark.parametrize(
    "extra, words",
    [
        ({"turbulence": "calm"}, "validation_flight.turbulence: must be one of off, same"),
        ({"maneuver": []}, "validation_flight.maneuver: a validation flight needs maneuvers"),
        ({"duration_s": 2.0}, "validation_flight.maneuver[0]: 'check_3211' ends at"),
        (
            {"maneuver": [{"name": "x", "axis": "de", "shape": "3211", "amplitude_rad": 0.1}]},
            "validation_flight.maneuver[0].amplitude_rad: wrong unit",
        ),
        ({"lenght_s": 3.0}, "validation_flight.lenght_s: unknown key"),
    ],
)
def test_validation_flight_errors_name_the_table(extra, words):
    with pytest.raises(sim.ScenarioError) as exc:
        custom(_with_validation("longitudinal_3211_calm", **extra))
    assert words in str(exc.value) and "\n" not in str(exc.value)


@pytest.fixture(scope="module")
def two_flights(tmp_path_factory):
    """longitudinal_3211_calm flown three times (seeds 4, 5, 6): flight.mcap with truth.json,
    and second.mcap, third.mcap in the same folder (validation flights: same aircraft and
    sensors)."""
    from pipeline.outputs.writers import write_mcap, write_truth_json

    out = tmp_path_factory.mktemp("two")
    s = sim.load_scenario(SCENARIOS / "longitudinal_3211_calm.toml")
    first = sim.fly(s, seed=4, workdir=out / ".jsbsim")
    write_mcap(out / "flight.mcap", first)
    write_truth_json(out / "truth.json", first)
    write_mcap(out / "second.mcap", sim.fly(s, seed=5, workdir=out / ".jsbsim"))
    write_mcap(out / "third.mcap", sim.fly(s, seed=6, workdir=out / ".jsbsim"))
    return out


def _report(out):
    return json.loads((out / "report.json").read_text())


def test_estimate_validate_with_a_second_flight(two_flights, tmp_path, capsys):
    """Built-in longitudinal model, output error: every elevator maneuver of flight.mcap
    fitted (3), the proof of match on each of second.mcap's (3), the open-loop simulation;
    the default run holds the last one out of the fit instead. Every stage counted once."""
    log, second = two_flights / "flight.mcap", two_flights / "second.mcap"
    n_elev = sum(s.axis == "de" for s in read_log(log).segments)
    n_val = sum(s.axis == "de" for s in read_log(second).segments)
    assert n_elev >= 2 and n_val >= 2
    code = main(
        [
            "estimate",
            str(log),
            "--model",
            "longitudinal",
            "--no-compat",
            "--validate-with",
            str(second),
            "--out",
            str(tmp_path / "v"),
        ]
    )
    err = capsys.readouterr().err
    assert code == 0, err
    stages = [(int(a), int(b)) for a, b in re.findall(r"^\[(\d+)/(\d+)\]", err, flags=re.M)]
    assert {b for _, b in stages} == {len(stages)}, err
    assert "ingest the validation flight" in err
    rep = _report(tmp_path / "v")
    assert rep["meta"]["validation flight"].startswith(str(second))
    m = rep["methods"]["oem"]
    pm = m["validation"]["proof_of_match"]
    assert pm["mode"] == "simulation" and len(pm["segments"]) == n_val
    assert all(sg["name"].startswith("validation flight: auto_de_") for sg in pm["segments"])
    # a calm flight with the model's own structure: the proof of match passes
    assert pm["all_pass"], [
        (sg["name"], {c: d["max_abs_error_display"] for c, d in sg["channels"].items()}) for sg in pm["segments"]
    ]
    # the alphadot derivatives are held: the report says what Cmq then estimates
    assert any("Cmq estimates about Cmq + Cmalphadot" in n for n in m["validation"]["problem"]["notes"])
    # every maneuver of the first log was fitted: one x0 per maneuver
    fitted = {n.split("[")[1].rstrip("]") for n in m["parameters"] if n.startswith("bias_q[")}
    assert len(fitted) == n_elev
    assert (
        main(["estimate", str(log), "--model", "longitudinal", "--no-compat", "--quiet", "--out", str(tmp_path / "d")])
        == 0
    )
    capsys.readouterr()
    d = _report(tmp_path / "d")["methods"]["oem"]
    held = d["validation"]["proof_of_match"]["segments"]
    assert len(held) == 1 and not held[0]["name"].startswith("validation flight")
    assert len({n.split("[")[1].rstrip("]") for n in d["parameters"] if n.startswith("bias_q[")}) == n_elev - 1


def test_validate_with_several_flights(two_flights, tmp_path, capsys):
    """``--validate-with`` repeated: the proof of match on every maneuver of each flight,
    named "validation flight 1: ...", "validation flight 2: ..."; the same flight's
    maneuvers score the same as with it alone; every stage counted once."""
    log, second, third = (two_flights / f"{k}.mcap" for k in ("flight", "second", "third"))
    n = [sum(s.axis == "de" for s in read_log(f).segments) for f in (second, third)]
    code = main(
        [
            "estimate",
            str(log),
            "--model",
            "longitudinal",
            "--no-compat",
            "--validate-with",
            str(second),
            "--validate-with",
            str(third),
            "--out",
            str(tmp_path / "two"),
        ]
    )
    err = capsys.readouterr().err
    assert code == 0, err
    stages = [(int(a), int(b)) for a, b in re.findall(r"^\[(\d+)/(\d+)\]", err, flags=re.M)]
    assert {b for _, b in stages} == {len(stages)}, err
    assert err.count("ingest the validation flight") == 2
    rep = _report(tmp_path / "two")
    assert rep["meta"]["validation flight"].startswith(
        f"validation flight 1: {second}; validation flight 2: {third}: the proof of match"
    )
    segs = rep["methods"]["oem"]["validation"]["proof_of_match"]["segments"]
    names = [sg["name"] for sg in segs]
    assert len(segs) == sum(n) and all(
        nm.startswith(f"validation flight {1 + (i >= n[0])}: auto_de_") for i, nm in enumerate(names)
    )
    assert (
        main(
            [
                "estimate",
                str(log),
                "--model",
                "longitudinal",
                "--no-compat",
                "--quiet",
                "--validate-with",
                str(second),
                "--out",
                str(tmp_path / "one"),
            ]
        )
        == 0
    )
    one = _report(tmp_path / "one")["methods"]["oem"]["validation"]["proof_of_match"]["segments"]
    assert [sg["name"].split(": ")[1] for sg in one] == [nm.split(": ")[1] for nm in names[: n[0]]]
    for a, b in zip(one, segs):
        assert {c: d["max_abs_error_display"] for c, d in a["channels"].items()} == pytest.approx(
            {c: d["max_abs_error_display"] for c, d in b["channels"].items()}, rel=1e-9
        )


def test_user_model_validate_with(two_flights, tmp_path, capsys):
    """A user model (tests/cli/test_estimate_user_model.MODEL_FILE) takes the validation flight
    too: every maneuver fitted, the proof of match on the second log's (and on a third's
    when given twice)."""
    from tests.cli.test_estimate_user_model import MODEL_FILE

    (tmp_path / "sp_user.py").write_text(MODEL_FILE)
    log, second = two_flights / "flight.mcap", two_flights / "second.mcap"
    code = main(
        [
            "estimate",
            str(log),
            "--model",
            f"{tmp_path / 'sp_user.py'}:short_period_user",
            "--no-compat",
            "--quiet",
            "--validate-with",
            str(second),
            "--out",
            str(tmp_path / "u"),
        ]
    )
    assert code == 0, capsys.readouterr().err
    m = _report(tmp_path / "u")["methods"]["oem"]
    segs = m["validation"]["proof_of_match"]["segments"]
    assert len(segs) == len(read_log(second).segments)
    assert all(sg["name"].startswith("validation flight: ") for sg in segs)
    assert len({n for n in m["parameters"] if n.startswith("de0[")}) == len(read_log(log).segments)
    # and on two flights
    third = two_flights / "third.mcap"
    assert (
        main(
            [
                "estimate",
                str(log),
                "--model",
                f"{tmp_path / 'sp_user.py'}:short_period_user",
                "--no-compat",
                "--quiet",
                "--validate-with",
                str(second),
                "--validate-with",
                str(third),
                "--out",
                str(tmp_path / "u2"),
            ]
        )
        == 0
    )
    segs2 = _report(tmp_path / "u2")["methods"]["oem"]["validation"]["proof_of_match"]["segments"]
    assert [sg["name"] for sg in segs2] == (
        [sg["name"].replace("validation flight:", "validation flight 1:") for sg in segs]
        + [f"validation flight 2: {sg.name}" for sg in read_log(third).segments]
    )


@pytest.mark.parametrize(
    "which, words",
    [
        ("same", "that is the log being fitted"),
        ("missing", "nothing.mcap: No such file"),
        ("twice", "that is a validation flight already given"),
    ],
)
def test_validate_with_errors_are_one_line(two_flights, tmp_path, capsys, which, words):
    log = two_flights / "flight.mcap"
    other = {"same": [log], "missing": [two_flights / "nothing.mcap"], "twice": [two_flights / "second.mcap"] * 2}[
        which
    ]
    code = main(
        [
            "estimate",
            str(log),
            "--model",
            "longitudinal",
            "--no-compat",
            "--quiet",
            *[a for o in other for a in ("--validate-with", str(o))],
            "--out",
            str(tmp_path / "e"),
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and words in err[0], err


def test_simulate_writes_the_validation_flight(tmp_path, capsys):
    """``fsid simulate`` of a scenario with a [validation_flight] also writes
    validation.mcap and validation.bin: its own maneuvers and duration."""
    text = (
        (SCENARIOS / "longitudinal_3211_calm.toml")
        .read_text()
        .replace('aircraft = "aircraft/', f'aircraft = "{SCENARIOS}/aircraft/')
    )
    text += (
        "\n[validation_flight]\nduration_s = 20.0\n[[validation_flight.maneuver]]\n"
        'name = "check_3211"\naxis = "de"\nshape = "3211"\namplitude_deg = 1.5\n'
        "pulse_s = 0.4\n"
    )
    path = tmp_path / "with_validation.toml"
    path.write_text(text)
    assert main(["simulate", str(path), "--out", str(tmp_path / "run"), "--seed", "9"]) == 0
    out = capsys.readouterr().out
    assert "validation.mcap" in out and "validation.bin" in out
    flight = read_log(tmp_path / "run" / "flight.mcap")
    assert flight["q"].t[-1] > 60.0
    for name in ("validation.mcap", "validation.bin"):
        fd = read_log(tmp_path / "run" / name)
        assert [s.axis for s in fd.segments] == ["de"], (name, fd.segments)
        assert fd["q"].t[-1] == pytest.approx(20.0, abs=0.2), name


def test_the_instrument_errors_carry_to_the_validation_flight():
    """Of the sensor errors the compatibility stage removed from the fitted flight, the
    scale factors and the air-data delay are removed from the validation flight too (the
    same instruments); the biases, which change with every power-up, are not."""
    import numpy as np

    from pipeline.ingest.flightdata import Channel, FlightData
    from pipeline.jobs.stages import with_instrument_errors_removed

    t = np.arange(0.0, 10.0, 0.02)
    fd = FlightData(
        {
            "q": Channel(t, 0.1 + 1.02 * np.sin(t), "rad/s", "imu"),
            "alpha": Channel(t, 1.05 * np.sin(t - 0.04), "rad", "vane"),
        },
        {},
        [],
    )
    comp = {
        "applied": {
            "scale_q": {"estimate": 0.02, "std": 0.001},
            "bias_q": {"estimate": 0.1, "std": 0.001},
            "scale_alpha": {"estimate": 0.05, "std": 0.01},
            "delay_air": {"estimate": 0.04, "std": 0.002},
        }
    }
    meta: dict = {}
    out = with_instrument_errors_removed(fd, comp, meta)
    assert meta["validation flight corrections"] == {"scale_q": 0.02, "scale_alpha": 0.05, "delay_air": 0.04}
    q = out["q"]
    np.testing.assert_allclose(q.values, 0.1 / 1.02 + np.sin(t), atol=1e-12)  # bias kept
    a = out["alpha"]
    inside = (a.t > 0.1) & (a.t < 9.9)
    np.testing.assert_allclose(a.values[inside], np.sin(a.t[inside]), atol=2e-4)
    assert fd["alpha"].values[5] == 1.05 * np.sin(t[5] - 0.04)  # input untouched
    assert with_instrument_errors_removed(fd, {"applied": {}}) is fd


def test_each_held_out_maneuver_keeps_its_own_flights_step_times():
    """The control-input steps between slow samples (pipeline.conditioning.input_sampling.step_times) that
    the proof of match moves within their timing uncertainty are times of one flight: a
    maneuver proved on a validation flight takes that flight's, not the fitted flight's
    (their clocks overlap)."""
    import numpy as np

    from estimators import Model, Parameter, Segment
    from pipeline.jobs.validation_flights import with_validation_flight
    from pipeline.problems import Problem

    m = Model(
        states=["p"],
        inputs=["da"],
        outputs=["p"],
        parameters=[Parameter("a", -1.0)],
        f=lambda x, u, p, c: (p.a * x[0] + u[0],),
        g=lambda x, u, p, c: (x[0],),
    )
    seg = lambda name: Segment(
        t=np.arange(0.0, 1.0, 0.01),
        u=np.zeros((100, 1)),  # noqa: E731
        z=np.zeros((100, 1)),
        name=name,
    )
    own = Problem("lateral", m, [seg("a")], [seg("b")], [], [], step_times={"da": [(0.2, 0.3, None)]})
    assert own.held_out_step_times() == [{"da": [(0.2, 0.3, None)]}]
    v1 = Problem("lateral", m, [seg("c"), seg("d")], [], [], [], step_times={"da": [(0.5, 0.51, 0.002)]})
    v2 = Problem("lateral", m, [seg("e")], [], [], [], step_times={})
    pb = with_validation_flight(own, [v1, v2], calm=False)
    assert [s.name for s in pb.held_out] == [
        "validation flight 1: c",
        "validation flight 1: d",
        "validation flight 2: e",
    ]
    assert pb.held_out_step_times() == [{"da": [(0.5, 0.51, 0.002)]}] * 2 + [{}]
    assert pb.step_times == own.step_times  # the fitted flight's own
