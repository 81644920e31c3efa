"""Model-simulated example problems with a known truth (for examples and for checking the estimators).

The main one is a business-jet-class (HFB-320-like) longitudinal case: the nonlinear
longitudinal model trimmed in level flight at 100 m/s, excited by an elevator 3-2-1-1,
simulated with the package's own RK4 and given white Gaussian noise on every output.
The aircraft constants follow the HFB-320 data of Jategaonkar's flight-vehicle system
identification text (mass, inertia, wing area, chord, density at about 5.5 km); the
derivatives are plausible values of that class, fixed here as the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from estimators.model import Model, Segment
from estimators.models.longitudinal import longitudinal
from estimators.simulation import simulate_outputs

HFB320_CONSTANTS = {
    "m": 7472.0,
    "Iyy": 65000.0,
    "S": 30.0,
    "cbar": 2.14,
    "rho": 0.7920,
    "g": 9.80665,
    "sigmaT": 0.0524,
    "zT": 0.0,
}
HFB320_TRUTH = {
    "CD0": 0.030,
    "CDalpha": 0.25,
    "CDalpha2": 0.0,
    "CDde": 0.04,
    "CL0": 0.15,
    "CLalpha": 4.8,
    "CLq": 6.0,
    "CLde": 0.38,
    "Cm0": 0.05,
    "Cmalpha": -0.75,
    "Cmq": -16.0,
    "Cmde": -1.6,
}
#: the 11 parameters estimated in the example problem
HFB320_FREE = ("CD0", "CDalpha", "CL0", "CLalpha", "CLq", "CLde", "Cm0", "Cmalpha", "Cmq", "Cmde", "CDde")
#: white-noise standard deviation per output (V m/s, angles rad, q rad/s, qdot rad/s^2, ax az m/s^2)
HFB320_NOISE = {
    "V": 0.2,
    "alpha": np.radians(0.1),
    "theta": np.radians(0.1),
    "q": np.radians(0.2),
    "qdot": np.radians(1.0),
    "ax": 0.05,
    "az": 0.1,
}


def multistep(t: np.ndarray, t0: float, unit: float, pattern=(3, -2, 1, -1), amplitude: float = 1.0) -> np.ndarray:
    """A multistep (3-2-1-1 by default) starting at t0 with pulse ``unit`` seconds; pattern
    entries are pulse widths in units, their signs the direction. Returns (N,) offsets."""
    out = np.zeros_like(t, dtype=float)
    start = t0
    for w in pattern:
        end = start + abs(w) * unit
        out[(t >= start) & (t < end)] = amplitude * np.sign(w)
        start = end
    return out


def trim_level(model: Model, V: float, gamma: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Trim the longitudinal model in steady flight at airspeed V (m/s) and flight-path
    angle gamma (rad): returns x0 = [V, alpha, theta, 0] and u0 = [de, thrust]."""
    P = np.array([[p.value] for p in model.parameters])

    def res(z):
        alpha, de, thrust = z
        x = np.array([[V], [alpha], [alpha + gamma], [0.0]])
        u = np.array([[de], [thrust]])
        d = model.eval_f(x, u, P, model.constants)[:, 0]
        return [d[0], d[1], d[3]]

    sol = optimize.least_squares(
        res, [0.05, -0.05, 5000.0], x_scale=[0.1, 0.1, 1e4], xtol=1e-14, ftol=1e-14, gtol=1e-14
    )
    alpha, de, thrust = sol.x
    return np.array([V, alpha, alpha + gamma, 0.0]), np.array([de, thrust])


@dataclass
class Example:
    """A simulated identification problem: the truth model, noisy segments and truth values."""

    model: Model  # the model with start values (free set as requested)
    truth_model: Model
    segments: list[Segment]
    truth: dict[str, float]
    clean: list[np.ndarray]  # noise-free outputs per segment (N, n_out)
    noise_std: np.ndarray  # (n_out,)


def longitudinal_example(
    seed: int = 0,
    n: int = 600,
    dt: float = 0.02,
    *,
    start_offset: float = 0.3,
    free=HFB320_FREE,
    segments: int = 1,
    integrator: str = "rk4",
    noise_scale: float = 1.0,
) -> Example:
    """The HFB-320-like longitudinal problem (see module docstring).

    n samples per segment at dt s; each segment flies a 3-2-1-1 on the elevator (segment k
    with a different pulse width and sign), from trim at 100 m/s. Start values are the
    truth times (1 + start_offset) alternating in sign, so each is off by start_offset.
    """
    truth_model = longitudinal(HFB320_CONSTANTS, values=HFB320_TRUTH, free=free)
    x0, u0 = trim_level(truth_model, 100.0)
    rng = np.random.default_rng(seed)
    sd = np.array([HFB320_NOISE[o] for o in truth_model.outputs]) * noise_scale
    segs, clean = [], []
    t = np.arange(n) * dt
    for k in range(segments):
        de = u0[0] + multistep(t, 1.0 + 0.5 * k, 0.5 + 0.1 * k, amplitude=np.radians(2.0) * (-1) ** k)
        u = np.column_stack([de, np.full(n, u0[1])])
        seg = Segment(t=t, u=u, z=np.zeros((n, 7)), x0=x0, name=f"3211-{k}")
        y = simulate_outputs(truth_model, seg, integrator=integrator).to_numpy()
        seg.z = y + rng.standard_normal(y.shape) * sd
        segs.append(seg)
        clean.append(y)
    signs = np.where(np.arange(len(free)) % 2 == 0, 1.0, -1.0)
    start = {name: HFB320_TRUTH[name] * (1.0 + s * start_offset) for name, s in zip(free, signs)}
    model = longitudinal(HFB320_CONSTANTS, values={**HFB320_TRUTH, **start}, free=free)
    return Example(model, truth_model, segs, dict(HFB320_TRUTH), clean, sd)
