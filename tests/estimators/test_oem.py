"""Output-error method: convergence, Cramér-Rao consistency, bounds, segments, failures."""

import numpy as np
import pytest

from estimators import (
    BoundsError,
    IdentifiabilityError,
    Model,
    ModelDefinitionError,
    OutputError,
    Parameter,
    Segment,
    SimulationDivergedError,
)
from estimators.datasets import HFB320_CONSTANTS, HFB320_FREE, HFB320_TRUTH, longitudinal_example, multistep
from estimators.models import lateral_directional, longitudinal, short_period
from estimators.simulation import simulate_outputs
from estimators.validation import morelli_klein


@pytest.fixture(scope="module")
def example():
    return longitudinal_example(seed=11)


@pytest.fixture(scope="module")
def fitted(example):
    return OutputError(example.model).fit(example.segments)


def within(res, truth, k=3.0, names=None):
    names = names or [n for n in res.free_names if n in truth]
    err = {n: abs(res.params[n] - truth[n]) / res.std[n] for n in names}
    bad = {n: round(e, 2) for n, e in err.items() if not e < k}
    assert not bad, f"estimates outside {k} std of truth: {bad}"


def test_converges_from_30_percent_off_within_15_iterations(example, fitted):
    starts = {n: example.model.parameter(n).value for n in HFB320_FREE}
    off = [abs(starts[n] / HFB320_TRUTH[n] - 1) for n in HFB320_FREE]
    assert min(off) == pytest.approx(0.3)
    assert fitted.converged and fitted.iterations <= 15
    within(fitted, example.truth)
    # the residual covariance is the noise covariance that was applied
    np.testing.assert_allclose(np.sqrt(np.diag(fitted.R)), example.noise_std, rtol=0.1)
    # cost history falls monotonically
    assert np.all(np.diff(fitted.history["det_R"].to_numpy()) <= 0)


def test_result_object(fitted, example):
    assert list(fitted.params.index[:4]) == ["CD0", "CDalpha", "CDalpha2", "CDde"]
    assert np.isnan(fitted.std["CDalpha2"])  # fixed parameter: no std
    assert fitted.params["CDalpha2"] == 0.0
    c = fitted.corr
    assert c.shape == (11, 11) and np.allclose(np.diag(c), 1.0)
    assert ("CD0", "CDalpha") in {(a, b) for a, b, _ in fitted.flagged_correlations}
    assert fitted.rel_std["Cmq"] == pytest.approx(100 * fitted.std["Cmq"] / abs(fitted.params["Cmq"]))
    assert fitted.cost == pytest.approx(np.linalg.det(fitted.R))
    r = fitted.residuals[0]
    np.testing.assert_allclose(r.to_numpy(), example.segments[0].z - fitted.predicted[0].to_numpy())
    text = fitted.summary(truth=example.truth)
    for word in ("Cmq", "Converged: yes", "det(R)", "|correlation| > 0.9", "CD0~CDalpha"):
        assert word in text
    d = fitted.to_dict(example.truth)
    assert d["parameters"]["Cmq"]["truth"] == -16.0 and d["converged"] is True


@pytest.mark.slow
def test_optimizer_and_jacobian_variants_agree(example, fitted):
    for kw in (
        {"optimizer": "levenberg-marquardt"},
        {"jacobian": "central"},
        {"integrator": "rkf45"},
        {"fallback": "always"},
    ):
        res = OutputError(example.model, **kw).fit(example.segments)
        assert res.converged, kw
        diff = (res.params[res.free_names] - fitted.params[res.free_names]).abs() / fitted.std[res.free_names]
        assert diff.max() < 0.05, (kw, diff.idxmax(), diff.max())
        if kw.get("fallback"):
            assert "Nelder-Mead" in res.message


def test_full_noise_covariance_matches_diagonal_on_independent_noise(example, fitted):
    res = OutputError(example.model, noise="full").fit(example.segments)
    assert res.R.shape == (7, 7) and np.count_nonzero(res.R - np.diag(np.diag(res.R))) > 0
    within(res, example.truth)


