"""Integrators: order of accuracy on a known ODE, batch consistency, compiled = numpy."""

import numpy as np
import pytest

from estimators import Model, Parameter
from estimators.compile.kernels import RhsKernel, kernel_for


def osc_f(x, u, p, c):
    x1, x2 = x
    (w,) = u
    return x2, -p.k * x1 + 0.0 * w


def osc_g(x, u, p, c):
    x1, x2 = x
    return x1, x2


def oscillator(k=4.0):
    return Model(
        states=["x1", "x2"],
        inputs=["w"],
        outputs=["x1", "x2"],
        parameters=[Parameter("k", k)],
        f=osc_f,
        g=osc_g,
        name="oscillator",
    )


def final_error(model, scheme, dt, T=2.0, **kw):
    t = np.arange(0.0, T + dt / 2, dt)
    U = np.zeros((t.size, 1))
    P = np.array([[4.0, 9.0]])  # a batch of two stiffnesses
    x0 = np.array([[1.0, 1.0], [0.0, 0.0]])
    X = kernel_for(model).integrate(scheme, x0, U, t, P, {}, **kw)
    exact = np.cos(np.sqrt(P[0]) * t[-1])
    return np.max(np.abs(X[-1, 0, :] - exact))


@pytest.mark.parametrize("scheme,order", [("euler", 1), ("rk2", 2), ("rk3", 3), ("rk4", 4)])
def test_fixed_step_order(scheme, order):
    m = oscillator()
    e1 = final_error(m, scheme, 0.02)
    e2 = final_error(m, scheme, 0.01)
    observed = np.log2(e1 / e2)
    assert abs(observed - order) < 0.25, (scheme, observed)


def test_rkf45_meets_tolerance_with_coarse_samples():
    m = oscillator()
    err = final_error(m, "rkf45", 0.25, rtol=1e-10, atol=1e-12)
    assert err < 1e-8
    # a loose tolerance is visibly less accurate: the step control is really working
    assert final_error(m, "rkf45", 0.25, rtol=1e-3, atol=1e-6) > 10 * err


def test_default_inputs_at_each_stage_time():
    # x' = u with u a ramp: each stage reads the input at its own time, so Euler (one
    # stage, at t_k) sums the left samples and RK4 integrates the ramp exactly
    m = Model(
        states=["x"],
        inputs=["u"],
        outputs=["x"],
        parameters=[Parameter("a", 1.0)],
        f=lambda x, u, p, c: (p.a * u[0],),
        g=lambda x, u, p, c: (x[0],),
        name="ramp",
    )
    t = np.linspace(0, 1, 11)
    X = kernel_for(m).integrate("euler", np.zeros((1, 1)), t[:, None], t, np.ones((1, 1)), {})
    np.testing.assert_allclose(X[:, 0, 0], np.concatenate([[0.0], np.cumsum(t[:-1] * 0.1)]), atol=1e-12)
    X = kernel_for(m).integrate("rk4", np.zeros((1, 1)), t[:, None], t, np.ones((1, 1)), {})
    np.testing.assert_allclose(X[:, 0, 0], t**2 / 2, atol=1e-12)


def test_default_rk4_step_matches_the_hand_computed_reference_step():
    """One RK4 step of x' = -a x + u^2 by hand with the reference software's convention:
    u_k at the first stage, (u_k + u_k+1)/2 at the two middle ones, u_k+1 at the last. The
    input enters squared, so holding the interval's mean at every stage gives another
    number, which the default must not."""
    m = Model(
        states=["x"],
        inputs=["u"],
        outputs=["x"],
        parameters=[Parameter("a", 2.0)],
        f=lambda x, u, p, c: (-p.a * x[0] + u[0] * u[0],),
        g=lambda x, u, p, c: (x[0],),
        name="squared-input",
    )
    a, h, x0, u0, u1 = 2.0, 0.1, 0.5, 1.0, 3.0
    um = 0.5 * (u0 + u1)

    def f(x, u):
        return -a * x + u * u

    def rk4(stage_inputs):
        ua, ub, uc, ud = stage_inputs
        k1 = f(x0, ua)
        k2 = f(x0 + 0.5 * h * k1, ub)
        k3 = f(x0 + 0.5 * h * k2, uc)
        k4 = f(x0 + h * k3, ud)
        return x0 + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)

    X = kernel_for(m).integrate(
        "rk4", np.array([[x0]]), np.array([[u0], [u1]]), np.array([0.0, h]), np.array([[a]]), {}
    )
    assert X[1, 0, 0] == pytest.approx(rk4((u0, um, um, u1)), rel=1e-14)
    assert abs(X[1, 0, 0] - rk4((um, um, um, um))) > 1e-3  # the old held-mean convention
    held = kernel_for(m).integrate(
        "rk4", np.array([[x0]]), np.array([[u0], [u1]]), np.array([0.0, h]), np.array([[a]]), {}, inputs="hold"
    )
    assert held[1, 0, 0] == pytest.approx(rk4((u0, u0, u0, u0)), rel=1e-14)
    # every estimator defaults to the same convention
    from estimators import EKF, UKF, FilterError, OutputError
    from estimators.integrators import DEFAULT_INPUTS

    assert DEFAULT_INPUTS == "linear"
    for cls in (OutputError, FilterError, EKF, UKF):  # (the unstable variants run OutputError)
        assert cls(m).inputs == "linear", cls


