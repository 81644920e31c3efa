"""Fly a scenario in JSBSim: build the aircraft, trim, fly the maneuvers, sample sensors."""

from __future__ import annotations

import contextlib
import os
import platform
import tempfile
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from operator import call
from pathlib import Path

import numpy as np
import pandas as pd

from sim.aircraft import DERIVATIVES, SERVO_SPAN_US, Aircraft
from sim.errors import ScenarioError
from sim.jsbsim_model import FcsConfig, write_jsbsim_root
from sim.lateral_trim import trim_with_asymmetry
from sim.maneuvers import input_histories
from sim.scenario import THROTTLE_SPAN_US, Scenario
from sim.sensors import sample_sensor
from sim.truth import AUX, FT, LBF, PROPS, PSF, SLUGFT3, TRUTH_UNITS, truth_table
from sim.turbulence import dryden_parameters

#: JSBSim integrators (FGPropagate enum: 1 rectangular Euler, 2 trapezoidal, 3/4/5
#: Adams-Bashforth 2/3/4). JSBSim's default Euler for the body rates adds a numerical
#: pitch damping of order omega^2 dt/2 at 100 Hz - as large as the aerodynamic Mq of a
#: small UAV - so a fitted Cmq would be half the truth. Adams-Bashforth 2 with substeps
#: per sample (scenario key ``substeps``) keeps that error small against the
#: continuous-time model an estimator fits.
INTEGRATORS: dict[str, int] = {
    "rate/rotational": 3,
    "rate/translational": 3,
    "position/rotational": 3,
    "position/translational": 4,
}

#: ft/s, the mean wind that carries the turbulence azimuth (Turbulence.axes)
_AXES_WIND_FPS = 1e-9


@dataclass
class SimResult:
    """Everything one flight produced.

    truth:     DataFrame on the JSBSim time grid t = k / rate_hz, shape (N, len(TRUTH_COLUMNS)),
               SI units (TRUTH_UNITS), noise-free. DESIGN.md section 3 channels (ax ay az:
               specific force at the CG; p q r: inertial body rates; V alpha beta u v w:
               air-relative; h above sea level; de da dr: surface positions; throttle,
               thrust), then p_aero q_aero r_aero (body minus turbulence rates, what the
               aerodynamics use), alphadot, p_turb q_turb r_turb, gust_n gust_e gust_d (NED)
               and gust_u gust_v gust_w (body) air-mass velocities, the coefficients CL CD
               (stability axes) CY (body y) Cl Cm Cn (body, about the CG) as JSBSim computed
               them, de_cmd da_cmd dr_cmd (commands before actuator and limits), de_sas,
               lat lon (deg).
    sensors:   sensor name -> DataFrame (column t at the sensor's own rate, then channels, SI).
    maneuvers: list of (name, axis, t_start, t_end); axis 'de', 'da', 'dr', 'throttle' or
               several joined with '+' (multisine).
    trim:      trim condition (SI + the JSBSim controls).
    meta:      seed, sensor error parameters, turbulence parameters, software versions.
    aero_terms: DataFrame of each derivative's JSBSim force/moment term (N or N m).
    """

    scenario: Scenario
    aircraft: Aircraft
    truth: pd.DataFrame
    sensors: dict[str, pd.DataFrame]
    maneuvers: list[tuple[str, str, float, float]]
    trim: dict[str, float]
    meta: dict
    aero_terms: pd.DataFrame = field(default_factory=pd.DataFrame)


@contextlib.contextmanager
def _quiet_stdout():
    """JSBSim's C++ code prints to fd 1; silence it (it cannot be disabled otherwise)."""
    try:
        fd = os.dup(1)
    except OSError:
        yield
        return
    with open(os.devnull, "w") as dn:
        os.dup2(dn.fileno(), 1)
        try:
            yield
        finally:
            os.dup2(fd, 1)
            os.close(fd)


def _versions() -> dict[str, str]:
    import jsbsim

    return {
        "jsbsim": jsbsim.__version__,
        "numpy": np.__version__,
        "pandas": pd.__version__,
        "python": platform.python_version(),
    }