def test_prior_pulls_estimate_and_shrinks_std(example, fitted):
    prior = {"Cmq": (-14.0, 0.01 * fitted.std["Cmq"])}  # a very confident a-priori value
    res = OutputError(example.model, priors=prior).fit(example.segments)
    assert abs(res.params["Cmq"] + 14.0) < 0.05 * fitted.std["Cmq"]
    assert res.std["Cmq"] < 0.02 * fitted.std["Cmq"]
    # the prior's information is kept apart, so the Morelli-Klein sandwich carries it: at
    # lag 0 it is the Cramér-Rao bound again (without it Cmq's fell to 0.015 x)
    W = res.extra["prior_information"]
    i = res.free_names.index("Cmq")
    assert W[i, i] == pytest.approx(1.0 / prior["Cmq"][1] ** 2) and np.count_nonzero(W) == 1
    mk = morelli_klein(
        res.sensitivities, [r.to_numpy() for r in res.residuals], R=res.R, info=res.information, max_lag=0, prior_info=W
    )
    np.testing.assert_allclose(mk.ratio, 1.0, atol=0.1)  # v v^T is R on average only
    bare = morelli_klein(
        res.sensitivities, [r.to_numpy() for r in res.residuals], R=res.R, info=res.information, max_lag=0
    )
    assert bare.ratio[i] < 0.1


def test_bounds_are_respected_and_reported(example):
    m = longitudinal(
        HFB320_CONSTANTS, values={**HFB320_TRUTH, "Cmq": -12.0}, free=HFB320_FREE, bounds={"Cmq": (-15.0, 0.0)}
    )
    res = OutputError(m).fit(example.segments)
    assert res.params["Cmq"] == pytest.approx(-15.0)
    assert res.at_bounds == ["Cmq"] and np.isnan(res.std["Cmq"])
    assert "at bound" in res.summary()
    assert np.isfinite(res.std[[n for n in res.free_names if n != "Cmq"]]).all()


def test_two_segments_with_per_segment_initial_states_and_biases():
    ex = longitudinal_example(seed=3, segments=2, n=500)
    biases = [(0.3, -0.02), (-0.2, 0.015)]  # (az m/s^2, q rad/s) per segment
    for seg, (baz, bq) in zip(ex.segments, biases):
        seg.z[:, 6] += baz
        seg.z[:, 3] += bq
        seg.x0 = seg.x0 + np.array([1.5, 0.01, -0.01, 0.0])  # start state 1.5 m/s, 0.6 deg off
    m = longitudinal(
        HFB320_CONSTANTS,
        values={p.name: p.value for p in ex.model.parameters},
        free=HFB320_FREE,
        output_biases=["az", "q"],
    )
    res = OutputError(m).fit(ex.segments, estimate_x0=["V", "alpha", "theta"])
    assert res.converged
    truth = dict(ex.truth)
    for k, (baz, bq) in enumerate(biases):
        truth[f"bias_az[{k}]"] = baz
        truth[f"bias_q[{k}]"] = bq
        x0 = ex.segments[k].x0 - np.array([1.5, 0.01, -0.01, 0.0])
        truth.update({f"x0_V[{k}]": x0[0], f"x0_alpha[{k}]": x0[1], f"x0_theta[{k}]": x0[2]})
    assert "x0_q[0]" in res.names and "x0_q[0]" not in res.free_names
    within(res, truth, names=[n for n in res.free_names])


