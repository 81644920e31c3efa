"""Scenario and aircraft files: validation messages, schedules, maneuver shapes."""

from __future__ import annotations

import copy
import tomllib

import numpy as np
import pytest

import sim
from sim.maneuvers import Maneuver, schroeder_multisine
from tests._simdata import SCENARIOS, custom, flown, scenario

BUILTIN = [
    "default",
    "longitudinal_3211_calm",
    "longitudinal_3211_turbulence",
    "lateral_doublets_calm",
    "multiaxis_multisine_turbulence",
    "unstable_short_period",
    "sensor_errors_calm",
    "pitot_wind_turn",
]


def _raw(name: str = "longitudinal_3211_calm") -> dict:
    return tomllib.loads((SCENARIOS / f"{name}.toml").read_text())


@pytest.mark.parametrize("name", BUILTIN)
def test_builtin_scenarios_load_with_two_maneuvers_per_axis(name):
    s = scenario(name)
    assert s.duration > 0 and s.maneuvers
    per_axis: dict[str, list] = {}
    for m in s.maneuvers:
        for ax in m.axes:
            per_axis.setdefault(ax, []).append(m)
    for ax, ms in per_axis.items():
        assert len(ms) >= 2, f"{name}: axis {ax} has only {len(ms)} maneuver"
        ms = sorted(ms, key=lambda m: m.t_start)
        gaps = [b.t_start - a.t_end for a, b in zip(ms, ms[1:])]
        assert min(gaps) >= 4.0, f"{name}: maneuvers on {ax} need quiet time between them, got {gaps}"
    assert max(m.t_end for m in s.maneuvers) <= s.duration


def test_default_is_short_enough_for_the_demo():
    s = scenario("default")
    assert 40 <= s.duration <= 60


@pytest.mark.parametrize(
    "mutate, where, what",
    [
        (lambda r: r.__setitem__("colour", "red"), "colour", "unknown key"),
        (lambda r: r["trim"].pop("airspeed_mps"), "trim.airspeed_mps", "missing field"),
        (lambda r: r.pop("duration_s"), "duration_s", "missing field"),
        (
            lambda r: r["trim"].__setitem__("airspeed_kts", r["trim"].pop("airspeed_mps")),
            "trim.airspeed_kts",
            "wrong unit; write it as trim.airspeed_mps",
        ),
        (
            lambda r: r["maneuver"][0].__setitem__("amplitude_rad", r["maneuver"][0].pop("amplitude_deg")),
            "maneuver[0].amplitude_rad",
            "wrong unit",
        ),
        (
            lambda r: r["maneuver"][0].__setitem__("pulse_ms", r["maneuver"][0].pop("pulse_s")),
            "maneuver[0].pulse_ms",
            "wrong unit",
        ),
        (lambda r: r["maneuver"][0].__setitem__("shape", "wiggle"), "maneuver[0].shape", "must be one of"),
        (lambda r: r["maneuver"][0].__setitem__("axis", "flaps"), "maneuver[0].axis", "must be one of"),
        (lambda r: r.__setitem__("duration_s", 20.0), "maneuver[", "after duration_s"),
        (lambda r: r["maneuver"][1].__setitem__("start_s", 3.5), "maneuver[1]", "overlaps"),
        (lambda r: r["turbulence"].__setitem__("model", "karman"), "turbulence.model", "must be one of"),
        (
            lambda r: r.__setitem__("sensors", {"imu": {"gyro_noise_radps": 0.01}}),
            "sensors.imu.gyro_noise_radps",
            "wrong unit; write it as sensors.imu.gyro_noise_dps",
        ),
        (lambda r: r.__setitem__("aircraft", "aircraft/nope.toml"), "aircraft", "not found"),
        (lambda r: r.__setitem__("substeps", 0), "substeps", "between 1 and 20"),
        (lambda r: r.__setitem__("rate_hz", "fast"), "rate_hz", "finite number"),
        (lambda r: r.__setitem__("validation", {"rate_dps": 2.0}), "validation.rate_dps", "unknown key"),
        (lambda r: r.__setitem__("validation", {"accel_g": -0.1}), "validation.accel_g", "> 0"),
        (lambda r: r.__setitem__("actuators", {"pwm_servos": 1}), "actuators.pwm_servos", "true or false"),
    ],
)
def test_malformed_scenario_fails_with_one_line_naming_the_key(mutate, where, what):
    raw = _raw()
    mutate(raw)
    with pytest.raises(sim.ScenarioError) as err:
        custom(raw)
    msg = str(err.value)
    assert "\n" not in msg
    assert where in msg and what in msg, msg


