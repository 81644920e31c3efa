"""A small EstimationResult made by hand (two free parameters, std 0.2 and 0.3, one fixed)
for the tests of what a result reports, without a fit."""

import numpy as np
import pandas as pd

from estimators import EstimationResult, Model, Parameter


def small_result(consider=None, consider_source: str = "") -> EstimationResult:
    """a = -1.5, b = 2.0 free with cov [[0.04, 0.01], [0.01, 0.09]], c = 0.5 fixed;
    ``consider``: its consider covariance (2, 2) or None."""
    model = Model(
        states=["x"],
        inputs=["u"],
        outputs=["x"],
        parameters=[Parameter("a", -1.0), Parameter("b", 2.0), Parameter("c", 0.5, free=False)],
        f=lambda x, u, p, c: (p.a * x[0] + p.b * u[0],),
        g=lambda x, u, p, c: (x[0],),
    )
    cov = np.array([[0.04, 0.01], [0.01, 0.09]])  # std 0.2, 0.3
    return EstimationResult(
        "oem", model, ["a", "b", "c"], np.array([-1.5, 2.0, 0.5]), np.array([True, True, False]), cov,
        np.eye(1), True, 3, pd.DataFrame(), [], [], consider_cov=consider, consider_source=consider_source,
    )  # fmt: skip