def _make_fdm(scenario: Scenario, root: Path):
    import jsbsim

    ac = scenario.aircraft
    steps = servo_steps(scenario)
    name = write_jsbsim_root(
        ac,
        FcsConfig(
            scenario.actuator_lag,
            scenario.sas_k_alpha,
            scenario.sas_k_q,
            tuple(steps[a] for a in ("de", "da", "dr")),
            steps["throttle"],
        ),
        root,
    )
    jsbsim.FGJSBBase().debug_lvl = 0
    fdm = jsbsim.FGFDMExec(str(root), None)
    fdm.set_debug_level(0)
    fdm.set_aircraft_path("aircraft")
    fdm.set_engine_path("engine")
    fdm.set_systems_path("systems")
    # the step before the model (loading keeps it): JSBSim's actuator works out its lag
    # filter's (Tustin) coefficients from dt when it loads; set afterwards, a lag_s of
    # 0.05 s acted as 0.01 s (the coefficients of the default 1/120 s step on 1/600 s steps)
    fdm.set_dt(1.0 / (scenario.rate_hz * scenario.substeps))
    if not fdm.load_model(name):
        raise ScenarioError(f"{ac.path}: JSBSim could not load the generated aircraft; check the truth set values")
    for kind, val in INTEGRATORS.items():
        fdm[f"simulation/integrator/{kind}"] = val
    return fdm


def servo_steps(scenario: Scenario) -> dict[str, float]:
    """Command step of each servo, one microsecond of PWM: de, da, dr [rad] (the aircraft's
    servo travel / SERVO_SPAN_US) and throttle [fraction]; all 0 for continuous commands."""
    if not scenario.pwm_servos:
        return {"de": 0.0, "da": 0.0, "dr": 0.0, "throttle": 0.0}
    ac = scenario.aircraft
    return {**{a: ac.travel(a) / SERVO_SPAN_US for a in ("de", "da", "dr")}, "throttle": 1.0 / THROTTLE_SPAN_US}


def servo_meta(scenario: Scenario) -> dict:
    """The flight's servos for SimResult.meta / truth.json: pwm (bool), travel_deg and
    step_deg per surface, span_us, throttle_step."""
    steps = servo_steps(scenario)
    ac = scenario.aircraft
    return {
        "pwm": scenario.pwm_servos,
        "span_us": SERVO_SPAN_US,
        "travel_deg": {a: round(float(np.rad2deg(ac.travel(a))), 9) for a in ("de", "da", "dr")},
        "step_deg": {a: float(np.rad2deg(steps[a])) for a in ("de", "da", "dr")},
        "throttle_step": steps["throttle"],
    }