def test_compiled_kernel_equals_numpy_path():
    m = oscillator()
    t = np.linspace(0, 3, 151)
    U = np.zeros((t.size, 1))
    P = np.array([[2.0, 5.0, 7.0]])
    x0 = np.ones((2, 3))
    k = RhsKernel(m)
    Xj = k.integrate("rk4", x0, U, t, P, {})
    assert k.compiled
    k2 = RhsKernel(m)
    k2._jit_state = "off"
    Xp = k2.integrate("rk4", x0, U, t, P, {})
    np.testing.assert_allclose(Xj, Xp, rtol=1e-12, atol=1e-14)


def test_uncompilable_model_falls_back_with_warning():
    class Gain:  # an arbitrary Python object: numba cannot type it
        value = 1.0

    gain = Gain()

    def f(x, u, p, c):
        return x[1], -gain.value * p.k * x[0]

    m = Model(
        states=["x1", "x2"],
        inputs=["w"],
        outputs=["x1", "x2"],
        parameters=[Parameter("k", 4.0)],
        f=f,
        g=osc_g,
        name="dicty",
    )
    k = RhsKernel(m)
    t = np.linspace(0, 1, 51)
    with pytest.warns(RuntimeWarning, match="could not be compiled"):
        X = k.integrate("rk4", np.array([[1.0], [0.0]]), np.zeros((51, 1)), t, np.array([[4.0]]), {})
    assert not k.compiled
    np.testing.assert_allclose(X[-1, 0, 0], np.cos(2.0), atol=1e-6)


def test_divergence_fills_nan_and_stops():
    m = Model(
        states=["x"],
        inputs=["w"],
        outputs=["x"],
        parameters=[Parameter("a", 1.0)],
        f=lambda x, u, p, c: (p.a * x[0] * x[0],),
        g=lambda x, u, p, c: (x[0],),
        name="blowup",
    )
    t = np.linspace(0, 3, 301)  # x' = x^2, x0 = 1 blows up at t = 1
    X = kernel_for(m).integrate("rk4", np.ones((1, 1)), np.zeros((301, 1)), t, np.ones((1, 1)), {})
    finite = np.isfinite(X[:, 0, 0])
    assert finite[:90].all() and not finite[-1]
    assert not finite[np.argmin(finite) :].any()  # once non-finite, stays NaN


@pytest.mark.parametrize("scheme", ["euler", "rk2", "rk3", "rk4", "rkf45"])
def test_input_interpolation_modes(scheme):
    # x' = u: 'hold' integrates a zero-order-held input exactly, 'linear' a sampled ramp
    # (Euler's one stage reads u_k: the left sum)
    m = Model(
        states=["x"],
        inputs=["u"],
        outputs=["x"],
        parameters=[Parameter("a", 1.0)],
        f=lambda x, u, p, c: (p.a * u[0],),
        g=lambda x, u, p, c: (x[0],),
        name="integrator",
    )
    t = np.linspace(0, 1, 11)
    u = np.where(t >= 0.5, 1.0, 0.0)
    k = kernel_for(m)
    X = k.integrate(scheme, np.zeros((1, 1)), u[:, None], t, np.ones((1, 1)), {}, inputs="hold")
    np.testing.assert_allclose(X[:, 0, 0], np.concatenate([[0], np.cumsum(u[:-1] * 0.1)]), atol=1e-9)
    X = k.integrate(scheme, np.zeros((1, 1)), t[:, None], t, np.ones((1, 1)), {}, inputs="linear")
    exact = t**2 / 2 if scheme != "euler" else np.concatenate([[0.0], np.cumsum(t[:-1] * 0.1)])
    np.testing.assert_allclose(X[:, 0, 0], exact, atol=1e-9)
    with pytest.raises(Exception, match="unknown input interpolation"):
        k.integrate(scheme, np.zeros((1, 1)), t[:, None], t, np.ones((1, 1)), {}, inputs="average")
    with pytest.raises(Exception, match="unknown input interpolation"):
        k.integrate(scheme, np.zeros((1, 1)), t[:, None], t, np.ones((1, 1)), {}, inputs="cubic")
