"""Model-simulated problems with process noise (turbulence) and an unstable aircraft, with
known truth, for checking the filter-error and Kalman methods.

* :func:`simulate_with_process_noise`: x_{k+1} = Phi_h(x_k) + F w_k h, w_k ~ N(0, I/h)
  (white noise of unit spectral density held over each step - the discrete model the
  filters assume), outputs g(x) plus white measurement noise.
* :func:`turbulent_longitudinal_example`: the HFB-320-like longitudinal case of
  :mod:`estimators.datasets` flown in turbulence (process noise on alpha and q).
* :func:`unstable_short_period_example`: a statically unstable short period
  (Cmalpha > 0, time to double about 0.8 s) flown with an angle-of-attack and pitch-rate
  stability augmentation loop de = de_pilot + K_alpha alpha_m + K_q q_m on the measured
  (noisy) signals of the previous sample; the recorded input is the total elevator.
* :func:`dryden_short_period_example`: a linear short period driven by a
  Dryden-filtered vertical gust, with the gust filter as an extra state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from estimators.compile import kernel_for
from estimators.datasets import HFB320_CONSTANTS, HFB320_NOISE, HFB320_TRUTH, multistep, trim_level
from estimators.layout import Layout
from estimators.model import Model, Parameter, Segment
from estimators.models import short_period
from estimators.models.longitudinal import longitudinal


@dataclass
class NoisyExample:
    model: Model  # model with start values (free as requested)
    truth_model: Model
    segments: list[Segment]
    truth: dict[str, float]
    process_noise: np.ndarray  # F (n, n), state units per sqrt(s)
    noise_std: np.ndarray  # measurement-noise std per output
    states: list[np.ndarray]  # true states per segment (N, n)


def simulate_with_process_noise(
    model: Model,
    seg: Segment,
    F: np.ndarray,
    rng: np.random.Generator,
    noise_std: np.ndarray | None = None,
    integrator: str = "rk4",
    feedback=None,
    substeps: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulate one segment with process noise F (see module docstring).

    substeps : integrator steps per sample interval, each followed by its share of the
        noise (F w sqrt(h / substeps)); more sub-steps approach the continuous noise model
        the filter-error method assumes (one step per sample misses its O(h A) part).

    feedback : optional callable (i, z_{i-1}) -> u_i replacing the input at sample i from
        the outputs measured one sample earlier (a closed loop on the measurements with one
        sample of computation delay, so the recorded input is known over each integration
        step exactly as the estimators assume); the realised inputs are returned. Returns (X (N, n), Z (N, n_out) measured, U (N, n_in)).
    """
    lay = Layout.build(model, [seg])
    P = lay.values[lay.pidx[0]][:, None]
    c = model.constants_for(seg)
    kern = kernel_for(model)
    n, N = len(model.states), seg.n
    sd = np.zeros(len(model.outputs)) if noise_std is None else np.asarray(noise_std, float)
    X = np.empty((N, n))
    Z = np.empty((N, len(model.outputs)))
    U = seg.u.copy()
    x = seg.initial_state(model)
    for i in range(N):
        X[i] = x
        y = model.eval_g(x[:, None, None], U[i][:, None, None], P, c)[:, 0, 0]
        Z[i] = y + sd * rng.standard_normal(sd.size)
        if i + 1 < N:
            if feedback is not None:
                U[i + 1] = feedback(i + 1, Z[i])
            h = seg.t[i + 1] - seg.t[i]
            if substeps == 1:
                Xs = kern.integrate(integrator, x[:, None], U[i : i + 2], seg.t[i : i + 2], P, c)
                x = Xs[1, :, 0] + F @ rng.standard_normal(F.shape[1]) * np.sqrt(h)
                continue
            frac = np.linspace(0.0, 1.0, substeps + 1)
            Us = U[i] + frac[:, None] * (U[i + 1] - U[i])
            ts = seg.t[i] + frac * h
            for j in range(substeps):
                Xs = kern.integrate(integrator, x[:, None], Us[j : j + 2], ts[j : j + 2], P, c)
                x = Xs[1, :, 0] + F @ rng.standard_normal(F.shape[1]) * np.sqrt(h / substeps)
    return X, Z, U