def _trim(fdm, scenario: Scenario) -> dict[str, float]:
    import jsbsim

    s = scenario
    fdm["simulation/randomseed"] = int(s.turbulence.seed) % 2**31
    fdm["ic/h-sl-ft"] = s.altitude / FT
    fdm["ic/vt-fps"] = s.airspeed / FT
    fdm["ic/gamma-deg"] = np.rad2deg(s.flight_path)
    fdm["ic/psi-true-deg"] = np.rad2deg(s.heading)
    fdm["ic/lat-geod-deg"] = 47.0
    fdm["ic/long-gc-deg"] = 8.0
    fdm["ic/beta-deg"] = 0.0
    fdm["ic/phi-deg"] = 0.0
    fdm["atmosphere/turb-type"] = 0
    if any(s.wind):
        # a steady wind belongs to the initial condition (run_ic and the trim reset FGWinds
        # to it). Setting it keeps the ground speed and changes vt, so the inertial NED
        # velocity is set after it: the air velocity along the heading plus the wind
        wn, we = s.wind
        fdm["ic/vw-mag-fps"] = np.hypot(wn, we) / FT
        fdm["ic/vw-dir-deg"] = np.rad2deg(np.arctan2(we, wn))  # the direction it blows to
        ca = s.airspeed * np.cos(s.flight_path)
        fdm["ic/vn-fps"] = (ca * np.cos(s.heading) + wn) / FT
        fdm["ic/ve-fps"] = (ca * np.sin(s.heading) + we) / FT
        fdm["ic/vd-fps"] = -s.airspeed * np.sin(s.flight_path) / FT
    fdm.run_ic()
    fdm["propulsion/set-running"] = -1
    where = f"{s.path}: trim"
    what = f"{s.aircraft.name} at {s.airspeed} m/s, {s.altitude} m, flight path {np.rad2deg(s.flight_path):.1f} deg"
    try:
        # a laterally asymmetric aircraft trims with aileron, rudder and bank too; a
        # symmetric one flies wings level at zero aileron and rudder
        lateral = trim_with_asymmetry(fdm) if s.aircraft.asymmetric else {}
        if not lateral:
            fdm.do_trim(0)
    except jsbsim.TrimFailureError:
        thr = fdm["fcs/throttle-cmd-norm[0]"]
        hint = (
            "thrust limit reached: lower airspeed_mps/flight_path_deg or raise max_thrust_N"
            if thr > 0.99 or thr < 0.01
            else "elevator cannot balance pitch or lift cannot carry the weight: change airspeed_mps"
        )
        raise ScenarioError(f"{where}: untrimmable: JSBSim cannot trim {what} ({hint})") from None
    thr = fdm["fcs/throttle-cmd-norm[0]"]
    ptrim = fdm["fcs/pitch-trim-cmd-norm"]
    alpha = fdm["aero/alpha-rad"]
    if not (0.0 <= thr <= 1.0) or abs(ptrim) > 0.999 or abs(alpha) > np.deg2rad(15):
        raise ScenarioError(
            f"{where}: untrimmable: {what} needs throttle {thr:.2f}, elevator "
            f"{np.rad2deg(ptrim * s.aircraft.limits['de']):.1f} deg, alpha "
            f"{np.rad2deg(alpha):.1f} deg (outside limits); change airspeed_mps or flight_path_deg"
        )
    return {
        "V": fdm["velocities/vt-fps"] * FT,
        "alpha": alpha,
        "theta": fdm["attitude/theta-rad"],
        "gamma": s.flight_path,
        "h": fdm["position/h-sl-ft"] * FT,
        "de": fdm["fcs/de-pos-rad"],
        "throttle": fdm["fcs/throttle-pos"],
        "thrust": fdm["fcs/thrust-lbf"] * LBF,
        "qbar": fdm["aero/qbar-psf"] * PSF,
        "rho": fdm["atmosphere/rho-slugs_ft3"] * SLUGFT3,
        "pitch_trim_cmd_norm": ptrim,
        "udot": fdm["accelerations/udot-ft_sec2"] * FT,
        "wdot": fdm["accelerations/wdot-ft_sec2"] * FT,
        "qdot": fdm["accelerations/qdot-rad_sec2"],
        "jsbsim_mass_kg": fdm["inertia/mass-slugs"] * 14.593902937206364,
        **lateral,
    }


def fly(
    scenario: Scenario,
    seed: int | None = None,
    workdir: str | os.PathLike | None = None,
    progress: Callable[[float], None] | None = None,
) -> SimResult:
    """Trim and fly ``scenario`` in JSBSim; sample the sensors.

    seed:     overrides the scenario seed (turbulence and sensor noise).
    workdir:  folder for the generated JSBSim XML (default: a temporary folder, removed).
    progress: called with the flown fraction (0..1) about 20 times.
    Raises ScenarioError if the trim condition cannot be trimmed.
    """
    if seed is not None:
        scenario = scenario.with_seed(seed)
    if workdir is None:
        with tempfile.TemporaryDirectory(prefix="fsid-jsbsim-") as tmp:
            return _fly(scenario, Path(tmp), progress)
    root = Path(workdir) / "jsbsim"
    return _fly(scenario, root, progress)


