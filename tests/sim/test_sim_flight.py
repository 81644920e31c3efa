"""JSBSim flights: coefficient identity, trim, surface inputs, reproducibility, SAS, sensors."""

from __future__ import annotations

import numpy as np
import pytest

import sim
from sim.maneuvers import input_histories
from tests._simdata import custom, flown, quiet_flight, scenario

G0 = 9.80665


@pytest.mark.parametrize("name", ["default", "multiaxis_multisine_turbulence", "unstable_short_period"])
def test_jsbsim_coefficients_equal_the_truth_formula(name):
    r = flown(name)
    T = r.truth
    want = r.aircraft.coefficients(T)
    for c, v in want.items():
        got = T[c].to_numpy()
        assert np.all(np.isfinite(got))
        assert np.max(np.abs(got - v)) < 1e-12 * max(1.0, np.max(np.abs(v))), c
        assert np.std(got) > 0, f"{c} not excited"
    if name == "multiaxis_multisine_turbulence":  # alphadot and rate terms really act
        ac = r.aircraft
        assert ac.derivatives["CLalphadot"] != 0 and np.std(T["alphadot"]) > 0.01
        qS = T["qbar"] * ac.S
        np.testing.assert_allclose(
            r.aero_terms["Cmalphadot"],
            qS * ac.cbar * ac.derivatives["Cmalphadot"] * T["alphadot"] * ac.cbar / (2 * T["V"]),
            rtol=1e-9,
            atol=1e-12,
        )
        np.testing.assert_allclose(
            r.aero_terms["Clp"],
            qS * ac.b * ac.derivatives["Clp"] * T["p_aero"] * ac.b / (2 * T["V"]),
            rtol=1e-9,
            atol=1e-12,
        )
        # aero rates are body rates minus turbulence rates
        np.testing.assert_allclose(T["q_aero"], T["q"] - T["q_turb"], atol=1e-12)
        assert np.std(T["q_turb"]) > 1e-3


@pytest.mark.parametrize("lag", [0.02, 0.05])
def test_actuator_lag_is_the_scenario_time_constant(tmp_path, lag):
    """A surface step through the actuator is 1 - 1/e of the way after lag_s. JSBSim works
    out the lag filter's coefficients when it loads the model: with the step size set
    after loading, lag_s = 0.05 acted as 0.01 s (the coefficients of its default 1/120 s
    step, run on 1/600 s steps)."""
    from sim.flight import _make_fdm

    raw = dict(scenario("default").raw)
    raw["actuators"] = {"lag_s": lag}
    fdm = _make_fdm(custom(raw), tmp_path)
    fdm.run_ic()
    for _ in range(5):
        fdm.run()
    p0, c0 = fdm["fcs/de-pos-rad"], fdm["fcs/de-cmd-rad"]
    fdm["fcs/de-maneuver-rad"] = 0.1
    n = int(round(lag / fdm.get_delta_t()))
    frac = []
    for _ in range(2 * n):
        fdm.run()
        frac.append((fdm["fcs/de-pos-rad"] - p0) / (fdm["fcs/de-cmd-rad"] - c0))
    assert abs(frac[n - 1] - (1 - np.exp(-1))) < 0.02, frac[n - 1]
    assert abs(frac[2 * n - 1] - (1 - np.exp(-2))) < 0.02, frac[2 * n - 1]


@pytest.mark.parametrize("aircraft, h, V", [("uav_small", 150.0, 30.0), ("light_aircraft", 1500.0, 67.0)])
def test_calm_trim_holds_for_30_s_without_input(aircraft, h, V):
    """JSBSim's trim, with continuous servo commands, holds; with the default PWM servos
    (whole microseconds) the trim deflections and throttle move to their nearest step at
    the start: a small transient, and every command on the step grid afterwards."""
    r = quiet_flight(aircraft, h, V, pwm_servos=False)
    T = r.truth
    assert T["t"].iloc[-1] == pytest.approx(30.0)
    assert np.max(np.abs(np.rad2deg(T["alpha"] - T["alpha"].iloc[0]))) < 0.1
    assert np.max(np.abs(T["V"] - T["V"].iloc[0])) < 0.1
    assert r.meta["servo"]["step_deg"] == {"de": 0.0, "da": 0.0, "dr": 0.0}
    pwm = quiet_flight(aircraft, h, V)
    P, step = pwm.truth, np.deg2rad(pwm.meta["servo"]["step_deg"]["de"])
    assert step == pytest.approx(np.deg2rad(30.0 / 400))
    de = P["de"].to_numpy()[1:]
    assert np.max(np.abs(de / step - np.round(de / step))) < 1e-6
    assert 0 < abs(de[0] - r.trim["de"]) <= step / 2 + 1e-12
    assert np.max(np.abs(P["V"] - P["V"].iloc[0])) < 1.0
    assert np.max(np.abs(np.rad2deg(P["alpha"] - P["alpha"].iloc[0]))) < 0.1
    assert T["V"].iloc[0] == pytest.approx(V, abs=1e-6) and T["h"].iloc[0] == pytest.approx(h, abs=1e-3)
    assert abs(r.trim["udot"]) < 1e-3 and abs(r.trim["wdot"]) < 1e-3 and abs(r.trim["qdot"]) < 1e-4
    # thrust model: throttle * max thrust
    assert T["thrust"].iloc[0] == pytest.approx(T["throttle"].iloc[0] * r.aircraft.max_thrust, rel=1e-12)