def turbulent_longitudinal_example(
    seed: int = 0,
    n: int = 600,
    dt: float = 0.02,
    *,
    sigma_alpha: float = 0.005,
    sigma_q: float = 0.01,
    start_offset: float = 0.2,
    free=("CLalpha", "CLde", "Cmalpha", "Cmq", "Cmde", "CL0", "Cm0"),
    segments: int = 1,
) -> NoisyExample:
    """HFB-320-like longitudinal 3-2-1-1 in turbulence: process noise std sigma_alpha
    (rad/sqrt(s)) on alpha and sigma_q (rad/s/sqrt(s)) on q, sensor noise as in
    :data:`estimators.datasets.HFB320_NOISE`. Start values off by +-start_offset."""
    truth_model = longitudinal(HFB320_CONSTANTS, values=HFB320_TRUTH, free=free)
    x0, u0 = trim_level(truth_model, 100.0)
    rng = np.random.default_rng(seed)
    sd = np.array([HFB320_NOISE[o] for o in truth_model.outputs])
    F = np.diag([0.0, sigma_alpha, 0.0, sigma_q])
    t = np.arange(n) * dt
    segs, states = [], []
    for k in range(segments):
        de = u0[0] + multistep(t, 1.0 + 0.5 * k, 0.5 + 0.1 * k, amplitude=np.radians(2.0) * (-1) ** k)
        seg = Segment(t=t, u=np.column_stack([de, np.full(n, u0[1])]), z=np.zeros((n, 7)), x0=x0, name=f"turb-{k}")
        X, Z, _ = simulate_with_process_noise(truth_model, seg, F, rng, sd)
        seg.z = Z
        segs.append(seg)
        states.append(X)
    signs = np.where(np.arange(len(free)) % 2 == 0, 1.0, -1.0)
    start = {nm: HFB320_TRUTH[nm] * (1.0 + s * start_offset) for nm, s in zip(free, signs)}
    model = longitudinal(HFB320_CONSTANTS, values={**HFB320_TRUTH, **start}, free=free)
    return NoisyExample(model, truth_model, segs, dict(HFB320_TRUTH), F, sd, states)


#: short-period constants (HFB-320 class at 100 m/s) and an unstable truth
SP_CONSTANTS = {"m": 7472.0, "Iyy": 65000.0, "S": 30.0, "cbar": 2.14, "rho": 0.792, "V": 100.0}
UNSTABLE_SP_TRUTH = {"CLalpha": 4.8, "CLq": 0.0, "CLde": 0.38, "Cmalpha": 0.5, "Cmq": -16.0, "Cmde": -1.6}
UNSTABLE_SP_FREE = ("CLalpha", "CLde", "Cmalpha", "Cmq", "Cmde")
SP_NOISE = {"alpha": np.radians(0.1), "q": np.radians(0.2), "qdot": np.radians(1.0), "az": 0.1}


