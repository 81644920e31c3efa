"""Built-in models: independent formulations agree, and the 6-DoF model is identifiable."""

import numpy as np

from estimators import OutputError, Segment
from estimators.datasets import multistep
from estimators.models import longitudinal, sixdof
from estimators.models.sixdof import body_velocity
from estimators.simulation import simulate_outputs

# Aerosonde-class UAV (scenarios/aircraft/uav_small.toml)
C = {
    "m": 13.5,
    "Ixx": 0.8244,
    "Iyy": 1.135,
    "Izz": 1.759,
    "Ixz": 0.1204,
    "S": 0.55,
    "b": 2.8956,
    "cbar": 0.18994,
    "rho": 1.2075,
    "x_vane": 0.8,
    "x_imu": 0.1,
    "z_imu": 0.02,
}
TRUTH = {
    "CL0": 0.28,
    "CLalpha": 3.45,
    "CLq": 0.0,
    "CLde": 0.36,
    "CD0": 0.03,
    "CDalpha": 0.05,
    "CDalpha2": 0.28,
    "CDde": 0.0,
    "Cm0": -0.02338,
    "Cmalpha": -0.38,
    "Cmq": -3.6,
    "Cmde": -0.5,
    "CYbeta": -0.98,
    "CYp": 0.0,
    "CYr": 0.0,
    "CYda": 0.0,
    "CYdr": -0.17,
    "Clbeta": -0.12,
    "Clp": -0.26,
    "Clr": 0.14,
    "Clda": 0.08,
    "Cldr": 0.105,
    "Cnbeta": 0.25,
    "Cnp": 0.022,
    "Cnr": -0.35,
    "Cnda": 0.06,
    "Cndr": -0.032,
}
TRIM = {"V": 30.0, "alpha": 0.05603, "de": -0.08935, "thrust": 10.0816}


def _segment(t, de, da, dr):
    n = t.size
    u = np.column_stack([TRIM["de"] + de, da, dr, np.full(n, TRIM["thrust"])])
    x0 = [*body_velocity(TRIM["V"], TRIM["alpha"], 0.0), 0.0, 0.0, 0.0, 0.0, TRIM["alpha"]]
    return Segment(t=t, u=u, z=np.zeros((n, 11)), x0=x0)


def test_sixdof_reduces_to_the_longitudinal_model_without_lateral_motion():
    t = np.arange(0, 10, 0.01)
    de = multistep(t, 1.0, 0.3, amplitude=np.radians(2))
    y6 = simulate_outputs(sixdof(C, values=TRUTH), _segment(t, de, 0 * t, 0 * t))
    lon = longitudinal(
        {k: C[k] for k in ("m", "Iyy", "S", "cbar", "rho")} | {"x_vane": 0.8, "x_imu": 0.1, "z_imu": 0.02},
        values={k: v for k, v in TRUTH.items() if k[:2] in ("CL", "CD", "Cm")},
    )
    seg = Segment(
        t=t,
        u=np.column_stack([TRIM["de"] + de, np.full(t.size, TRIM["thrust"])]),
        z=np.zeros((t.size, 7)),
        x0=[TRIM["V"], TRIM["alpha"], TRIM["alpha"], 0.0],
    )
    yl = simulate_outputs(lon, seg)
    for ch in ("V", "alpha", "theta", "q", "ax", "az"):
        # the same physics in other coordinates: equal to the integrators' truncation error
        np.testing.assert_allclose(y6[ch], yl[ch], atol=1e-6 * max(1.0, np.abs(yl[ch]).max()), err_msg=ch)
    assert np.abs(y6[["beta", "p", "r", "phi", "ay"]].to_numpy()).max() < 1e-12
    assert np.ptp(y6["q"]) > 0.1  # the maneuver really moved the aircraft


