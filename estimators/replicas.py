"""Simulated replicas of the reference software's filter-error test cases, with known truth.

The reference (Jategaonkar's FVSysID, *Flight Vehicle System Identification*, 2nd ed.)
fits two flights in turbulence with its filter-error method; their data are not public.
Each replica keeps the case's model, sample interval, length, initial state, start values
and process noise, takes the reference's estimates as the truth, and flies inputs of our
design through :func:`estimators.process_noise_examples.simulate_with_process_noise`
(ten noise sub-steps per sample):

* :func:`hfb320_replica`: HFB-320 longitudinal, nonlinear, 11 aerodynamic parameters,
  process noise on V, alpha, theta, q (test case 4).
* :func:`lateral_replica`: linear lateral-directional p, r with the lateral velocity as
  an input, 15 derivatives and 7 biases, process noise on p and r (test case 2).
* :func:`unstable_replica`: the unstable short period in w and q flown closed loop with
  process noise, az an exact function of the measured w, q and the elevator (test case 8).
"""

from __future__ import annotations

import numpy as np

from estimators.datasets import multistep
from estimators.model import Model, Parameter, Segment
from estimators.process_noise_examples import NoisyExample, simulate_with_process_noise

HFB320_CONSTANTS = dict(
    g0=9.80665, Sbym=4.028e-3, Scbyiy=8.0027e-4, Feiylt=-7.0153e-6, v0=104.67, rm=7472.0, sigmat=0.0524, rho=0.792
)
#: the reference's filter-error estimates (the replica's truth) and start values
HFB320_TRUTH = dict(
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
HFB320_START = dict(
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
#: process noise F on V, alpha, theta, q (state unit per sqrt(s)): the reference's estimate
#: and its start
HFB320_F = np.array([0.35855, 0.0024210, 0.00044761, 0.0017378])
HFB320_F_START = {"V": 0.02, "alpha": 0.002, "theta": 0.02, "q": 0.02}
#: the reference's innovation variances of V, alpha, theta, q, qdot, ax, az, taken here as
#: the measurement-noise variances
HFB320_R = np.array([0.017587, 9.9021e-7, 1.9774e-7, 3.3836e-7, 3.1684e-5, 4.1910e-4, 0.020203])
HFB320_X0 = np.array([106.023, 0.111685, 0.104887, -0.00332659])


def _hfb_coefficients(x, u, p, c):
    V, alpha, theta, q = x
    de, Fe = u
    CD = p.CD0 + p.CDV * V / c.v0 + p.CDal * alpha
    CL = p.CL0 + p.CLV * V / c.v0 + p.CLal * alpha
    Cm = p.Cm0 + p.CmV * V / c.v0 + p.Cmal * alpha + p.Cmq * q / c.v0 + p.Cmde * de
    return CD, CL, Cm


def hfb320_f(x, u, p, c):
    """The HFB-320 state derivatives (V, alpha, theta, q), as a user writes f."""
    V, alpha, theta, q = x
    de, Fe = u
    CD, CL, Cm = _hfb_coefficients(x, u, p, c)
    qbar = 0.5 * c.rho * V**2
    Vdot = -c.Sbym * qbar * CD + Fe * np.cos(alpha + c.sigmat) / c.rm + c.g0 * np.sin(alpha - theta)
    alphadot = (
        -c.Sbym * qbar * CL / V + q - Fe * np.sin(alpha + c.sigmat) / (c.rm * V) + c.g0 * np.cos(alpha - theta) / V
    )
    return Vdot, alphadot, q, c.Scbyiy * qbar * Cm + c.Feiylt * Fe


def hfb320_g(x, u, p, c):
    """The HFB-320 outputs (V, alpha, theta, q, qdot, ax, az), as a user writes g."""
    V, alpha, theta, q = x
    de, Fe = u
    CD, CL, Cm = _hfb_coefficients(x, u, p, c)
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


def hfb320_model(values: dict[str, float] | None = None, f=hfb320_f) -> Model:
    """The HFB-320 longitudinal model of test case 4: states V (m/s), alpha, theta (rad),
    q (rad/s); inputs elevator (rad) and thrust (N); outputs V, alpha, theta, q, qdot, ax,
    az (SI); every parameter free at ``values`` (default the reference's start values).
    ``f``: another form of :func:`hfb320_f` (a test of the numpy fallback)."""
    values = HFB320_START if values is None else values
    return Model(
        states=["V", "alpha", "theta", "q"],
        inputs=["de", "Fe"],
        outputs=["V", "alpha", "theta", "q", "qdot", "ax", "az"],
        parameters=[Parameter(k, v) for k, v in values.items()],
        constants=HFB320_CONSTANTS,
        f=f,
        g=hfb320_g,
        name="hfb320-tc04",
    )


def hfb320_replica(seed: int = 0) -> NoisyExample:
    """60 s at 10 Hz (601 samples) from the reference's initial state: two elevator
    3-2-1-1s and a thrust step, flown with the reference's process noise and its R as
    measurement noise. The model carries the reference's start values."""
    t = np.arange(601) * 0.1
    de = (
        -0.026
        + multistep(t, 2.0, 1.0, amplitude=0.03)
        + multistep(t, 25.0, 1.0, amplitude=-0.03)
        + multistep(t, 48.0, 0.5, amplitude=0.04)
    )
    U = np.c_[de, np.where((t > 15.0) & (t < 40.0), 11200.0, 9700.0)]
    seg = Segment(t=t, u=U, z=np.zeros((t.size, 7)), x0=HFB320_X0.copy(), name="tc04")
    truth_model = hfb320_model(HFB320_TRUTH)
    F = np.diag(HFB320_F)
    sd = np.sqrt(HFB320_R)
    X, Z, _ = simulate_with_process_noise(truth_model, seg, F, np.random.default_rng(seed), sd, substeps=10)
    seg.z = Z
    return NoisyExample(
        model=hfb320_model(),
        truth_model=truth_model,
        segments=[seg],
        truth=dict(HFB320_TRUTH),
        process_noise=F,
        noise_std=sd,
        states=[X],
    )


LATERAL_NAMES = (
    "Lp",
    "Lr",
    "Lda",
    "Ldr",
    "Lv",
    "Np",
    "Nr",
    "Nda",
    "Ndr",
    "Nv",
    "Yp",
    "Yr",
    "Yda",
    "Ydr",
    "Yv",
    "BX1",
    "BX2",
    "BY1",
    "BY2",
    "BY3",
    "BY4",
    "BY5",
)
#: the reference's start values (derivatives Lp..Yv, then BX1, BX2, BY1..BY5)
LATERAL_START = dict(
    zip(
        LATERAL_NAMES,
        (
            -6.7,
            1.83,
            -18.3,
            0.43,
            -0.114,
            -0.906,
            -0.665,
            -0.66,
            -2.82,
            0.0069,
            -0.64,
            1.30,
            -1.40,
            2.79,
            -0.193,
            0.08,
            -0.089,
            0.08,
            -0.089,
            0.044,
            -0.0034,
            -0.0015,
        ),
    )
)
#: the replica's truth: the reference's estimates where published (Lp, Lda, Nr, Ndr, Yv),
#: the start values elsewhere, small biases
LATERAL_TRUTH = {
    **LATERAL_START,
    "Lp": -5.722,
    "Lda": -14.97,
    "Nr": -0.7233,
    "Ndr": -2.831,
    "Yv": -0.1802,
    "BX1": 0.02,
    "BX2": -0.01,
    "BY1": 0.03,
    "BY2": -0.02,
    "BY3": 0.05,
    "BY4": -0.003,
    "BY5": -0.0015,
}
#: process noise on p and r (rad/s per sqrt(s)): the reference's estimate and its start
LATERAL_F = np.array([0.1672, 0.1247])
LATERAL_F_START = {"p": 0.02, "r": 0.02}
#: measurement-noise std of pdot, rdot (rad/s^2), ay (m/s^2), p, r (rad/s)
LATERAL_NOISE = np.array([0.05, 0.02, 0.05, 0.01, 0.005])


def _lat_f(x, u, p, c):
    pr, r = x
    da, dr, vk = u
    pdot = p.Lp * pr + p.Lr * r + p.Lda * da + p.Ldr * dr + p.Lv * vk + p.BX1
    rdot = p.Np * pr + p.Nr * r + p.Nda * da + p.Ndr * dr + p.Nv * vk + p.BX2
    return pdot, rdot


def _lat_g(x, u, p, c):
    pr, r = x
    da, dr, vk = u
    pdot = p.Lp * pr + p.Lr * r + p.Lda * da + p.Ldr * dr + p.Lv * vk + p.BY1
    rdot = p.Np * pr + p.Nr * r + p.Nda * da + p.Ndr * dr + p.Nv * vk + p.BY2
    ay = p.Yp * pr + p.Yr * r + p.Yda * da + p.Ydr * dr + p.Yv * vk + p.BY3
    return pdot, rdot, ay, pr + p.BY4, r + p.BY5


def lateral_model(values: dict[str, float] | None = None) -> Model:
    """The linear lateral-directional model of test case 2: states p, r (rad/s); inputs
    aileron, rudder (rad) and lateral velocity vk (m/s); outputs pdot, rdot, ay, p, r."""
    values = LATERAL_START if values is None else values
    return Model(
        states=["p", "r"],
        inputs=["da", "dr", "vk"],
        outputs=["pdot", "rdot", "ay", "p", "r"],
        parameters=[Parameter(k, v) for k, v in values.items()],
        f=_lat_f,
        g=_lat_g,
        name="lateral-tc02",
    )


def lateral_replica(seed: int = 0) -> NoisyExample:
    """16 s at 20 Hz (321 samples) from x0 = 0: an aileron 3-2-1-1, a rudder doublet and
    a lateral velocity of a few m/s, flown with the reference's process noise."""
    t = np.arange(321) * 0.05
    da = multistep(t, 1.0, 0.5, amplitude=0.04)
    dr = multistep(t, 7.0, 1.0, pattern=(1, -1), amplitude=0.05)
    vk = 1.5 * np.sin(2 * np.pi * 0.15 * t) + 0.8 * np.sin(2 * np.pi * 0.4 * t + 1.0)
    seg = Segment(t=t, u=np.c_[da, dr, vk], z=np.zeros((t.size, 5)), x0=np.zeros(2), name="tc02")
    truth_model = lateral_model(LATERAL_TRUTH)
    F = np.diag(LATERAL_F)
    X, Z, _ = simulate_with_process_noise(truth_model, seg, F, np.random.default_rng(seed), LATERAL_NOISE, substeps=10)
    seg.z = Z
    return NoisyExample(
        model=lateral_model(),
        truth_model=truth_model,
        segments=[seg],
        truth=dict(LATERAL_TRUTH),
        process_noise=F,
        noise_std=LATERAL_NOISE,
        states=[X],
    )


#: the unstable short period of test case 8 (w (m/s), q (rad/s); dimensional derivatives):
#: Mw > 0 makes it unstable (time to double about 1 s); Zq is held, as in the reference
UNSTABLE_TRUTH = dict(Zw=-1.4249, Zq=-1.4768, Zde=-6.2632, Mw=0.2163, Mq=-3.7067, Mde=-12.784)
UNSTABLE_START = dict(Zw=-1.2, Zq=-1.4768, Zde=-5.0, Mw=0.15, Mq=-3.0, Mde=-10.0)
UNSTABLE_CONSTANTS = dict(U0=44.5)
#: process noise on w and q (m/s and rad/s per sqrt(s)), and its start
UNSTABLE_F = np.array([0.5, 0.02])
UNSTABLE_F_START = {"w": 0.1, "q": 0.005}
#: measurement-noise std of w (m/s) and q (rad/s); az is computed from the measured w and q
UNSTABLE_NOISE = np.array([0.05, 0.002])
#: the stability augmentation de = de_pilot + K_w w_m + K_q q_m on the measured signals
UNSTABLE_FEEDBACK = (0.05, 0.1)


def _uns_f(x, u, p, c):
    w, q = x
    (de,) = u
    return p.Zw * w + (c.U0 + p.Zq) * q + p.Zde * de, p.Mw * w + p.Mq * q + p.Mde * de


def _uns_g(x, u, p, c):
    w, q = x
    (de,) = u
    return p.Zw * w + p.Zq * q + p.Zde * de, w, q


def unstable_model(values: dict[str, float] | None = None) -> Model:
    """The unstable short period of test case 8: states w (m/s), q (rad/s); input the
    elevator (rad); outputs az (m/s^2), w, q. Zq is held at its value."""
    values = UNSTABLE_START if values is None else values
    return Model(
        states=["w", "q"],
        inputs=["de"],
        outputs=["az", "w", "q"],
        parameters=[Parameter(k, v, free=k != "Zq") for k, v in values.items()],
        constants=UNSTABLE_CONSTANTS,
        f=_uns_f,
        g=_uns_g,
        name="unstable-tc08",
    )


def unstable_replica(seed: int = 0) -> NoisyExample:
    """40 s at 50 Hz (2001 samples) from x0 = 0: pilot elevator 3-2-1-1s and a doublet
    through the stability augmentation (:data:`UNSTABLE_FEEDBACK`, closed on the
    measurements of the sample before), process noise on w and q; the recorded elevator is
    the total one and az is computed from the measured w, q and elevator (as in the
    reference's data, an exact function of them)."""
    t = np.arange(2001) * 0.02
    pilot = (
        multistep(t, 2.0, 0.5, amplitude=0.02)
        + multistep(t, 15.0, 1.0, pattern=(1, -1), amplitude=-0.02)
        + multistep(t, 26.0, 0.7, amplitude=-0.015)
    )
    seg = Segment(t=t, u=pilot[:, None], z=np.zeros((t.size, 3)), x0=np.zeros(2), name="tc08")
    truth_model = unstable_model(UNSTABLE_TRUTH)
    F = np.diag(UNSTABLE_F)
    kw, kq = UNSTABLE_FEEDBACK

    def feedback(i: int, z: np.ndarray) -> np.ndarray:
        return np.array([pilot[i] + kw * z[1] + kq * z[2]])

    sd = np.r_[0.0, UNSTABLE_NOISE]
    rng = np.random.default_rng(seed)
    X, Z, U = simulate_with_process_noise(truth_model, seg, F, rng, sd, feedback=feedback, substeps=10)
    p = UNSTABLE_TRUTH
    Z[:, 0] = p["Zw"] * Z[:, 1] + p["Zq"] * Z[:, 2] + p["Zde"] * U[:, 0]
    seg.z, seg.u = Z, U
    return NoisyExample(
        model=unstable_model(),
        truth_model=truth_model,
        segments=[seg],
        truth={k: v for k, v in UNSTABLE_TRUTH.items() if k != "Zq"},
        process_noise=F,
        noise_std=UNSTABLE_NOISE,
        states=[X],
    )


#: the replicas by name: (the function flying one for a seed, the reference's start of F)
REPLICA_CASES = {
    "hfb320": (hfb320_replica, HFB320_F_START),
    "lateral": (lateral_replica, LATERAL_F_START),
    "unstable": (unstable_replica, UNSTABLE_F_START),
}