def unstable_short_period_example(
    seed: int = 0,
    n: int = 1000,
    dt: float = 0.02,
    *,
    k_alpha: float = 0.5,
    k_q: float = 0.3,
    sigma_alpha: float = 0.0,
    sigma_q: float = 0.0,
    start_offset: float = 0.2,
    segments: int = 1,
) -> NoisyExample:
    """The statically unstable short period (Cmalpha = +0.5) with the SAS loop
    de = de_pilot + k_alpha alpha_m + k_q q_m closed on the measured signals; de_pilot a
    3-2-1-1 and a later doublet. Optional process noise (rad/sqrt(s)) on alpha and q.
    Start values off by +-start_offset (Cmalpha starts at +0.5 (1 +- offset), still
    unstable)."""
    truth_model = short_period(SP_CONSTANTS, values=UNSTABLE_SP_TRUTH, free=UNSTABLE_SP_FREE)
    rng = np.random.default_rng(seed)
    sd = np.array([SP_NOISE[o] for o in truth_model.outputs])
    F = np.diag([sigma_alpha, sigma_q])
    t = np.arange(n) * dt
    segs, states = [], []
    for k in range(segments):
        pilot = multistep(t, 1.0 + 0.3 * k, 0.6, amplitude=np.radians(1.5) * (-1) ** k) + multistep(
            t, 12.0, 1.0, (1, -1), np.radians(1.0)
        )
        seg = Segment(t=t, u=pilot[:, None], z=np.zeros((n, 4)), x0=np.zeros(2), name=f"sas-{k}")

        def feedback(i, z, pilot=pilot):
            return np.array([pilot[i] + k_alpha * z[0] + k_q * z[1]])

        X, Z, U = simulate_with_process_noise(truth_model, seg, F, rng, sd, feedback=feedback)
        seg.z, seg.u = Z, U
        segs.append(seg)
        states.append(X)
    signs = np.where(np.arange(len(UNSTABLE_SP_FREE)) % 2 == 0, 1.0, -1.0)
    start = {nm: UNSTABLE_SP_TRUTH[nm] * (1.0 + s * start_offset) for nm, s in zip(UNSTABLE_SP_FREE, signs)}
    model = short_period(SP_CONSTANTS, values={**UNSTABLE_SP_TRUTH, **start}, free=UNSTABLE_SP_FREE)
    return NoisyExample(model, truth_model, segs, dict(UNSTABLE_SP_TRUTH), F, sd, states)


STABLE_SP_TRUTH = {"CLalpha": 4.8, "CLq": 0.0, "CLde": 0.38, "Cmalpha": -0.75, "Cmq": -16.0, "Cmde": -1.6}


def turbulent_short_period_example(
    seed: int = 0,
    n: int = 800,
    dt: float = 0.02,
    *,
    sigma_alpha: float = 0.004,
    sigma_q: float = 0.008,
    segments: int = 2,
    biases=(0.3, 0.6),
    start_offset: float = 0.2,
) -> NoisyExample:
    """The (stable) linear short period in turbulence: process noise on alpha and q,
    3-2-1-1 elevator inputs of different widths per segment, a per-segment az bias
    (truth ``bias_az[k]`` = biases[k]); all start values 1 + start_offset times the truth."""
    truth_model = short_period(SP_CONSTANTS, values=STABLE_SP_TRUTH, output_biases=["az"])
    rng = np.random.default_rng(seed)
    sd = np.array([SP_NOISE[o] for o in truth_model.outputs])
    F = np.diag([sigma_alpha, sigma_q])
    t = np.arange(n) * dt
    segs, states = [], []
    truth = dict(STABLE_SP_TRUTH)
    for k in range(segments):
        de = multistep(t, 1.0, 0.5 + 0.2 * k, amplitude=np.radians(2.0) * (-1) ** k)
        seg = Segment(t=t, u=de[:, None], z=np.zeros((n, 4)), x0=np.zeros(2), name=f"turb-sp-{k}")
        X, Z, _ = simulate_with_process_noise(truth_model, seg, F, rng, sd)
        Z[:, 3] += biases[k]
        truth[f"bias_az[{k}]"] = biases[k]
        seg.z = Z
        segs.append(seg)
        states.append(X)
    model = short_period(
        SP_CONSTANTS, values={k: v * (1 + start_offset) for k, v in STABLE_SP_TRUTH.items()}, output_biases=["az"]
    )
    return NoisyExample(model, truth_model, segs, truth, F, sd, states)