def test_short_period_and_lateral_models_recover_truth():
    rng = np.random.default_rng(5)
    t = np.arange(0, 15, 0.02)
    c = {"m": 1200.0, "Iyy": 1800.0, "S": 16.0, "cbar": 1.5, "rho": 1.1, "V": 55.0}
    sp_truth = {"CLalpha": 5.2, "CLq": 0.0, "CLde": 0.45, "Cmalpha": -0.9, "Cmq": -12.0, "Cmde": -1.3}
    sp = short_period(c, values=sp_truth)
    de = multistep(t, 1.0, 0.4, amplitude=np.radians(2))
    seg = Segment(t=t, u=de[:, None], z=np.zeros((t.size, 4)), x0=[0.0, 0.0])
    y = simulate_outputs(sp, seg).to_numpy()
    seg.z = y + rng.standard_normal(y.shape) * np.array([1e-3, 2e-3, 1e-2, 0.05])
    start = short_period(c, values={k: v * 0.7 for k, v in sp_truth.items()})
    within(OutputError(start).fit(seg), sp_truth)

    cl = {
        "m": 1200.0,
        "Ixx": 1400.0,
        "Izz": 2600.0,
        "Ixz": 60.0,
        "S": 16.0,
        "b": 11.0,
        "rho": 1.1,
        "V": 55.0,
        "alpha0": 0.05,
        "theta0": 0.05,
    }
    lat_truth = {
        "CYbeta": -0.6,
        "CYp": 0.0,
        "CYr": 0.0,
        "CYda": 0.0,
        "CYdr": 0.17,
        "Clbeta": -0.09,
        "Clp": -0.48,
        "Clr": 0.09,
        "Clda": 0.16,
        "Cldr": 0.012,
        "Cnbeta": 0.07,
        "Cnp": -0.04,
        "Cnr": -0.14,
        "Cnda": -0.008,
        "Cndr": -0.075,
    }
    lat = lateral_directional(cl, values=lat_truth)
    da = multistep(t, 1.0, 0.5, (2, -2), np.radians(5))
    dr = multistep(t, 6.0, 0.7, (3, -2, 1, -1), np.radians(4))
    seg = Segment(t=t, u=np.column_stack([da, dr]), z=np.zeros((t.size, 7)), x0=np.zeros(4))
    y = simulate_outputs(lat, seg).to_numpy()
    seg.z = y + rng.standard_normal(y.shape) * np.array([1e-3, 2e-3, 2e-3, 2e-3, 0.05, 0.02, 0.02])
    start = lateral_directional(cl, values={k: v * 1.3 for k, v in lat_truth.items()})
    res = OutputError(start).fit(seg)
    assert res.converged and res.iterations <= 15
    within(res, lat_truth)


# --- failures ---------------------------------------------------------------------------


def test_start_outside_bounds_raises():
    with pytest.raises(BoundsError, match="outside its bounds"):
        Parameter("Cmq", -90.0, bounds=(-80.0, 0.0))
    with pytest.raises(BoundsError, match="Cmq"):
        longitudinal(HFB320_CONSTANTS, values={"Cmq": 5.0}, bounds={"Cmq": (-80.0, 0.0)})


def test_diverging_simulation_raises(example):
    m = longitudinal(HFB320_CONSTANTS, values={**HFB320_TRUTH, "Cmalpha": 60.0, "Cmq": 40.0}, free=HFB320_FREE)
    with pytest.raises(SimulationDivergedError, match="diverged at t=") as info:
        OutputError(m).fit(example.segments)
    assert info.value.segment == 0 and 0 < info.value.time < 12


def _lin_model(params):
    def f(x, u, p, c):
        (s,) = x
        (w,) = u
        return (-s + (p.a + p.b) * w,)

    def g(x, u, p, c):
        (s,) = x
        return (s,)

    return Model(states=["s"], inputs=["w"], outputs=["s"], parameters=params, f=f, g=g, name="sum")


