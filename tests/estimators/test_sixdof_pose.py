"""The 6-DoF model's navigation states, throttle-to-thrust gain and command scaling, and
the both-axes problem built from a pose-only archive."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from estimators import Segment, simulate_outputs
from estimators.models.sixdof import sixdof

CONSTANTS = dict(m=0.063, Ixx=6.9e-4, Iyy=6.0e-4, Izz=1.25e-3, Ixz=0.0, S=0.0555, b=0.617, cbar=0.09, rho=1.225)
ZERO_AERO = {
    k: 0.0 for k in ("CL0", "CLalpha", "CLde", "CD0", "CDalpha", "Cm0", "Cmalpha", "Cmq", "Cmde", "CYbeta", "Cnr")
}
TRAIN = Path(__file__).resolve().parents[3] / "shared" / "data" / "sportcub" / "sportcub_mocap_4_17_26_train.npz"


def test_navigation_integrates_heading_and_position():
    """No aerodynamic force, thrust = kT x throttle: the body accelerates along x at
    kT throttle / m while gravity pulls it down, the track follows the heading."""
    model = sixdof(CONSTANTS, values={**ZERO_AERO, "kT": 0.2}, throttle=True, navigation=True)
    assert model.inputs[-1] == "throttle" and model.states[-4:] == ["psi", "x_n", "y_e", "z_d"]
    t = np.arange(0, 0.51, 0.01)
    psi = np.radians(30.0)
    seg = Segment(t=t, u=np.tile([0.0, 0.0, 0.0, 0.5], (t.size, 1)), z=np.full((t.size, 15), np.nan))
    seg.x0 = np.array([4.0, 0, 0, 0, 0, 0, 0, 0, psi, 0, 0, 0])
    y = simulate_outputs(model, seg, states=True)
    a = 0.2 * 0.5 / 0.063  # thrust / mass, m/s^2
    s = 4.0 * t + 0.5 * a * t**2  # along the heading
    np.testing.assert_allclose(y["x_n"], s * np.cos(psi), atol=1e-9)
    np.testing.assert_allclose(y["y_e"], s * np.sin(psi), atol=1e-9)
    np.testing.assert_allclose(y["z_d"], 0.5 * 9.80665 * t**2, atol=1e-9)
    np.testing.assert_allclose(y["psi"], psi, atol=1e-12)


def test_command_scaling_multiplies_the_surfaces():
    """A normalised elevator command of 0.5 with k_de = 0.4 rad acts as de = 0.2 rad."""
    values = {**ZERO_AERO, "Cmde": -0.5}
    scaled = sixdof({**CONSTANTS, "k_de": 0.4}, values=values, navigation=True)
    plain = sixdof(CONSTANTS, values=values, navigation=True)
    t = np.arange(0, 0.21, 0.01)
    x0 = np.array([4.0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0])
    z = np.full((t.size, 15), np.nan)
    qa = simulate_outputs(scaled, Segment(t=t, u=np.tile([0.5, 0, 0, 0], (t.size, 1)), z=z, x0=x0))["q"]
    qb = simulate_outputs(plain, Segment(t=t, u=np.tile([0.2, 0, 0, 0], (t.size, 1)), z=z, x0=x0))["q"]
    np.testing.assert_allclose(qa, qb, rtol=1e-12)
    assert qa.iloc[-1] < -0.5  # nose down: Cmde < 0 with de > 0


@pytest.mark.skipif(not TRAIN.is_file(), reason="shared Sport Cub data absent")
def test_both_axes_problem_from_a_pose():
    from pipeline.ingest.aircraft_file import read_aircraft_file
    from pipeline.ingest.readers import read_log
    from pipeline.problems.sixdof import sixdof_problem

    air = read_aircraft_file(Path(__file__).resolve().parents[2] / "benchmarks" / "sportcub_aircraft.toml")
    fd = read_log(TRAIN, servo_travel=air.servo_travel, pose={"roll_sign": -1})
    pb = sixdof_problem(fd, air.constants, fd.segments[:2], navigation=True)
    free = [p.name for p in pb.model.parameters if p.free]
    assert "kT" in free and "Clp" in free and "CLalpha" in free  # throttle only: thrust gain estimated
    assert pb.model.inputs[-1] == "throttle"
    seg = pb.fit[0]
    assert seg.z.shape == (250, 15) and np.isfinite(seg.u).all()
    # initial state: body velocity from V, alpha, beta of the pose's first sample
    assert np.hypot(*seg.x0[:3][[0, 2]]) == pytest.approx(np.nanmax(seg.z[:1, 0]), rel=0.05)