# -- Dryden gust case -----------------------------------------------------------------------------
def _sp_gust_f(x, u, p, c):
    alpha, q, g1, g2 = x
    (de,) = u
    qbar = 0.5 * c.rho * c.V * c.V
    qhat = q * c.cbar / (2.0 * c.V)
    ag = c.kg * (g1 + c.r3tau * g2) / c.V  # gust angle of attack w_g / V
    CL = p.CLalpha * (alpha + ag) + p.CLq * qhat + p.CLde * de
    Cm = p.Cmalpha * (alpha + ag) + p.Cmq * qhat + p.Cmde * de
    return (
        q - qbar * c.S / (c.m * c.V) * CL,
        qbar * c.S * c.cbar / c.Iyy * Cm,
        g2,
        (-g1 - 2.0 * c.tau * g2) / (c.tau * c.tau),
    )


def _sp_gust_g(x, u, p, c):
    alpha, q, g1, g2 = x
    (de,) = u
    qbar = 0.5 * c.rho * c.V * c.V
    qhat = q * c.cbar / (2.0 * c.V)
    ag = c.kg * (g1 + c.r3tau * g2) / c.V
    CL = p.CLalpha * (alpha + ag) + p.CLq * qhat + p.CLde * de
    Cm = p.Cmalpha * (alpha + ag) + p.Cmq * qhat + p.Cmde * de
    return alpha, q, qbar * c.S * c.cbar / c.Iyy * Cm, -qbar * c.S / c.m * CL


def dryden_short_period_model(
    values=None, free=UNSTABLE_SP_FREE, *, sigma_w: float = 1.5, L: float = 150.0
) -> tuple[Model, float]:
    """The linear short period driven by a Dryden vertical gust w_g (std sigma_w m/s, scale
    length L m): the shaping filter (1 + sqrt(3) tau s) / (1 + tau s)^2, tau = L / V, is
    realised as states g1, g2 (g1' = g2, g2' = (-g1 - 2 tau g2)/tau^2 + F n) with
    w_g = kg (g1 + sqrt(3) tau g2); the gust adds w_g/V to the angle of attack in the
    aerodynamic coefficients. kg is set so that std(w_g) = sigma_w for the true noise
    intensity F_g2 = 1/tau^2 (returned). States alpha, q, g1, g2; outputs alpha, q, qdot, az."""
    c = dict(SP_CONSTANTS)
    tau = L / c["V"]
    A = np.array([[0.0, 1.0], [-1.0 / tau**2, -2.0 / tau]])
    Fg = 1.0 / tau**2
    Pg = linalg.solve_continuous_lyapunov(A, -np.array([[0.0, 0.0], [0.0, Fg**2]]))
    cvec = np.array([1.0, np.sqrt(3.0) * tau])
    kg = sigma_w / np.sqrt(cvec @ Pg @ cvec)
    c.update({"tau": tau, "r3tau": np.sqrt(3.0) * tau, "kg": kg})
    vals = {**STABLE_SP_TRUTH, **(values or {})}
    params = [Parameter(k, v, k in free) for k, v in vals.items()]
    return Model(
        ["alpha", "q", "g1", "g2"],
        ["de"],
        ["alpha", "q", "qdot", "az"],
        params,
        _sp_gust_f,
        _sp_gust_g,
        c,
        name="short_period+dryden",
    ), Fg


