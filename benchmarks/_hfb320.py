"""The HFB-320 longitudinal case of the reference software's test case 4, replicated by
simulation, for :mod:`benchmarks.first_fit`.

The model is the one of tests/estimators/test_user_model_api.py (states V m/s, alpha rad, theta rad,
q rad/s; inputs elevator de rad and thrust N; outputs V, alpha, theta, q, qdot rad/s^2, ax
and az m/s^2; 11 free derivatives), written as users write it: f and g share a helper.
The data: 601 samples at 10 Hz from the reference's initial state, simulated at the
reference's estimates with an elevator multistep, plus white noise of the reference's
estimated R. The recorded flight is not redistributable, so this replica stands in for it:
the same model, size and noise level, hence the same work for the fit.

This module imports numpy only: the timed process (:func:`timed_fit`) imports estimators
itself, and the import's time is part of what is measured.
"""

from __future__ import annotations

import numpy as np

CONSTANTS = dict(
    g0=9.80665, Sbym=4.028e-3, Scbyiy=8.0027e-4, Feiylt=-7.0153e-6, v0=104.67, rm=7472.0, sigmat=0.0524, rho=0.792
)
#: the reference software's estimates of test case 4: the replica's truth
TRUTH = dict(
    CD0=0.12269,
    CDV=-0.06450,
    CDal=0.32005,
    CL0=-0.09291,
    CLV=0.14873,
    CLal=4.3278,
    Cm0=0.11190,
    CmV=0.00395,
    Cmal=-0.96785,
    Cmq=-34.710,
    Cmde=-1.5291,
)
#: start values (those of tests/estimators/test_user_model_api.py: 2-80 % off the truth there)
START = dict(
    CD0=0.12,
    CDV=-0.065,
    CDal=0.32,
    CL0=-0.092,
    CLV=0.15,
    CLal=4.3,
    Cm0=0.11,
    CmV=0.004,
    Cmal=-0.97,
    Cmq=-35.0,
    Cmde=-1.5,
)
#: the reference's estimated measurement-noise variances (V, alpha, theta, q, qdot, ax, az)
NOISE_VAR = np.array([0.017587, 9.9021e-7, 1.9774e-7, 3.3836e-7, 3.1684e-5, 4.1910e-4, 0.020203])
#: the reference's initial state [V m/s, alpha rad, theta rad, q rad/s]
X0 = np.array([106.023, 0.111685, 0.104887, -0.00332659])
DT, N = 0.1, 601
STATES = ["V", "alpha", "theta", "q"]
INPUTS = ["de", "Fe"]
OUTPUTS = ["V", "alpha", "theta", "q", "qdot", "ax", "az"]


def coefficients(x, u, p, c):
    V, alpha, theta, q = x
    de, Fe = u
    CD = p.CD0 + p.CDV * V / c.v0 + p.CDal * alpha
    CL = p.CL0 + p.CLV * V / c.v0 + p.CLal * alpha
    Cm = p.Cm0 + p.CmV * V / c.v0 + p.Cmal * alpha + p.Cmq * q / c.v0 + p.Cmde * de
    return CD, CL, Cm


def f(x, u, p, c):
    V, alpha, theta, q = x
    de, Fe = u
    CD, CL, Cm = coefficients(x, u, p, c)
    qbar = 0.5 * c.rho * V**2
    Vdot = -c.Sbym * qbar * CD + Fe * np.cos(alpha + c.sigmat) / c.rm + c.g0 * np.sin(alpha - theta)
    alphadot = (
        -c.Sbym * qbar * CL / V + q - Fe * np.sin(alpha + c.sigmat) / (c.rm * V) + c.g0 * np.cos(alpha - theta) / V
    )
    return Vdot, alphadot, q, c.Scbyiy * qbar * Cm + c.Feiylt * Fe


def g(x, u, p, c):
    V, alpha, theta, q = x
    de, Fe = u
    CD, CL, Cm = coefficients(x, u, p, c)
    qbar = 0.5 * c.rho * V**2
    Cx = CL * np.sin(alpha) - CD * np.cos(alpha)
    Cz = -CL * np.cos(alpha) - CD * np.sin(alpha)
    return (
        V,
        alpha,
        theta,
        q,
        c.Scbyiy * qbar * Cm + c.Feiylt * Fe,
        qbar * c.Sbym * Cx + Fe * np.cos(c.sigmat) / c.rm,
        qbar * c.Sbym * Cz - Fe * np.sin(c.sigmat) / c.rm,
    )


def model(values):
    """The model with every parameter free at ``values``."""
    from estimators import Model, Parameter

    return Model(
        states=STATES,
        inputs=INPUTS,
        outputs=OUTPUTS,
        parameters=[Parameter(k, v) for k, v in values.items()],
        constants=CONSTANTS,
        f=f,
        g=g,
        name="hfb320-tc04-replica",
    )


def _pulses(t, t0, unit, pattern, amplitude):
    out = np.zeros_like(t)
    for w in pattern:
        end = t0 + abs(w) * unit
        out[(t >= t0) & (t < end)] = amplitude * np.sign(w)
        t0 = end
    return out


def inputs() -> tuple[np.ndarray, np.ndarray]:
    """t (601,) s at 10 Hz and U (601, 2): elevator (rad) a 3-2-1-1 of 1 s pulses at 2 s,
    a reversed one at 20 s and a 2 s doublet at 40 s about -0.026 rad; thrust 9700 N
    held (the reference flight's is nearly constant)."""
    t = np.arange(N) * DT
    de = (
        -0.026
        + _pulses(t, 2.0, 1.0, (3, -2, 1, -1), 0.03)
        + _pulses(t, 20.0, 1.0, (3, -2, 1, -1), -0.03)
        + _pulses(t, 40.0, 2.0, (1, -1), 0.02)
    )
    return t, np.c_[de, np.full(N, 9700.0)]


def make_data(path: str, seed: int = 0) -> None:
    """Simulate the replica at TRUTH (the package's RK4, default input convention), add the
    noise and save t, u, z, x0 to ``path`` (.npz)."""
    from estimators import Segment, simulate_outputs

    t, U = inputs()
    seg = Segment(t=t, u=U, z=np.zeros((N, len(OUTPUTS))), x0=X0)
    y = simulate_outputs(model(TRUTH), seg).to_numpy()
    z = y + np.random.default_rng(seed).standard_normal(y.shape) * np.sqrt(NOISE_VAR)
    np.savez(path, t=t, u=U, z=z, x0=X0)


def timed_fit(path: str, t_start: float) -> dict:
    """What the timed process does after start-up: import estimators, load the data, build
    the model and fit with OutputError's defaults. Returns the phase times (s, from
    ``t_start``, a ``time.perf_counter()`` taken first thing) and the estimates."""
    import time

    t0 = time.perf_counter()
    from estimators import OutputError, Segment

    t1 = time.perf_counter()
    d = np.load(path)
    seg = Segment(t=d["t"], u=d["u"], z=d["z"], x0=d["x0"])
    res = OutputError(model(START)).fit([seg])
    t2 = time.perf_counter()
    return {
        "before_import": t0 - t_start,
        "import": t1 - t0,
        "fit": t2 - t1,
        "total": t2 - t_start,
        "converged": bool(res.converged),
        "iterations": int(res.iterations),
        "params": {k: float(v) for k, v in res.params.items()},
        "std": {k: float(v) for k, v in res.std.items()},
    }
