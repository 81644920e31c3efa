"""Covariance of estimates from a model fed its own measurements
(estimators.output_error.pseudo_input_noise), against hand-computed values."""

import numpy as np
import pytest

from estimators import Model, OutputError
from estimators.model import Parameter, Segment
from estimators.output_error.pseudo_input_noise import (
    PropagationError,
    adjoint_sums,
    onto_measured,
    propagated_covariance,
    pseudo_mixing,
)
from estimators.statistics import difference_noise_std


def test_difference_noise_std_on_its_own_samples():
    rng = np.random.default_rng(0)
    t = np.arange(20000) * 0.01
    z = np.column_stack(
        [
            0.3 * t + 0.05 * rng.standard_normal(t.size),  # ramp + noise
            np.sin(0.5 * t) + 0.002 * rng.standard_normal(t.size),
        ]
    )
    z[1::2, 1] = np.nan  # channel 1 at half the rate
    sd = difference_noise_std([z[:10000], z[10000:]])
    assert sd == pytest.approx([0.05, 0.002], rel=0.03)
    # a few steps (a control input's kinks) inflate the plain estimate, not the robust one
    z[::500, 0] += 2.0
    assert difference_noise_std([z])[0] > 1.5 * 0.05
    assert difference_noise_std([z], robust=True)[0] == pytest.approx(0.05, rel=0.03)
    assert np.isnan(difference_noise_std([z[:3]])[0])


def test_pseudo_mixing_of_a_derived_pseudo_input():
    t = np.arange(50) * 0.1
    z = np.column_stack([np.sin(t), np.cos(t), t])
    seg = Segment(t=t, u=np.zeros((50, 1)), z=z, x0=np.zeros(1))
    J = pseudo_mixing(seg, ["a", "b", "c"], ["a"], lambda s, st: 2 * s.z[:, :1] - s.z[:, 1:2] ** 2)
    assert J.shape == (50, 1, 3)
    assert J[:, 0, 0] == pytest.approx(np.full(50, 2.0), rel=1e-6)
    assert J[:, 0, 1] == pytest.approx(-2 * np.cos(t), rel=1e-5, abs=1e-7)
    assert np.all(J[:, 0, 2] == 0)
    one_hot = pseudo_mixing(seg, ["a", "b", "c"], ["b"], None)
    assert np.all(one_hot[:, 0] == [0.0, 1.0, 0.0])


def _first_order(feedback: float, seed: int = 3) -> tuple[Model, Segment]:
    """x' = a x + b u + k (z_y - x), y = x: a pseudo-input z_y with gain k (1/s)."""

    def f(x, u, p, c):
        return (p.a * x[0] + p.b * u[0] + feedback * (u[1] - x[0]),)

    def g(x, u, p, c):
        return (x[0],)

    m = Model(
        states=["x"],
        inputs=["u", "z_y"],
        outputs=["y"],
        parameters=[Parameter("a", -1.0), Parameter("b", 2.0)],
        f=f,
        g=g,
    )
    t = np.arange(2000) * 0.01
    u = np.sign(np.sin(0.7 * t))
    clean = np.zeros_like(t)
    for k in range(1, t.size):  # the true system (a = -1, b = 2), Euler at 0.01 s
        clean[k] = clean[k - 1] + 0.01 * (-clean[k - 1] + 2 * u[k - 1])
    z = clean + 0.05 * np.random.default_rng(seed).standard_normal(t.size)
    return m, Segment(t=t, u=np.column_stack([u, z]), z=z[:, None], x0=np.zeros(1))


def test_without_feedback_it_is_the_cramer_rao_covariance():
    m, seg = _first_order(0.0)
    res = OutputError(m).fit(seg)
    cov, s2 = propagated_covariance(
        m,
        [seg],
        res.params.to_dict(),
        res.sensitivities,
        [r.to_numpy() for r in res.residuals],
        res.R,
        res.information,
        ["y"],
    )
    assert s2 == pytest.approx(difference_noise_std([seg.z], robust=True) ** 2)
    # nothing fed back: the Cramér-Rao covariance, scaled from the residual variance to the
    # noise variance measured from the samples (the same within a few per cent)
    assert cov == pytest.approx(res.cov * s2[0] / res.R[0, 0], rel=1e-8)
    assert np.sqrt(s2[0]) == pytest.approx(np.sqrt(res.R[0, 0]), rel=0.05)


def test_feedback_widens_the_bounds_and_unstable_fed_models_are_refused():
    m, seg = _first_order(5.0)
    res = OutputError(m).fit(seg)
    args = (res.sensitivities, [r.to_numpy() for r in res.residuals], res.R, res.information, ["y"])
    cov, s2 = propagated_covariance(m, [seg], res.params.to_dict(), *args)
    # the fed-back noise high-passes the residuals, and the sensitivities live at low
    # frequency: the estimates scatter far less than the white-residual Cramér-Rao bound says
    # (30 noise seeds, measured: empirical / propagated std 1.06, 0.98; empirical / CRB 0.30,
    # 0.31 for a, b)
    assert np.all(np.sqrt(np.diag(cov)) < 0.5 * res.std[["a", "b"]].to_numpy())
    # the noise std is taken from the samples (0.05 simulated), not from the residuals,
    # which the feedback shapes
    assert np.sqrt(s2[0]) == pytest.approx(0.05, rel=0.05)
    with pytest.raises(PropagationError, match="not stable"):
        propagated_covariance(m, [seg], {"a": 8.0, "b": 2.0}, *args)


def test_coefficients_of_filled_samples_go_back_to_the_measured_ones():
    # a 50 Hz channel on a 0.01 s grid: samples 1 and 3 filled as the mean of their neighbours
    t = np.arange(5) * 0.01
    measured = np.array([True, False, True, False, True])
    c = np.array([[1.0], [2.0], [3.0], [4.0], [5.0]])
    out = onto_measured(c, t, measured)
    assert out[:, 0] == pytest.approx([1.0 + 1.0, 0.0, 3.0 + 1.0 + 2.0, 0.0, 5.0 + 2.0])
    assert out.sum() == pytest.approx(c.sum())
    # before the first and after the last measurement the fill holds the nearest one
    out = onto_measured(c, t, np.array([False, True, True, True, False]))
    assert out[:, 0] == pytest.approx([0.0, 3.0, 3.0, 9.0, 0.0])


def test_adjoint_sums_are_the_impulse_response_correlated_forward():
    rng = np.random.default_rng(1)
    Ad = np.array([[1.0, 0.01], [0.0, 0.98]])  # an integrator chain: a pole at 1
    Bd, Cd, Dd = rng.standard_normal((2, 2)), rng.standard_normal((3, 2)), rng.standard_normal((3, 2))
    a = rng.standard_normal((60, 3, 4))
    g = [Dd] + [Cd @ np.linalg.matrix_power(Ad, l - 1) @ Bd for l in range(1, 60)]
    want = np.stack([sum(g[l].T @ a[m + l] for l in range(60 - m)) for m in range(60)])
    assert adjoint_sums(Ad, Bd, Cd, Dd, a) == pytest.approx(want, rel=1e-10, abs=1e-10)
