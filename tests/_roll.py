"""A one-state roll-rate model with known derivatives for the validation tests:
p' = Lp p + Lda da (Lp -8 1/s, Lda 40 1/s^2), p measured with white noise."""

from __future__ import annotations

import numpy as np

from estimators import Model, Parameter, Segment, simulate_outputs


def roll_model() -> Model:
    return Model(
        states=["p"],
        inputs=["da"],
        outputs=["p"],
        parameters=[Parameter("Lp", -8.0), Parameter("Lda", 40.0)],
        f=lambda x, u, p, c: (p.Lp * x[0] + p.Lda * u[0],),
        g=lambda x, u, p, c: (x[0],),
        name="roll",
    )


def roll_segment(t: np.ndarray, da: np.ndarray, noise_rad_s: float, seed: int) -> Segment:
    """The model's p (rad/s) driven by ``da`` (rad) on ``t`` (s, from rest, inputs read
    linearly), plus white noise of ``noise_rad_s``."""
    m = roll_model()
    y = simulate_outputs(
        m, Segment(t=t, u=da[:, None], z=np.zeros((t.size, 1)), x0=np.zeros(1)), inputs="linear"
    ).to_numpy()
    z = y + noise_rad_s * np.random.default_rng(seed).standard_normal(y.shape)
    return Segment(t=t, u=da[:, None], z=z, x0=np.zeros(1))
