"""One axis maneuvered in turbulence, from a log (no turbulence level known): the filters
fit the gust models whatever the maneuvers (pipeline.jobs.identify._Axis.method_problem), each axis driven
by the other axis' measured motion, with the Dryden gust states - the aerodynamics see
p - p_turb whatever is flown.

The flight: multiaxis_multisine_turbulence (light aircraft, 67 m/s, light Tustin turbulence
in the aircraft's axes) with its multisines on aileron and rudder only, seed 34, its
calm-air validation flight for the proof of match. Measured (fsid estimate flight.mcap
--method fem --method ekf --method ukf --validate-with validation.mcap, ad hoc): the linear
lateral model put FEM's Clp 46, Clda 38, Clbeta 32 std off the truth (EKF, UKF Clp 26);
the gust model every FEM derivative within 2.5 std (EKF 3.6, UKF 4.3; the proof of match
on the validation multisine fails on phi, 1.8 deg against a 1.5 deg band). Flown with
elevator multisines only, the longitudinal FEM went from Cmalpha, Cmde, Cm0 21-23 std off
to within 2.6 (proof of match passes): tests/closed_loop/test_closed_loop_filters.py shows the
longitudinal case on the built-in longitudinal_3211_turbulence.
"""

import json
import re
import sys
from pathlib import Path

import pytest

from pipeline.problems.lateral import LAT_FREE

ROOT = Path(__file__).resolve().parents[2]
LAT = LAT_FREE


def _aileron_rudder_flight(folder: Path, seed: int) -> Path:
    """The scenario with its multisines on aileron and rudder only, flown and written into
    ``folder`` (benchmarks/single_axis_gusts_seeds.py's variant); the run folder."""
    pytest.importorskip("jsbsim")
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from single_axis_gusts_seeds import variant

    from pipeline.jobs.simulate import simulate

    scenario = variant('["da", "dr"]', folder)
    flown = scenario.read_text().partition("[turbulence]")[0]
    assert flown.count('axis = ["da", "dr"]') == 3 and not re.search(r'axis = .*"de"', flown)
    return simulate(scenario, folder / "sim", seed=seed, progress=False)[0]


@pytest.fixture(scope="module")
def lateral_flight(tmp_path_factory):
    return _aileron_rudder_flight(tmp_path_factory.mktemp("lateral_turbulence"), 34)


def test_lateral_filter_error_fits_the_gust_model(lateral_flight, tmp_path):
    from pipeline.jobs.estimate import estimate_log

    out = tmp_path / "est"
    estimate_log(
        lateral_flight / "flight.mcap",
        out,
        methods=["fem"],
        model="lateral",
        compat=False,
        quiet=True,
        validation_log=[lateral_flight / "validation.mcap"],
        figures=False,
    )
    rep = json.loads((out / "report.json").read_text())
    m = rep["methods"]["fem"]
    assert m["model"] == "lateral-measured" and m["converged"]
    assert "turbulence" not in rep["meta"]
    notes = m["validation"]["problem"]["notes"]
    assert any(n.startswith("roll-gust state p_g") for n in notes), notes
    ps = m["parameters"]
    # the roll gust is in the data: its process noise far from 0 (ad hoc 0.118 +- 0.004),
    # its time constant of the Dryden p-gust's order (4 b / (pi V) = 0.21 s; ad hoc 0.50 s)
    assert ps["F_p_g"]["estimate"] > 10 * ps["F_p_g"]["std"]
    assert 0.1 < ps["tau_pg"]["estimate"] < 1.0
    errs = {n: round(abs(ps[n]["error_in_std"]), 2) for n in LAT}
    assert max(errs.values()) < 3.0, errs


def test_filter_error_restarts_when_it_does_not_converge(tmp_path):
    """The same aileron-rudder flight's ArduPilot log, seed 37 (no vanes: beta rebuilt from
    the flight path). Equation error starts the gust model far off in turbulence (CYp 0.87
    for -0.075, Clp -0.13 for -0.48); from there the earlier filter error wandered (F_p_g to 0, tau_pg
    to its bound) and stopped after 30 iterations with Clbeta 230 and CYbeta 204 std off
    the truth. It now refits with the process noise held first, then free
    (pipeline.methods.fitting._fem_restart), and keeps the fit of lower det R: converged, every
    derivative within 5.4 std (Cnbeta, CYbeta 4.9: the rebuilt sideslip's bias, the same
    as started from the truth)."""
    from pipeline.ingest.constants import AircraftConstants
    from pipeline.ingest.readers import read_log
    from pipeline.jobs.fit import fit_and_validate
    from pipeline.jobs.progress import quiet_progress
    from pipeline.jobs.stages import flow_angle_stage
    from pipeline.methods.noise import attach_logged_noise
    from pipeline.problems import multiaxis_problem

    run = _aileron_rudder_flight(tmp_path, 37)
    truth_doc = json.loads((run / "truth.json").read_text())
    fd, ac = flow_angle_stage(read_log(run / "flight.bin"), AircraftConstants.from_truth(truth_doc), quiet_progress())[
        :2
    ]
    pb = multiaxis_problem(fd, ac, "lateral", gust_states=True, rate_hz=50.0, hold_out=0)
    pb.inputs = "linear"
    attach_logged_noise(fd, pb)
    res, val = fit_and_validate(pb, "fem", "lateral axis", truth_doc["derivatives"], quiet_progress())
    # filter error as the reference algorithm converges from these starts itself; the
    # restart is taken only when it does not, and then says so
    note = [n for n in val["problem"]["notes"] if n.startswith("filter error did not converge")]
    assert len(note) <= 1 and all(n.endswith("that fit is kept") for n in note), val["problem"]["notes"]
    assert res.converged
    errs = {n: abs(res.params[n] - truth_doc["derivatives"][n]) / res.std[n] for n in LAT}
    assert max(errs.values()) < 6.0, errs