def test_specific_force_is_that_of_the_cg():
    """ax, ay, az (= non-gravitational force / mass) satisfy the rigid-body kinematics
    a = dv/dt + w x v - g in body axes, with v the inertial velocity."""
    T = flown("longitudinal_3211_calm").truth
    ph, th, ps = (T[c].to_numpy() for c in ("phi", "theta", "psi"))
    cph, sph, cth, sth, cps, sps = np.cos(ph), np.sin(ph), np.cos(th), np.sin(th), np.cos(ps), np.sin(ps)
    R = np.array(
        [
            [cth * cps, cth * sps, -sth],
            [sph * sth * cps - cph * sps, sph * sth * sps + cph * cps, sph * cth],
            [cph * sth * cps + sph * sps, cph * sth * sps - sph * cps, cph * cth],
        ]
    )  # NED -> body
    vned = np.vstack([T["vn"], T["ve"], T["vd"]])
    vb = np.einsum("ijn,jn->in", R, vned)
    w = np.vstack([T["p"], T["q"], T["r"]])
    dv = np.gradient(vb, T["t"].to_numpy(), axis=1)
    acc = dv + np.cross(w.T, vb.T).T - R[:, 2, :] * G0
    meas = np.vstack([T["ax"], T["ay"], T["az"]])
    err = np.abs(acc - meas)[:, 5:-5]
    # quiet flight: gravity, signs and the CG location agree to a few mm/s^2; during the
    # 1.6 g pull-ups JSBSim's multistep integrators put the velocity about half a frame
    # off the rates (0.5*dt*qdot*V ~ 0.4 m/s^2), which bounds the worst samples
    assert np.median(err) < 0.005
    assert np.percentile(err, 90) < 0.05 and np.max(err) < 0.6
    assert np.std(meas[2]) > 0.5


def _pwm_step(x, step: float):
    """``x`` rounded to the nearest multiple of ``step`` as the sim's servos do (half up)."""
    return step * np.floor(np.asarray(x) / step + 0.5)


@pytest.mark.parametrize("name", ["longitudinal_3211_calm", "lateral_doublets_calm", "multiaxis_multisine_turbulence"])
def test_surfaces_follow_the_designed_maneuvers(name):
    r = flown(name)
    T = r.truth
    u = input_histories(list(r.scenario.maneuvers), T["t"].to_numpy())
    steps = {
        **{a: np.deg2rad(v) for a, v in r.meta["servo"]["step_deg"].items()},
        "throttle": r.meta["servo"]["throttle_step"],
    }
    trim0 = {"de": r.trim["de"], "da": 0.0, "dr": 0.0, "throttle": r.trim["throttle"]}
    # the servos take whole-microsecond PWM commands (after t = 0, the trim point)
    trim = {ax: _pwm_step(v, steps[ax]) for ax, v in trim0.items()}
    flown_ = T["t"] > 0
    for ax in ("de", "da", "dr", "throttle"):
        want = _pwm_step(trim0[ax] + u[ax], steps[ax])
        assert np.max(np.abs(T[ax] - want)[flown_]) < 1e-12, ax
    for m in r.scenario.maneuvers:
        for ax, amp in zip(m.axes, m.amplitude):
            inside = (T["t"] >= m.t_start) & (T["t"] < m.t_end - 1e-9)
            x = (T[ax] - trim[ax])[inside]
            assert np.max(np.abs(x)) == pytest.approx(abs(amp), rel=2e-3, abs=steps[ax]), (m.name, ax)
            # timing on the designed input (the surfaces are its PWM steps, checked above:
            # a sweep starting from zero shows once it passes half a step)
            on = T["t"][inside & (np.abs(u[ax]) > 1e-9)]
            assert on.iloc[0] == pytest.approx(m.t_start, abs=0.011)
            if m.shape in ("doublet", "3211"):
                assert on.iloc[-1] == pytest.approx(m.t_end - 0.01, abs=1e-6)
                assert np.sign(x[np.abs(x) > steps[ax]].iloc[0]) == np.sign(amp)