def _fly(s: Scenario, root: Path, progress) -> SimResult:
    ac = s.aircraft
    with _quiet_stdout():  # JSBSim prints trim diagnostics on fd 1
        fdm = _make_fdm(s, root)
        trim = _trim(fdm, s)
    _configure_flight(fdm, s, trim)
    pm = fdm.get_property_manager()
    coef_names = [n for n in (x for v in DERIVATIVES.values() for x in v) if ac.derivatives[n] != 0.0]
    # each property once (aero/qbar-psf is both a truth column and a coefficient reference)
    props = list(dict.fromkeys([p for p, _ in PROPS.values()] + AUX + [f"aero/coefficient/{n}" for n in coef_names]))
    nodes = [pm.get_node(p) for p in props]
    missing = [p for p, n in zip(props, nodes) if n is None]
    if missing:
        raise RuntimeError(f"JSBSim properties missing: {missing}")
    n_steps = int(round(s.duration * s.rate_hz))
    tgrid = np.arange(n_steps + 1) / s.rate_hz
    changes = _input_changes(s, pm, tgrid)
    data = _run(fdm, s, [n.get_double_value for n in nodes], changes, n_steps, progress)
    data = data.reshape(n_steps + 1, len(props))
    truth, terms = truth_table(data, props, coef_names, ac)
    # JSBSim accumulates dt (2.99999999999998 for 3.0); the exact grid is k/rate_hz
    if np.max(np.abs(truth["t"].to_numpy() - tgrid)) > 1e-6:
        raise RuntimeError("JSBSim time base drifted from the sample grid")
    truth["t"] = tgrid
    terms["t"] = tgrid
    rng_seq = np.random.SeedSequence([int(s.seed), 0x5E45])
    sensors = {}
    for (name, spec), child in zip(s.sensors.items(), rng_seq.spawn(len(s.sensors))):
        sensors[name] = sample_sensor(truth, spec, np.random.default_rng(child), s.duration)
    mans = [(m.name, m.axis_label, round(float(m.t_start), 9), round(float(m.t_end), 9)) for m in s.maneuvers]
    return SimResult(
        scenario=s,
        aircraft=ac,
        truth=truth,
        sensors=sensors,
        maneuvers=mans,
        trim=trim,
        meta=_meta(s, trim),
        aero_terms=terms,
    )


def _configure_flight(fdm, s: Scenario, trim: dict[str, float]) -> None:
    """After the trim: whole-microsecond servo commands, the SAS on its trim reference,
    the turbulence model and its seed."""
    # whole-microsecond servo commands from here on (the trim needs continuous ones): the
    # trim deflections move to their nearest PWM step, a small start-up transient as in flight
    fdm["fcs/servo-quantize"] = 1.0
    if s.sas_k_alpha or s.sas_k_q:
        fdm["fcs/sas-alpha-ref-rad"] = trim["alpha"]
        fdm["fcs/sas-on"] = 1.0
    if s.turbulence.model != "off":
        fdm["atmosphere/turb-type"] = 3 if s.turbulence.model == "milspec" else 4
        fdm["atmosphere/turbulence/milspec/windspeed_at_20ft_AGL-fps"] = s.turbulence.windspeed_20ft / FT
        fdm["atmosphere/turbulence/milspec/severity"] = s.turbulence.poe_index
    fdm["simulation/randomseed"] = int(s.turbulence.seed) % 2**31


def _input_changes(s: Scenario, pm, tgrid: np.ndarray) -> dict[int, list]:
    """Sample k -> [(setter, value before, change)] of the maneuver inputs that change at
    k. An input property is set only on the steps where its value changes; between two
    samples it moves linearly over the JSBSim substeps (first-order hold, what an
    estimator interpolating the sampled inputs assumes)."""
    setters = {
        ax: pm.get_node(f"fcs/{ax}-maneuver-rad" if ax != "throttle" else "fcs/throttle-maneuver")
        for ax in ("de", "da", "dr", "throttle")
    }
    inputs = input_histories(list(s.maneuvers), tgrid)
    changes: dict[int, list] = {}
    for ax, hist in inputs.items():
        hist = hist.copy()
        hist[0] = 0.0  # the property's value at the trim point; inputs act from step 1
        ks = np.flatnonzero(np.diff(hist) != 0.0) + 1
        setv = setters[ax].set_double_value
        for k, a, b in zip(ks.tolist(), hist[ks - 1].tolist(), hist[ks].tolist()):
            changes.setdefault(k, []).append((setv, a, b - a))
    return changes