def test_singular_information_names_the_parameters():
    t = np.linspace(0, 10, 501)
    w = np.sin(t)
    params = [Parameter("a", 1.0), Parameter("b", 0.5), Parameter("unused", 2.0)]
    seg = Segment(t=t, u=w[:, None], z=np.zeros((501, 1)), x0=[0.0])
    seg.z = simulate_outputs(_lin_model(params), seg).to_numpy() + 0.01 * np.cos(7 * t)[:, None]
    with pytest.raises(IdentifiabilityError) as info:
        OutputError(_lin_model(params)).fit(seg)
    assert set(info.value.parameters) == {"a", "b", "unused"}
    assert "cannot be identified" in str(info.value)
    params[1] = Parameter("b", 0.5, free=False)
    params[2] = Parameter("unused", 2.0, free=False)
    res = OutputError(_lin_model(params)).fit(seg)
    assert res.params["a"] == pytest.approx(1.0, abs=1e-3)


def test_identifiability_does_not_depend_on_the_parameters_units():
    """A parameter with little information in its own units is not "without sensitivity":
    filter error's F_alpha (information 3.5e16) next to CLq (24, std 0.2) once failed a fit."""
    from estimators.statistics import unidentifiable

    F = np.diag([3.5e16, 24.0, 1.2e8])
    F[1, 2] = F[2, 1] = 0.5 * np.sqrt(24.0 * 1.2e8)  # correlated, not dependent
    assert unidentifiable(F, ["F_alpha", "CLq", "CL0"]) == []
    F[1, 1] = F[1, 2] = F[2, 1] = 0.0  # CLq without any effect
    assert unidentifiable(F, ["F_alpha", "CLq", "CL0"]) == ["CLq"]
    G = np.array([[4.0, 2.0], [2.0, 1.0]])  # b = 2 a: one direction
    assert set(unidentifiable(G, ["a", "b"])) == {"a", "b"}


def test_bad_segments_are_rejected(example):
    seg = example.segments[0]
    t = seg.t.copy()
    t[10] = t[9]
    with pytest.raises(ModelDefinitionError, match="not strictly increasing"):
        Segment(t=t, u=seg.u, z=seg.z)
    u = seg.u.copy()
    u[5, 0] = np.nan
    with pytest.raises(ModelDefinitionError, match="NaN"):
        Segment(t=seg.t, u=u, z=seg.z)
    with pytest.raises(ModelDefinitionError, match="columns"):
        OutputError(example.model).fit(Segment(t=seg.t, u=seg.u[:, :1], z=seg.z, x0=seg.x0))


def test_analytic_sensitivity_hook_matches_finite_differences():
    """x' = -a x + b w, y = x: the hook integrates the sensitivity equations
    s_a' = -x - a s_a, s_b' = -a s_b + w alongside the state."""

    def f(x, u, p, c):
        (s,) = x
        (w,) = u
        return (-p.a * s + p.b * w,)

    def g(x, u, p, c):
        return (x[0],)

    model = Model(
        states=["s"],
        inputs=["w"],
        outputs=["s"],
        parameters=[Parameter("a", 1.5), Parameter("b", 0.5)],
        f=f,
        g=g,
        name="first",
    )

    def fa(x, u, p, c):
        s, sa, sb = x
        (w,) = u
        return -p.a * s + p.b * w, -s - p.a * sa, -p.a * sb + w

    aug = Model(
        states=["s", "sa", "sb"],
        inputs=["w"],
        outputs=["s", "sa", "sb"],
        parameters=[Parameter("a", 1.5), Parameter("b", 0.5)],
        f=fa,
        g=lambda x, u, p, c: (x[0], x[1], x[2]),
        name="first-sens",
    )
    calls = []

    def hook(model_, seg, k, layout, theta):
        calls.append(k)
        vals = dict(zip(layout.names, theta))
        aseg = Segment(t=seg.t, u=seg.u, z=np.zeros((seg.n, 3)), x0=[seg.x0[0], 0.0, 0.0])
        y = simulate_outputs(aug, aseg, {"a": vals["a"], "b": vals["b"]}).to_numpy()
        return y[:, :1], y[:, None, 1:]  # Y (N, 1), S (N, 1, 2)

    t = np.linspace(0, 10, 501)
    w = np.sign(np.sin(1.3 * t))
    seg = Segment(t=t, u=w[:, None], z=np.zeros((501, 1)), x0=[0.0])
    truth = {"a": 2.0, "b": 1.2}
    clean = simulate_outputs(model, seg, truth).to_numpy()
    seg.z = clean + 0.01 * np.random.default_rng(2).standard_normal(clean.shape)
    fd = OutputError(model).fit(seg)
    an = OutputError(model, jacobian=hook).fit(seg)
    assert calls and an.settings["jacobian"] == "analytic"
    for n in ("a", "b"):
        assert abs(an.params[n] - fd.params[n]) < 0.01 * fd.std[n]
        assert an.std[n] == pytest.approx(fd.std[n], rel=1e-4)
    within(an, truth)