def test_pwm_servos_default_and_continuous():
    s = scenario("default")
    assert s.pwm_servos and s.aircraft.travel("de") == pytest.approx(np.deg2rad(30.0))
    raw = _raw()
    raw["actuators"] = {"pwm_servos": False}
    assert custom(raw).pwm_servos is False


def test_validation_bands_default_and_from_the_scenario():
    assert scenario("default").pom_bands == {"rate_deg_s": 1.5, "accel_g": 0.1, "angle_deg": 1.5}
    raw = _raw()
    raw["validation"] = {"rate_deg_s": 2.0}
    assert custom(raw).pom_bands == {"rate_deg_s": 2.0, "accel_g": 0.1, "angle_deg": 1.5}


def test_missing_file_and_bad_toml_are_one_line(tmp_path):
    with pytest.raises(sim.ScenarioError, match="not found"):
        sim.load_scenario(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("duration_s = = 3\n")
    with pytest.raises(sim.ScenarioError, match="not valid TOML"):
        sim.load_scenario(bad)


def test_untrimmable_condition_names_the_reason():
    raw = _raw()
    raw["trim"]["airspeed_mps"] = 80.0  # needs more than max_thrust_N
    with pytest.raises(sim.ScenarioError) as err:
        sim.fly(custom(raw))
    msg = str(err.value)
    assert "untrimmable" in msg and "trim" in msg and "\n" not in msg


def test_aircraft_truth_set_validation(tmp_path):
    text = (SCENARIOS / "aircraft" / "uav_small.toml").read_text()
    ac = sim.load_aircraft(SCENARIOS / "aircraft" / "uav_small.toml")
    assert ac.derivatives["Cmalpha"] == -0.38 and ac.S == 0.55 and ac.source
    assert set(ac.derivatives) == set(sim.ALL_DERIVATIVES)
    assert ac.servo_travel == {} and ac.travel("de") == pytest.approx(np.radians(30.0))
    for old, new, expect in [
        ("Cmq = -3.6", "Cmqq = -3.6", "derivatives.Cmqq: unknown derivative"),
        ("S_m2 = 0.55", "S_ft2 = 5.9", "geometry.S_ft2: wrong unit"),
        ("mass_kg = 13.5\n", "", "mass.mass_kg: missing field"),
        ("Clp = -0.26\n", "", "derivatives.Clp: missing field"),
        (
            "[derivatives]",
            "[servos]\nde_travel_deg = 20.0\n[derivatives]",
            "servos.de_travel_deg: 20 deg is less than the surface limit",
        ),
        (
            "[derivatives]",
            "[servos]\nde_travel_rad = 0.5\n[derivatives]",
            "servos.de_travel_rad: wrong unit; write it as servos.de_travel_deg",
        ),
        ("[derivatives]", "[servos]\nflap_travel_deg = 30\n[derivatives]", "servos.flap_travel_deg: unknown key"),
    ]:
        p = tmp_path / "ac.toml"
        p.write_text(text.replace(old, new))
        with pytest.raises(sim.ScenarioError, match=expect.replace(".", r"\.")):
            sim.load_aircraft(p)


def _m(shape, **kw):
    base = dict(name="m", shape=shape, axes=("de",), amplitude=(0.1,), t_start=2.0)
    base.update(kw)
    return Maneuver(**base)


def test_step_shapes_have_designed_timing_and_levels():
    t = np.arange(0, 12, 0.01)
    u = _m("3211", pulse=0.5).signal(t, "de")
    exp = np.select(
        [(t >= 2) & (t < 3.5), (t >= 3.5) & (t < 4.5), (t >= 4.5) & (t < 5.0), (t >= 5.0) & (t < 5.5)],
        [0.1, -0.1, 0.1, -0.1],
        0.0,
    )
    assert np.array_equal(u, exp)
    d = _m("doublet", pulse=0.7)
    assert d.duration == pytest.approx(1.4)
    ud = d.signal(t, "de")
    assert np.all(ud[(t >= 2) & (t < 2.7)] == 0.1) and np.all(ud[(t >= 2.7) & (t < 3.4)] == -0.1)
    assert np.all(ud[(t < 2) | (t >= 3.4)] == 0)
    ms = _m("multistep", pulse=1.0, levels=(1.0, 0.0, -0.5))
    assert ms.signal(np.array([2.5, 3.5, 4.5, 5.5]), "de").tolist() == [0.1, 0.0, -0.05, 0.0]
    assert np.all(u == _m("3211", pulse=0.5).signal(t, "de"))
    assert not np.any(u[(t < 2)]) and _m("3211", pulse=0.5).signal(t, "da").max() == 0


def test_sweeps_hit_their_frequencies():
    t = np.arange(0, 30, 0.001)
    for kind in ("linear", "log"):
        m = _m("sweep", t_start=0.0, f0=0.2, f1=2.0, length=20.0, sweep=kind)
        u = m.signal(t, "de")
        assert np.max(np.abs(u)) == pytest.approx(0.1, rel=1e-3) and not np.any(u[t >= 20])
        zc = t[1:][(np.sign(u[1:]) != np.sign(u[:-1])) & (t[1:] < 19.99)]
        f_inst = 0.5 / np.diff(zc)  # half period between zero crossings
        tm = 0.5 * (zc[1:] + zc[:-1])
        f_design = 0.2 + 1.8 * tm / 20.0 if kind == "linear" else 0.2 * 10.0 ** (tm / 20.0)
        assert np.max(np.abs(f_inst / f_design - 1)) < 0.03
        assert f_design[0] < 0.3 and f_design[-1] > 1.8


def test_multisine_is_schroeder_phased_orthogonal_and_peak_scaled():
    axes = ("de", "da", "dr")
    f, ph, sc = schroeder_multisine(axes, 0.1, 1.5, 10.0)
    allf = np.sort(np.concatenate([f[a] for a in axes]))
    assert np.allclose(allf, np.arange(1, 16) / 10.0)  # every harmonic used once
    assert not set(f["de"]) & set(f["da"]) and not set(f["da"]) & set(f["dr"])
    m = Maneuver(
        "ms",
        "multisine",
        axes,
        (0.02, 0.04, 0.03),
        1.0,
        f0=0.1,
        f1=1.5,
        length=10.0,
        cycles=2,
        harmonics=f,
        phases=ph,
        scale=sc,
    )
    t = 1.0 + np.arange(0, 20, 0.005)
    sig = {a: m.signal(t, a) for a in axes}
    for a, amp in zip(axes, (0.02, 0.04, 0.03)):
        assert np.max(np.abs(sig[a])) == pytest.approx(amp, rel=2e-3)
        rpf = np.max(np.abs(sig[a])) / (np.sqrt(2) * np.std(sig[a]))
        assert rpf < 1.45, f"peak factor {rpf} too high for Schroeder phases"
    # orthogonal over whole periods
    c = np.corrcoef(np.vstack([sig[a] for a in axes]))
    assert np.max(np.abs(c - np.eye(3))) < 1e-6


def test_maneuver_table_matches_the_scenario_schedule():
    r = flown("longitudinal_3211_calm")
    names = [m[0] for m in r.maneuvers]
    assert names == ["elevator_3211_a", "elevator_3211_b", "elevator_doublet", "throttle_step_a", "throttle_step_b"]
    n, ax, t0, t1 = r.maneuvers[1]
    assert ax == "de" and t0 == pytest.approx(3.0 + 2.1 + 8.0) and t1 - t0 == pytest.approx(7 * 0.4)
    assert flown("multiaxis_multisine_turbulence").maneuvers[0][1] == "de+da+dr"


def test_with_seed_changes_turbulence_seed_only():
    s = scenario("longitudinal_3211_turbulence")
    s2 = s.with_seed(99)
    assert s2.seed == 99 and s2.turbulence.seed == 99 and s.seed == 12
    raw = copy.deepcopy(s.raw)
    assert raw["turbulence"]["model"] == "milspec"


def test_multisine_takes_one_amplitude_per_axis():
    raw = tomllib.loads((SCENARIOS / "multiaxis_multisine_turbulence.toml").read_text())
    raw["maneuver"][0]["amplitude_deg"] = [1.5, 4.0, -3.0]
    s = custom(raw)
    assert np.degrees(s.maneuvers[0].amplitude) == pytest.approx([1.5, 4.0, -3.0])
    assert np.degrees(s.maneuvers[1].amplitude) == pytest.approx([-3.0] * 3)  # one value: all axes
    for bad, what in (
        ([1.5, 4.0], "one value per axis (3), got 2"),
        ([1.5, "big", 2.0], "amplitude_deg[1]: must be a finite number"),
        ([1.5, 0.0, 2.0], "amplitude_deg: must not be zero"),
    ):
        raw["maneuver"][0]["amplitude_deg"] = bad
        with pytest.raises(
            sim.ScenarioError,
            match=what.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[").replace("]", r"\]"),
        ):
            custom(raw)