def test_same_seed_is_bit_identical_and_other_seeds_differ():
    s = sim.load_scenario(flown("longitudinal_3211_turbulence").scenario.path)
    a, b = sim.fly(s), sim.fly(s)
    assert a.truth.equals(b.truth)
    for k in a.sensors:
        assert a.sensors[k].equals(b.sensors[k])
    c = sim.fly(s, seed=2)
    assert c.meta["seed"] == 2
    assert not np.allclose(a.truth["gust_d"], c.truth["gust_d"])
    assert not np.allclose(a.sensors["imu"]["q"], c.sensors["imu"]["q"])
    # calm air: the seed changes the sensor noise only
    calm = sim.load_scenario(flown("longitudinal_3211_calm").scenario.path)
    x, y = flown("longitudinal_3211_calm"), sim.fly(calm, seed=77)
    assert x.truth.equals(y.truth)
    assert not x.sensors["airdata"].equals(y.sensors["airdata"])


def test_unstable_aircraft_is_held_by_the_sas_with_correlated_inputs():
    r = flown("unstable_short_period")
    T, ac, s = r.truth, r.aircraft, r.scenario
    assert ac.derivatives["Cmalpha"] > 0
    a0 = r.trim["alpha"]
    # JSBSim runs the FCS before it recomputes alpha: the SAS sees alpha one JSBSim step
    # (half a sample) late, so the law holds to within half a sample's change of alpha
    al = T["alpha"].to_numpy()
    alpha_half_back = np.concatenate([[a0], 0.5 * (al[1:] + al[:-1])])
    law = s.sas_k_alpha * (alpha_half_back - a0) + s.sas_k_q * T["q"]
    assert np.max(np.abs(T["de_sas"] - law)) < 0.02 * np.max(np.abs(T["de_sas"]))
    u = input_histories(list(s.maneuvers), T["t"].to_numpy())["de"]
    step = np.deg2rad(r.meta["servo"]["step_deg"]["de"])
    np.testing.assert_allclose(T["de_cmd"][1:], _pwm_step(r.trim["de"] + u + T["de_sas"], step)[1:], atol=1e-12)
    # actuator lag: the position trails the command by about lag_s
    lag = np.argmax(np.correlate(np.diff(T["de"]), np.diff(T["de_cmd"]), "full")) - (len(T) - 2)
    assert 1 <= lag <= 3
    # closed loop: bounded, back to trim after the last maneuver, surface correlated with alpha
    assert np.max(np.abs(T["alpha"] - a0)) < np.deg2rad(5)
    assert abs(T["alpha"].iloc[-1] - a0) < np.deg2rad(0.2)
    assert np.corrcoef(T["de_sas"], T["alpha"])[0, 1] > 0.5
    # the same aircraft without the SAS departs within seconds
    raw = dict(s.raw)
    raw["sas"] = {}
    raw["duration_s"] = 8.0
    raw["maneuver"] = [dict(s.raw["maneuver"][-1], start_s=1.0)]
    open_loop = sim.fly(custom(raw, "unstable_open_loop"))
    assert np.nanmax(np.abs(open_loop.truth["alpha"] - open_loop.trim["alpha"])) > np.deg2rad(10)


def test_sensor_tables_have_their_rates_and_columns():
    r = flown("default")
    want = {
        "imu": (100.0, ["ax", "ay", "az", "p", "q", "r"]),
        "airdata": (50.0, ["V", "alpha", "beta"]),
        "attitude": (50.0, ["phi", "theta", "psi"]),
        "baro": (20.0, ["h"]),
        "surfaces": (100.0, ["de", "da", "dr", "throttle"]),
        "gps": (10.0, ["vn", "ve", "vd", "h"]),
    }
    assert set(r.sensors) == set(want)
    for k, (rate, cols) in want.items():
        df = r.sensors[k]
        assert list(df.columns) == ["t", *cols]
        assert len(df) == int(r.scenario.duration * rate) + 1
        assert np.allclose(np.diff(df["t"]), 1 / rate)
        assert r.meta["sensors"][k]["rate_hz"] == rate