def _run(fdm, s: Scenario, getters: list, changes: dict[int, list], n_steps: int, progress) -> np.ndarray:
    """Fly n_steps samples of s.substeps JSBSim steps each; the properties read by
    ``getters`` at the trim point and after every sample, flat ((n_steps + 1) x
    len(getters),). One row per sample goes to a flat float64 buffer: the C-level map over
    the node getters avoids a Python list per sample."""
    pm = fdm.get_property_manager()
    buf = array("d")
    read = buf.extend
    read(map(call, getters))
    every = max(1, n_steps // 20)
    run = fdm.run
    fracs = [(j + 1) / s.substeps for j in range(s.substeps)]
    heading_axes = s.turbulence.model != "off" and s.turbulence.axes == "aircraft"
    if heading_axes:
        # Turbulence.axes: FGWinds turns its gusts by -psiw (north = cos(psiw) xi_u +
        # sin(psiw) xi_v) and takes psiw from the mean wind, so a wind towards -heading
        # puts xi_u along the heading
        psi_node = pm.get_node("attitude/psi-rad")
        wind_n = pm.get_node("atmosphere/wind-north-fps").set_double_value
        wind_e = pm.get_node("atmosphere/wind-east-fps").set_double_value
    for k in range(1, n_steps + 1):
        if heading_axes:
            psi = psi_node.get_double_value()
            wind_n(_AXES_WIND_FPS * np.cos(psi))
            wind_e(-_AXES_WIND_FPS * np.sin(psi))
        ch = changes.get(k)
        if ch is None:
            for _ in fracs:
                run()
        else:
            for f in fracs:
                for setv, a, d in ch:
                    setv(a + d * f)
                run()
        read(map(call, getters))
        if progress is not None and k % every == 0:
            progress(k / n_steps)
    return np.frombuffer(buf, dtype=np.float64)


def _meta(s: Scenario, trim: dict[str, float]) -> dict:
    """SimResult.meta: seed, sensors, turbulence (with its Dryden parameters), wind, SAS,
    actuator lag, servos, software versions, truth units and the JSBSim settings."""
    turb = {
        "model": s.turbulence.model,
        "severity": s.turbulence.severity,
        "windspeed_20ft_mps": s.turbulence.windspeed_20ft,
        "poe_index": s.turbulence.poe_index,
        "seed": s.turbulence.seed,
        "jsbsim_turb_type": {"off": 0, "milspec": 3, "tustin": 4}[s.turbulence.model],
        "axes": s.turbulence.axes,
    }
    if s.turbulence.model != "off":
        turb.update(dryden_parameters(s.altitude, s.turbulence.windspeed_20ft, s.turbulence.poe_index))
    sas = {
        "k_alpha": s.sas_k_alpha,
        "k_q_s": s.sas_k_q,
        "alpha_ref_rad": trim["alpha"],
        "feedback": "truth alpha and body pitch rate",
    }
    return {
        "seed": s.seed,
        "scenario": s.name,
        "rate_hz": s.rate_hz,
        "duration_s": s.duration,
        "sensors": {k: v.to_dict() for k, v in s.sensors.items()},
        "turbulence": turb,
        "wind": {"north_mps": s.wind[0], "east_mps": s.wind[1], "down_mps": 0.0},
        "sas": sas if (s.sas_k_alpha or s.sas_k_q) else None,
        "actuator_lag_s": s.actuator_lag,
        "servo": servo_meta(s),
        "versions": _versions(),
        "truth_units": TRUTH_UNITS,
        "jsbsim": {
            "dt_s": 1.0 / (s.rate_hz * s.substeps),
            "substeps": s.substeps,
            "integrators": dict(INTEGRATORS),
            "input_hold": "linear between samples (first-order hold over the substeps)",
        },
    }
