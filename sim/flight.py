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
from sim.maneuvers import input_histories
from sim.scenario import THROTTLE_SPAN_US, Scenario
from sim.sensors import sample_sensor
from sim.turbulence import dryden_parameters

FT = 0.3048
LBF = 4.4482216152605
PSF = 47.880258980335840
SLUGFT3 = 515.3788183931961

#: JSBSim integrators (FGPropagate enum: 1 rectangular Euler, 2 trapezoidal, 3/4/5
#: Adams-Bashforth 2/3/4). JSBSim's default Euler for the body rates adds a numerical
#: pitch damping of order omega^2 dt/2 at 100 Hz - as large as the aerodynamic Mq of a
#: small UAV - so a fitted Cmq would be half the truth. With Adams-Bashforth 2 and two
#: substeps per sample (scenario key ``substeps``) an output-error fit of the
#: continuous-time model to the noise-free truth lands within 0.15 % of every Cm/CL
#: derivative (0.5 % with one substep); see tests/test_sim_flight.py.
INTEGRATORS: dict[str, int] = {
    "rate/rotational": 3,
    "rate/translational": 3,
    "position/rotational": 3,
    "position/translational": 4,
}

#: truth column -> (JSBSim property, factor to SI)
_PROPS: dict[str, tuple[str, float]] = {
    "p": ("velocities/p-rad_sec", 1.0),
    "q": ("velocities/q-rad_sec", 1.0),
    "r": ("velocities/r-rad_sec", 1.0),
    "pdot": ("accelerations/pdot-rad_sec2", 1.0),
    "qdot": ("accelerations/qdot-rad_sec2", 1.0),
    "rdot": ("accelerations/rdot-rad_sec2", 1.0),
    "phi": ("attitude/phi-rad", 1.0),
    "theta": ("attitude/theta-rad", 1.0),
    "psi": ("attitude/psi-rad", 1.0),
    "V": ("velocities/vt-fps", FT),
    "alpha": ("aero/alpha-rad", 1.0),
    "beta": ("aero/beta-rad", 1.0),
    "u": ("velocities/u-aero-fps", FT),
    "v": ("velocities/v-aero-fps", FT),
    "w": ("velocities/w-aero-fps", FT),
    "vn": ("velocities/v-north-fps", FT),
    "ve": ("velocities/v-east-fps", FT),
    "vd": ("velocities/v-down-fps", FT),
    "h": ("position/h-sl-ft", FT),
    "qbar": ("aero/qbar-psf", PSF),
    "rho": ("atmosphere/rho-slugs_ft3", SLUGFT3),
    "de": ("fcs/de-pos-rad", 1.0),
    "da": ("fcs/da-pos-rad", 1.0),
    "dr": ("fcs/dr-pos-rad", 1.0),
    "throttle": ("fcs/throttle-pos", 1.0),
    "thrust": ("fcs/thrust-lbf", LBF),
    "p_aero": ("velocities/p-aero-rad_sec", 1.0),
    "q_aero": ("velocities/q-aero-rad_sec", 1.0),
    "r_aero": ("velocities/r-aero-rad_sec", 1.0),
    "alphadot": ("aero/alphadot-rad_sec", 1.0),
    "p_turb": ("atmosphere/p-turb-rad_sec", 1.0),
    "q_turb": ("atmosphere/q-turb-rad_sec", 1.0),
    "r_turb": ("atmosphere/r-turb-rad_sec", 1.0),
    "gust_n": ("atmosphere/turb-north-fps", FT),
    "gust_e": ("atmosphere/turb-east-fps", FT),
    "gust_d": ("atmosphere/turb-down-fps", FT),
    "de_cmd": ("fcs/de-cmd-rad", 1.0),
    "da_cmd": ("fcs/da-cmd-rad", 1.0),
    "dr_cmd": ("fcs/dr-cmd-rad", 1.0),
    "de_sas": ("fcs/de-sas-rad", 1.0),
    "lat": ("position/lat-geod-deg", 1.0),
    "lon": ("position/long-gc-deg", 1.0),
}
#: raw JSBSim helpers needed to form coefficients and specific forces
_AUX = [
    "simulation/sim-time-sec",
    "forces/fbx-total-lbs",
    "forces/fby-total-lbs",
    "forces/fbz-total-lbs",
    "inertia/mass-slugs",
    "aero/qbar-psf",
    "metrics/Sw-sqft",
    "metrics/bw-ft",
    "metrics/cbarw-ft",
]