def _expected(r, name):
    from sim.sensors import lever_arm_signals

    spec = r.scenario.sensors[name]
    src = lever_arm_signals(r.truth, spec)
    t = r.sensors[name]["t"].to_numpy()
    tt = r.truth["t"].to_numpy()
    return spec, {c: np.interp(np.maximum(t - spec.delay, 0), tt, src[c]) for c in spec.channels}


def test_sensor_errors_are_applied_as_recorded():
    r = flown("sensor_errors_calm")
    for name in ("imu", "airdata", "baro"):
        spec, x = _expected(r, name)
        meas = r.sensors[name]
        n = len(meas)
        for i, c in enumerate(spec.channels):
            res = meas[c].to_numpy() - ((1 + spec.scale[i]) * x[c] + spec.bias[i])
            sd = np.sqrt(spec.noise[i] ** 2 + spec.quant[i] ** 2 / 12)
            assert abs(res.mean()) < 4 * sd / np.sqrt(n) + 1e-12, (name, c)
            assert res.std() == pytest.approx(sd, rel=0.06), (name, c)
    rec = r.meta["sensors"]
    assert rec["imu"]["bias"]["q"] == pytest.approx(np.deg2rad(-0.25))
    assert rec["airdata"]["scale_factor"]["alpha"] == 0.08 and rec["airdata"]["delay_s"] == 0.04
    assert rec["imu"]["position_m"] == [0.10, 0.02, 0.03]


def test_airdata_delay_is_visible_in_the_data():
    r = flown("sensor_errors_calm")
    spec = r.scenario.sensors["airdata"]
    from sim.sensors import lever_arm_signals

    src = lever_arm_signals(r.truth, spec)
    t = r.sensors["airdata"]["t"].to_numpy()
    meas = (r.sensors["airdata"]["alpha"].to_numpy() - spec.bias[1]) / (1 + spec.scale[1])
    cost = [np.var(meas - np.interp(t - d, r.truth["t"], src["alpha"])) for d in np.arange(0, 0.101, 0.01)]
    assert np.argmin(cost) == 4


def test_mounting_positions_add_the_rotation_terms():
    """Independent cross-product form of the IMU and boom lever-arm terms."""
    r = flown("lateral_doublets_calm")
    T = r.truth
    from sim.sensors import lever_arm_signals

    w = T[["p", "q", "r"]].to_numpy()
    wd = T[["pdot", "qdot", "rdot"]].to_numpy()
    for name in ("imu", "airdata"):
        spec = r.scenario.sensors[name]
        pos = np.broadcast_to(spec.position, w.shape)
        got = lever_arm_signals(T, spec)
        if name == "imu":
            a = T[["ax", "ay", "az"]].to_numpy() + np.cross(wd, pos) + np.cross(w, np.cross(w, pos))
            for i, c in enumerate(("ax", "ay", "az")):
                np.testing.assert_allclose(got[c], a[:, i], atol=1e-12)
        else:
            v = T[["u", "v", "w"]].to_numpy() + np.cross(w, pos)
            np.testing.assert_allclose(got["alpha"], np.arctan2(v[:, 2], v[:, 0]), atol=1e-12)
            np.testing.assert_allclose(got["beta"], np.arcsin(v[:, 1] / np.linalg.norm(v, axis=1)), atol=1e-12)
            assert np.max(np.abs(got["alpha"] - T["alpha"])) > 1e-3  # the boom really sees q x r