def test_missing_samples_get_zero_weight(example, fitted):
    """Multi-rate data: alpha and theta measured at every other sample only (NaN between)."""
    seg = example.segments[0]
    z = seg.z.copy()
    z[1::2, 1:3] = np.nan
    res = OutputError(example.model).fit(Segment(t=seg.t, u=seg.u, z=z, x0=seg.x0))
    assert res.converged
    within(res, example.truth)
    assert np.isnan(res.residuals[0]["alpha"].to_numpy()[1::2]).all()
    # fewer angle samples: the angle-driven derivatives lose information, none gains any
    free = list(HFB320_FREE)
    assert (res.std[free] >= fitted.std[free] * 0.999).all()
    assert res.std["CLalpha"] > 1.05 * fitted.std["CLalpha"]


@pytest.mark.parametrize(
    "kw,match", [({"integrator": "rk5"}, "unknown integrator"), ({"inputs": "cubic"}, "inputs must be one of")]
)
def test_every_estimator_rejects_unknown_integration_options(example, kw, match):
    from estimators import EKF, UKF, FilterError

    for cls in (OutputError, FilterError, EKF, UKF):
        with pytest.raises(ModelDefinitionError, match=match):
            cls(example.model, **kw)


def _wrong_after(n_good: int):
    """A first-order model x' = -a x + b w, its noisy data, and a sensitivity hook that is
    right for its first ``n_good`` calls and sign-flipped afterwards (a gradient that stops
    pointing downhill)."""
    model = Model(
        states=["x"],
        inputs=["w"],
        outputs=["x"],
        parameters=[Parameter("a", 1.5), Parameter("b", 0.5)],
        f=lambda x, u, p, c: (-p.a * x[0] + p.b * u[0],),
        g=lambda x, u, p, c: (x[0],),
        name="first-order",
    )
    t = np.linspace(0, 10, 501)
    seg = Segment(t=t, u=np.sign(np.sin(1.3 * t))[:, None], z=np.zeros((501, 1)), x0=[0.0])
    seg.z = simulate_outputs(model, seg, {"a": 2.0, "b": 1.2}).to_numpy() + 0.01 * np.random.default_rng(
        3
    ).standard_normal((501, 1))
    calls = []

    def hook(model_, seg_, k, layout, theta):
        vals = dict(zip(layout.names, theta))
        y = simulate_outputs(model_, seg_, vals).to_numpy()
        S = np.empty((seg_.n, 1, 2))
        for j, n in enumerate(("a", "b")):
            h = 1e-6 * max(abs(vals[n]), 1.0)
            S[:, 0, j] = (simulate_outputs(model_, seg_, {**vals, n: vals[n] + h}).to_numpy()[:, 0] - y[:, 0]) / h
        calls.append(k)
        return y, (S if len(calls) <= n_good else -S)

    return model, seg, hook


def test_simplex_fallback_only_when_no_step_was_accepted():
    """'auto' runs Nelder-Mead when Gauss-Newton cannot move from the start; once steps
    were accepted, a failing line search ends the fit with a message instead of a simplex
    over every parameter (minutes on the stabilised models' numpy path)."""
    model, seg, hook = _wrong_after(0)
    res = OutputError(model, jacobian=hook).fit(seg)
    assert "Nelder-Mead" in res.message
    model, seg, hook = _wrong_after(1)
    res = OutputError(model, jacobian=hook).fit(seg)
    assert not res.converged and res.iterations == 2
    assert "Nelder-Mead" not in res.message and "after 1 accepted steps" in res.message