#: truth columns, in order (DESIGN.md section 3 first, then the extras)
TRUTH_COLUMNS: tuple[str, ...] = (
    "t",
    "ax",
    "ay",
    "az",
    "p",
    "q",
    "r",
    "pdot",
    "qdot",
    "rdot",
    "phi",
    "theta",
    "psi",
    "V",
    "alpha",
    "beta",
    "u",
    "v",
    "w",
    "vn",
    "ve",
    "vd",
    "h",
    "qbar",
    "rho",
    "de",
    "da",
    "dr",
    "throttle",
    "thrust",
    "p_aero",
    "q_aero",
    "r_aero",
    "alphadot",
    "p_turb",
    "q_turb",
    "r_turb",
    "gust_n",
    "gust_e",
    "gust_d",
    "gust_u",
    "gust_v",
    "gust_w",
    "CL",
    "CD",
    "CY",
    "Cl",
    "Cm",
    "Cn",
    "de_cmd",
    "da_cmd",
    "dr_cmd",
    "de_sas",
    "lat",
    "lon",
)

#: SI unit of every truth column
TRUTH_UNITS: dict[str, str] = {
    "t": "s",
    **{c: "m/s^2" for c in ("ax", "ay", "az")},
    **{c: "rad/s" for c in ("p", "q", "r", "p_aero", "q_aero", "r_aero", "alphadot", "p_turb", "q_turb", "r_turb")},
    **{c: "rad/s^2" for c in ("pdot", "qdot", "rdot")},
    **{
        c: "rad"
        for c in ("phi", "theta", "psi", "alpha", "beta", "de", "da", "dr", "de_cmd", "da_cmd", "dr_cmd", "de_sas")
    },
    **{
        c: "m/s"
        for c in ("V", "u", "v", "w", "vn", "ve", "vd", "gust_n", "gust_e", "gust_d", "gust_u", "gust_v", "gust_w")
    },
    "h": "m",
    "qbar": "Pa",
    "rho": "kg/m^3",
    "throttle": "-",
    "thrust": "N",
    **{c: "-" for c in ("CL", "CD", "CY", "Cl", "Cm", "Cn")},
    "lat": "deg",
    "lon": "deg",
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
    pm = fdm.get_property_manager()
    coef_names = [n for n in (x for v in DERIVATIVES.values() for x in v) if ac.derivatives[n] != 0.0]
    # each property once (aero/qbar-psf is both a truth column and a coefficient reference)
    props = list(dict.fromkeys([p for p, _ in _PROPS.values()] + _AUX + [f"aero/coefficient/{n}" for n in coef_names]))
    nodes = [pm.get_node(p) for p in props]
    missing = [p for p, n in zip(props, nodes) if n is None]
    if missing:
        raise RuntimeError(f"JSBSim properties missing: {missing}")
    getters = [n.get_double_value for n in nodes]
    setters = {
        ax: pm.get_node(f"fcs/{ax}-maneuver-rad" if ax != "throttle" else "fcs/throttle-maneuver")
        for ax in ("de", "da", "dr", "throttle")
    }
    n_steps = int(round(s.duration * s.rate_hz))
    tgrid = np.arange(n_steps + 1) / s.rate_hz
    inputs = input_histories(list(s.maneuvers), tgrid)
    # set an input property only on the steps where its value changes; between two samples
    # an input moves linearly over the JSBSim substeps (first-order hold, what an
    # estimator interpolating the sampled inputs assumes)
    changes: dict[int, list] = {}
    for ax, hist in inputs.items():
        hist = hist.copy()
        hist[0] = 0.0  # the property's value at the trim point; inputs act from step 1
        ks = np.flatnonzero(np.diff(hist) != 0.0) + 1
        setv = setters[ax].set_double_value
        for k, a, b in zip(ks.tolist(), hist[ks - 1].tolist(), hist[ks].tolist()):
            changes.setdefault(k, []).append((setv, a, b - a))
    # one row of len(props) values per sample, appended to a flat float64 buffer: the C-level
    # map over the node getters avoids a Python list per sample (the loop's main overhead
    # after JSBSim itself)
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
    data = np.frombuffer(buf, dtype=np.float64).reshape(n_steps + 1, len(props))
    truth, terms = _truth_table(data, props, coef_names, ac)
    # JSBSim accumulates dt (2.99999999999998 for 3.0); the exact grid is k/rate_hz
    if np.max(np.abs(truth["t"].to_numpy() - tgrid)) > 1e-6:
        raise RuntimeError("JSBSim time base drifted from the sample grid")
    truth["t"] = tgrid
    terms["t"] = tgrid
    rng_seq = np.random.SeedSequence([int(s.seed), 0x5E45])
    sensors = {}
    for (name, spec), child in zip(s.sensors.items(), rng_seq.spawn(len(s.sensors))):
        sensors[name] = sample_sensor(truth, spec, np.random.default_rng(child), s.duration)
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
    meta = {
        "seed": s.seed,
        "scenario": s.name,
        "rate_hz": s.rate_hz,
        "duration_s": s.duration,
        "sensors": {k: v.to_dict() for k, v in s.sensors.items()},
        "turbulence": turb,
        "wind": {"north_mps": s.wind[0], "east_mps": s.wind[1], "down_mps": 0.0},
        "sas": {
            "k_alpha": s.sas_k_alpha,
            "k_q_s": s.sas_k_q,
            "alpha_ref_rad": trim["alpha"],
            "feedback": "truth alpha and body pitch rate",
        }
        if (s.sas_k_alpha or s.sas_k_q)
        else None,
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
    mans = [(m.name, m.axis_label, round(float(m.t_start), 9), round(float(m.t_end), 9)) for m in s.maneuvers]
    return SimResult(
        scenario=s, aircraft=ac, truth=truth, sensors=sensors, maneuvers=mans, trim=trim, meta=meta, aero_terms=terms
    )


def _truth_table(data: np.ndarray, props: list[str], coef_names: list[str], ac: Aircraft):
    col = {p: data[:, i] for i, p in enumerate(props)}
    d: dict[str, np.ndarray] = {"t": col["simulation/sim-time-sec"]}
    m = col["inertia/mass-slugs"]
    for ax, f in (("ax", "fbx"), ("ay", "fby"), ("az", "fbz")):
        d[ax] = col[f"forces/{f}-total-lbs"] / m * FT
    for name, (p, k) in _PROPS.items():
        d[name] = col[p] * k
    # turbulence NED -> body axes (gust_u/v/w: air-mass velocity along body x/y/z)
    ph, th, ps = d["phi"], d["theta"], d["psi"]
    cph, sph, cth, sth, cps, sps = np.cos(ph), np.sin(ph), np.cos(th), np.sin(th), np.cos(ps), np.sin(ps)
    gn, ge, gd = d["gust_n"], d["gust_e"], d["gust_d"]
    d["gust_u"] = cth * cps * gn + cth * sps * ge - sth * gd
    d["gust_v"] = (sph * sth * cps - cph * sps) * gn + (sph * sth * sps + cph * cps) * ge + sph * cth * gd
    d["gust_w"] = (cph * sth * cps + sph * sps) * gn + (cph * sth * sps - sph * cps) * ge + cph * cth * gd
    qs = col["aero/qbar-psf"] * col["metrics/Sw-sqft"]
    ref = {
        "CL": qs,
        "CD": qs,
        "CY": qs,
        "Cl": qs * col["metrics/bw-ft"],
        "Cm": qs * col["metrics/cbarw-ft"],
        "Cn": qs * col["metrics/bw-ft"],
    }
    terms = {"t": d["t"]}
    for coef, names in DERIVATIVES.items():
        tot = np.zeros_like(d["t"])
        unit = LBF if coef in ("CL", "CD", "CY") else LBF * FT
        for n in names:
            if n in coef_names:
                term = col[f"aero/coefficient/{n}"]
                tot = tot + term
                terms[n] = term * unit
        with np.errstate(divide="ignore", invalid="ignore"):
            d[coef] = tot / ref[coef]
    truth = pd.DataFrame({c: d[c] for c in TRUTH_COLUMNS})
    return truth, pd.DataFrame(terms)