def test_flight_matches_the_continuous_equations():
    """The flown longitudinal states equal an accurate (RK4, 5 ms) integration of the
    continuous point-mass-plus-pitch equations with the truth derivatives and the recorded
    inputs (linearly interpolated): what the estimators' longitudinal model will fit.
    Measured: 0.07 % rms in alpha, 0.15 % in q with Adams-Bashforth 2 and two substeps;
    JSBSim's default Euler body-rate integration at 100 Hz gives 5.6 % in alpha."""
    r = flown("longitudinal_3211_calm")
    T, ac = r.truth, r.aircraft
    d = ac.derivatives
    m, S, c, Iyy, g0 = ac.mass, ac.S, ac.cbar, ac.Iyy, 9.80665
    t = T["t"].to_numpy()
    h = 0.005
    tf = np.arange(0.0, 30.0 + h / 2, h / 2)
    de, thrust, rho = (np.interp(tf, t, T[k]) for k in ("de", "thrust", "rho"))

    def f(x, i):
        V, al, th, q = x
        qb, qh = 0.5 * rho[i] * V * V, q * c / (2 * V)
        CL = d["CL0"] + d["CLalpha"] * al + d["CLq"] * qh + d["CLde"] * de[i]
        CD = d["CD0"] + d["CDalpha"] * al + d["CDalpha2"] * al * al + d["CDde"] * de[i]
        Cm = d["Cm0"] + d["Cmalpha"] * al + d["Cmq"] * qh + d["Cmde"] * de[i]
        L, D, gam = qb * S * CL, qb * S * CD, th - al
        return np.array(
            [
                (thrust[i] * np.cos(al) - D) / m - g0 * np.sin(gam),
                q + (-L - thrust[i] * np.sin(al)) / (m * V) + g0 * np.cos(gam) / V,
                q,
                qb * S * c * Cm / Iyy,
            ]
        )

    x = np.array([T["V"][0], T["alpha"][0], T["theta"][0], T["q"][0]])
    out = [x]
    for n in range(int(round(30.0 / h))):
        i = 2 * n
        k1 = f(x, i)
        k2 = f(x + h / 2 * k1, i + 1)
        k3 = f(x + h / 2 * k2, i + 1)
        k4 = f(x + h * k3, i + 2)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(x)
    y = np.array(out)[::2]  # back on the 100 Hz grid
    keep = t <= 30.0 + 1e-9
    for j, name, tol in ((0, "V", 0.003), (1, "alpha", 0.002), (2, "theta", 0.002), (3, "q", 0.003)):
        ref = T[name].to_numpy()[keep]
        rel = np.sqrt(np.mean((y[:, j] - ref) ** 2)) / np.std(ref)
        assert rel < tol, (name, rel)


def test_rigid_body_moments_use_the_truth_inertia_with_textbook_ixz():
    """Euler's moment equations hold with the truth set's Ixz (textbook sign, int x z dm):
    L = Ixx pdot - Ixz (rdot + p q) + (Izz - Iyy) q r, N = Izz rdot - Ixz (pdot - q r) + (Iyy - Ixx) p q."""
    r = flown("lateral_doublets_calm")
    T, ac = r.truth, r.aircraft
    assert ac.Ixz > 0
    qSb = T["qbar"] * ac.S * ac.b
    p, q, rr, pd, rd = (T[c] for c in ("p", "q", "r", "pdot", "rdot"))
    L = ac.Ixx * pd - ac.Ixz * (rd + p * q) + (ac.Izz - ac.Iyy) * q * rr
    N = ac.Izz * rd - ac.Ixz * (pd - q * rr) + (ac.Iyy - ac.Ixx) * p * q
    M = ac.Iyy * T["qdot"] - (ac.Izz - ac.Ixx) * p * rr - ac.Ixz * (rr**2 - p**2)
    scale = np.max(np.abs(qSb * T["Cl"]))
    assert scale > 5.0
    assert np.max(np.abs(L - qSb * T["Cl"])) < 1e-5 * scale
    assert np.max(np.abs(N - qSb * T["Cn"])) < 1e-5 * scale
    assert np.max(np.abs(M - T["qbar"] * ac.S * ac.cbar * T["Cm"])) < 1e-5 * scale


@pytest.mark.parametrize("name", ["lateral_doublets_calm", "multiaxis_multisine_turbulence"])
def test_aero_forces_act_in_stability_axes_and_thrust_along_body_x(name):
    """m a = thrust x_b + L, D in stability axes (rotated by alpha only) + CY along body y,
    also with sideslip."""
    r = flown(name)
    T, ac = r.truth, r.aircraft
    qS = T["qbar"] * ac.S
    L, D, Y = qS * T["CL"], qS * T["CD"], qS * T["CY"]
    a = T["alpha"]
    m = r.trim["jsbsim_mass_kg"]
    assert np.max(np.abs(np.rad2deg(T["beta"]))) > 1.0
    scale = np.max(np.abs(L))
    np.testing.assert_allclose(m * T["ax"], T["thrust"] + L * np.sin(a) - D * np.cos(a), atol=1e-6 * scale)
    np.testing.assert_allclose(m * T["ay"], Y, atol=1e-6 * scale)
    np.testing.assert_allclose(m * T["az"], -L * np.cos(a) - D * np.sin(a), atol=1e-6 * scale)