def test_hold_fixes_named_parameters(example, fitted):
    """Model.hold: the named parameters fixed at the given values, the others as they were;
    the fit then estimates the rest (one parameter fewer)."""
    m = example.model
    free0 = [p.name for p in m.parameters if p.free]
    name = free0[0]
    held = m.hold({name: example.truth[name]})
    assert not held.parameter(name).free and held.parameter(name).value == example.truth[name]
    assert [p.name for p in held.parameters if p.free] == free0[1:]
    assert m.parameter(name).free  # the original is untouched
    res = OutputError(held).fit(example.segments)
    assert name not in res.free_names and res.params[name] == example.truth[name]
    with pytest.raises(ModelDefinitionError, match="no parameter"):
        m.hold({"Cnope": 0.0})


@pytest.fixture(scope="module")
def two_segments():
    """Two 3-2-1-1 segments with their initial states estimated: each segment depends on
    the shared derivatives and its own x0 only."""
    ex = longitudinal_example(seed=5, segments=2)
    return ex, OutputError(ex.model).fit(ex.segments, estimate_x0=True)


def test_sensitivities_are_kept_per_segment_for_its_own_parameters(two_segments):
    from estimators import statistics as st

    ex, res = two_segments
    names = res.free_names
    for k, S in enumerate(res.sensitivities):
        own = {names[i] for i in S.cols}
        other = 1 - k
        assert not any(n.endswith(f"[{other}]") for n in own)  # not the other's x0
        assert {n for n in names if "[" not in n} <= own
        dense = np.asarray(S)
        assert dense.shape == S.shape == (ex.segments[k].n, 7, len(names)) and S.ndim == 3
        np.testing.assert_array_equal(S[:, :, 3], dense[:, :, 3])  # indexes as the array
        assert not np.any(dense[:, :, [i for i in range(len(names)) if i not in S.cols]])
    # the blocks give the information of the dense arrays
    E = [r.to_numpy() for r in res.residuals]
    L = st.whitener(res.R)
    F_b, G_b, J_b = st.information_and_gradient(res.sensitivities, E, L)
    F_d, G_d, J_d = st.information_and_gradient([np.asarray(S) for S in res.sensitivities], E, L)
    np.testing.assert_allclose(F_b, F_d, rtol=1e-12)
    np.testing.assert_allclose(G_b, G_d, rtol=1e-9, atol=1e-7 * np.abs(G_d).max())  # ~0 at the optimum
    np.testing.assert_allclose(F_b, res.information, rtol=1e-10)


def test_step_from_gives_the_refit_change_of_a_held_value(two_segments):
    """Moving the held CDalpha2 by 0.1: one Gauss-Newton step with the fit's sensitivities
    moves the estimates as a full refit does (the first-order change a consider
    parameter's Jacobian needs), and by many std."""
    ex, res = two_segments
    held = ex.model.hold({"CDalpha2": 0.1})
    step = OutputError(held).step_from(res, ex.segments, estimate_x0=True)
    refit = OutputError(held).fit(ex.segments, estimate_x0=True, start={n: res.params[n] for n in res.free_names})
    names = [n for n in res.free_names if "[" not in n]
    d_step = step.params[names] - res.params[names]
    d_refit = refit.params[names] - res.params[names]
    assert (d_refit.abs() / res.std[names]).max() > 3.0  # a change that matters
    np.testing.assert_allclose(d_step, d_refit, atol=0.05 * float(d_refit.abs().max()))
    assert step.params["CDalpha2"] == 0.1 and step.free_names == res.free_names
    # other segments than the fit's: one clear error
    with pytest.raises(ModelDefinitionError, match="segments"):
        OutputError(held).step_from(res, ex.segments[:1], estimate_x0=True)