def dryden_short_period_example(
    seed: int = 0, n: int = 1000, dt: float = 0.02, *, sigma_w: float = 1.5, L: float = 150.0, start_offset: float = 0.2
) -> NoisyExample:
    """A stable short period (:data:`STABLE_SP_TRUTH`) flying a 3-2-1-1 and a doublet in
    Dryden turbulence (see :func:`dryden_short_period_model`), sensor noise SP_NOISE.
    The returned ``model`` is the same gust-augmented model with start values off by
    +-start_offset; F_g2 (true value ``process_noise[3, 3]``) is what FEM estimates."""
    truth_model, Fg = dryden_short_period_model(sigma_w=sigma_w, L=L)
    rng = np.random.default_rng(seed)
    sd = np.array([SP_NOISE[o] for o in truth_model.outputs])
    F = np.diag([0.0, 0.0, 0.0, Fg])
    t = np.arange(n) * dt
    de = multistep(t, 1.0, 0.6, amplitude=np.radians(2.0)) + multistep(t, 12.0, 1.0, (1, -1), np.radians(1.5))
    # start in a random stationary gust state (not in calm air)
    tau = truth_model.constants["tau"]
    Ag = np.array([[0.0, 1.0], [-1.0 / tau**2, -2.0 / tau]])
    Pg = linalg.solve_continuous_lyapunov(Ag, -np.array([[0.0, 0.0], [0.0, Fg**2]]))
    g0 = np.linalg.cholesky(Pg) @ rng.standard_normal(2)
    seg = Segment(t=t, u=de[:, None], z=np.zeros((n, 4)), x0=np.array([0.0, 0.0, *g0]), name="dryden")
    X, Z, _ = simulate_with_process_noise(truth_model, seg, F, rng, sd)
    seg.z = Z
    seg.x0 = np.zeros(4)  # the estimators do not know the initial gust state
    free = [p.name for p in truth_model.parameters if p.free]
    signs = np.where(np.arange(len(free)) % 2 == 0, 1.0, -1.0)
    start = {nm: STABLE_SP_TRUTH[nm] * (1.0 + s * start_offset) for nm, s in zip(free, signs)}
    model, _ = dryden_short_period_model(values=start, sigma_w=sigma_w, L=L)
    return NoisyExample(model, truth_model, [seg], dict(STABLE_SP_TRUTH), F, sd, [X])


#: roll_gust_example's truth: damping a (1/s), control power b (rad/s^2 per unit input)
ROLL_GUST_TRUTH = {"a": -6.0, "b": 10.0}


def _roll_gust_f(x, u, p, c):
    return (p.a * (x[0] + x[1]) + p.b * u[0], -x[1] / p.tau)


def _roll_gust_g(x, u, p, c):
    return (x[0],)


def roll_gust_model(values=None) -> Model:
    """A roll axis whose unmeasured first-order roll gust g acts through the damping a:
    p' = a (p + g) + b u, g' = -g / tau; output p (rad/s). a, b free; tau held."""
    v = {**ROLL_GUST_TRUTH, "tau": 0.4, **(values or {})}
    return Model(
        states=["p", "g"],
        inputs=["u"],
        outputs=["p"],
        parameters=[Parameter("a", v["a"]), Parameter("b", v["b"]), Parameter("tau", v["tau"], free=False)],
        f=_roll_gust_f,
        g=_roll_gust_g,
        name="roll_gust",
    )


def roll_gust_example(
    seed: int = 0,
    n: int = 1500,
    dt: float = 0.02,
    *,
    tau: float = 0.4,
    gust_rms: float = 0.1,
    sensor_std: float = 0.003,
    start: dict[str, float] | None = None,
) -> NoisyExample:
    """:func:`roll_gust_model` flown through its own gust (a first-order Markov process of
    time constant tau s and rms gust_rms rad/s: white input gust_rms sqrt(2 / tau) per
    sqrt(s), the gust started from its stationary spread) on a square wave plus a sine,
    sensor noise sensor_std rad/s. Start values 33 % / 20 % off the truth (``start``
    overrides)."""
    truth_model = roll_gust_model({"tau": tau})
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    u = 0.05 * np.sign(np.sin(2 * np.pi * t / 3.0 + 0.3)) + 0.03 * np.sin(2 * np.pi * 0.7 * t)
    F = np.diag([0.0, gust_rms * np.sqrt(2.0 / tau)])
    seg = Segment(t=t, u=u[:, None], z=np.zeros((n, 1)), x0=[0.0, gust_rms * rng.standard_normal()], name="roll-gust")
    X, Z, _ = simulate_with_process_noise(truth_model, seg, F, rng, np.array([sensor_std]))
    seg.z = Z
    seg.x0 = np.array([Z[0, 0], 0.0])  # the filters know the measured rate, not the gust
    model = roll_gust_model({"tau": tau, **(start or {"a": -4.0, "b": 8.0})})
    return NoisyExample(model, truth_model, [seg], dict(ROLL_GUST_TRUTH), F, np.array([sensor_std]), [X])