def test_sixdof_lateral_derivatives_recovered_with_longitudinal_held():
    t = np.arange(0, 14, 0.02)
    da = multistep(t, 1.0, 0.5, (2, -2), np.radians(4))
    dr = multistep(t, 6.0, 0.6, (2, -2), np.radians(4))
    seg = _segment(t, 0 * t, da, dr)
    truth_model = sixdof(C, values=TRUTH)
    clean = simulate_outputs(truth_model, seg).to_numpy()
    sd = np.array([0.3, *np.radians([0.2, 0.2, 0.1, 0.1, 0.1, 0.1, 0.1]), 0.05, 0.05, 0.05])
    seg.z = clean + np.random.default_rng(8).standard_normal(clean.shape) * sd
    lat = ["CYbeta", "CYdr", "Clbeta", "Clp", "Clr", "Clda", "Cldr", "Cnbeta", "Cnp", "Cnr", "Cnda", "Cndr"]
    start = {**TRUTH, **{k: TRUTH[k] * 1.25 for k in lat}}
    res = OutputError(sixdof(C, values=start, free=lat)).fit(seg)
    assert res.converged
    err = {k: abs(res.params[k] - TRUTH[k]) / res.std[k] for k in lat}
    assert max(err.values()) < 3.0, err
    assert np.ptp(clean[:, 6]) > np.radians(5)  # a real bank-angle excursion


def test_sixdof_follows_jsbsim_on_a_lateral_flight():
    """An independent check of the equations: the 6-DoF model with the truth derivatives,
    started from JSBSim's state and driven by its surfaces and thrust, reproduces the
    noise-free JSBSim flight through an aileron doublet and a rudder doublet."""
    from tests._simdata import flown

    r = flown("lateral_doublets_calm")
    tr = r.truth
    ac = r.aircraft.to_dict()
    c = {
        "m": ac["mass"]["mass_kg"],
        "Ixx": ac["mass"]["Ixx_kgm2"],
        "Iyy": ac["mass"]["Iyy_kgm2"],
        "Izz": ac["mass"]["Izz_kgm2"],
        "Ixz": ac["mass"]["Ixz_kgm2"],
        "S": ac["geometry"]["S_m2"],
        "b": ac["geometry"]["b_m"],
        "cbar": ac["geometry"]["cbar_m"],
        "rho": float(tr["rho"].mean()),
        # the specific force at the trim point (t = 0, before the servos move to their PWM
        # steps and start a small transient)
        "g": float(np.sqrt(tr["ax"] ** 2 + tr["ay"] ** 2 + tr["az"] ** 2).iloc[0]),
    }
    model_values = {k: v for k, v in r.aircraft.derivatives.items() if k in TRUTH}
    model = sixdof(c, values=model_values)
    name, axis, t0, t1 = r.maneuvers[0]
    w = tr[(tr["t"] >= t0 - 0.5) & (tr["t"] <= t1 + 4.0)]
    x0 = [*w[["u", "v", "w", "p", "q", "r", "phi", "theta"]].iloc[0]]
    seg = Segment(t=w["t"], u=w[["de", "da", "dr", "thrust"]].to_numpy(), z=np.zeros((len(w), 11)), x0=x0)
    assert np.radians(2) < np.ptp(w["phi"])  # a real roll excursion

    def rms_errors(m):
        y = simulate_outputs(m, seg, inputs="linear")
        return {
            ch: float(np.sqrt(np.mean((y[ch].to_numpy() - w[ch].to_numpy()) ** 2)))
            for ch in ("p", "q", "r", "phi", "beta", "V")
        }

    # rms, not max: the truth table's rates lead its air data by one JSBSim substep, which
    # shows as short spikes at the surface steps
    tol = {
        "p": np.radians(0.1),
        "q": np.radians(0.1),
        "r": np.radians(0.1),
        "phi": np.radians(0.05),
        "beta": np.radians(0.05),
        "V": 0.02,
    }
    err = rms_errors(model)
    assert all(err[ch] < tol[ch] for ch in tol), err
    # the check has teeth: the product of inertia with the wrong sign is far outside
    wrong = rms_errors(sixdof({**c, "Ixz": -c["Ixz"]}, values=model_values))
    assert sum(wrong[ch] > 3 * tol[ch] for ch in tol) >= 3, wrong
