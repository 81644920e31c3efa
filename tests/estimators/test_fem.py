"""Filter-error method: linear and nonlinear forms in turbulence, Riccati/discretisation
pieces against scipy, reduction to output error in calm air."""

import numpy as np
import pytest
from scipy import integrate, linalg

from estimators import EstimationResult, FilterError, OutputError
from estimators.filters.steady_state import continuous_gain, discrete_gain, discretize, expm, input_integrals
from estimators.process_noise_examples import turbulent_longitudinal_example, turbulent_short_period_example


def within(res, truth, k=3.0):
    err = {n: abs(res.params[n] - v) / res.std[n] for n, v in truth.items() if n in res.free_names}
    bad = {n: round(e, 2) for n, e in err.items() if not e < k}
    assert not bad, f"estimates outside {k} std of truth: {bad}"
    return err


@pytest.fixture(scope="module")
def sp():
    return turbulent_short_period_example(seed=2)


@pytest.fixture(scope="module")
def fem(sp):
    return FilterError(sp.model, process_noise={"alpha": 0.01, "q": 0.01}).fit(sp.segments)


def noise_truth(ex):
    return {f"F_{s}": ex.process_noise[i, i] for i, s in enumerate(ex.model.states)}


def test_fem_in_turbulence_recovers_parameters_and_noise(sp, fem):
    """The reference's criterion (diagonal R, the default) recovers the derivatives; the
    process noise it gives is biased where the innovations are correlated (it ignores
    their correlation), so F is checked on the full-R likelihood, identifiable here."""
    assert isinstance(fem, EstimationResult) and fem.method == "fem-nl"
    assert fem.converged and fem.iterations <= 15
    within(fem, sp.truth)
    full = FilterError(sp.model, process_noise={"alpha": 0.01, "q": 0.01}, full_R=True).fit(sp.segments)
    within(full, {**sp.truth, **noise_truth(sp)})
    # output error on the same data: std too small for its errors
    oem = OutputError(sp.model).fit(sp.segments)
    worst = max(abs(oem.params[n] - sp.truth[n]) / oem.std[n] for n in oem.free_names)
    assert worst > 3
    # the likelihood fell monotonically
    assert np.all(np.diff(fem.history["J"].to_numpy()) <= 1e-9)


def test_fem_result_contents(sp, fem):
    assert fem.free_names[-2:] == ["F_alpha", "F_q"]
    assert not any(n.startswith("G_") for n in fem.names)  # R is not a parameter
    K = fem.extra["gain"][0]
    assert K.shape == (2, 4) and np.all(np.isfinite(K))
    seg = sp.segments[1]
    np.testing.assert_allclose(fem.residuals[1].to_numpy(), seg.z - fem.predicted[1].to_numpy())
    # innovation covariance of the model ~ sample covariance of the innovations
    Bm = fem.extra["innovation_cov"][0]
    np.testing.assert_allclose(np.diag(fem.R), np.diag(Bm), rtol=0.15)
    # the measurement noise the gain implies, R - C P C^T, against the simulated noise
    np.testing.assert_allclose(np.sqrt(np.diag(fem.extra["measurement_noise"])), sp.noise_std, rtol=0.25)
    assert fem.extra["F"][0, 0] == pytest.approx(fem.params["F_alpha"])
    text = fem.summary(truth=sp.truth)
    assert "FEM" in text and "F_alpha" in text


def test_riccati_and_input_integrals_match_scipy():
    rng = np.random.default_rng(0)
    n, m, h = 3, 2, 0.05
    A = rng.standard_normal((n, n))
    A[0, 0] = 1.5  # unstable is fine
    FF = np.diag([0.1, 0.0, 0.3]) ** 2
    np.testing.assert_allclose(expm(A * 3.0), linalg.expm(A * 3.0), rtol=1e-10)
    ts = np.linspace(0, h, 2001)
    E = np.array([linalg.expm(A * s) for s in ts])
    # held input: Gamma0 = int e^{As} ds; first-order hold: Gamma1 = int e^{A(h-s)} s/h ds
    Phi1, G0, G1 = input_integrals(A, h)
    E1 = np.array([linalg.expm(A * (h - s)) * s / h for s in ts])
    np.testing.assert_allclose(Phi1, linalg.expm(A * h), rtol=1e-12)
    np.testing.assert_allclose(G0, integrate.simpson(E, x=ts, axis=0), rtol=1e-8)
    np.testing.assert_allclose(G1, integrate.simpson(E1, x=ts, axis=0), rtol=1e-8)
    # the continuous Riccati equation with the innovation covariance R, batched
    C = rng.standard_normal((m, n))
    R = np.diag([1e-3, 4e-3])
    P, K = continuous_gain(np.stack([A, 0.5 * A]), np.stack([C, C]), np.stack([FF, FF]), R, h)
    for b, Ab in enumerate((A, 0.5 * A)):
        np.testing.assert_allclose(P[b], linalg.solve_continuous_are(Ab.T, C.T, FF, R * h), rtol=1e-8)
        np.testing.assert_allclose(K[b], P[b] @ C.T @ np.linalg.inv(R), rtol=1e-12)
        res = Ab @ P[b] + P[b] @ Ab.T - P[b] @ C.T @ np.linalg.inv(R * h) @ C @ P[b] + FF
        assert np.abs(res).max() < 1e-9 * np.abs(FF).max()
    P0, K0 = continuous_gain(A[None], C[None], np.zeros((1, n, n)), R, h)
    assert not P0.any() and not K0.any()
    # the sampled filter's form (gain="discrete"): Qd by van Loan against quadrature, and
    # P = Phi (P - P C^T R^-1 C P) Phi^T + Qd solved
    Phi, Gam, Qd = discretize(A, FF, h)
    np.testing.assert_allclose(Phi, linalg.expm(A * h), rtol=1e-12)
    np.testing.assert_allclose(Gam, G0, rtol=1e-12)
    np.testing.assert_allclose(
        Qd, integrate.simpson(E @ FF @ E.transpose(0, 2, 1), x=ts, axis=0), rtol=1e-7, atol=1e-14
    )
    Pd, Kd = discrete_gain(A[None], C[None], FF[None], R, h)
    Ri = np.linalg.inv(R)
    res = Phi @ (Pd[0] - Pd[0] @ C.T @ Ri @ C @ Pd[0]) @ Phi.T + Qd - Pd[0]
    assert np.abs(res).max() < 1e-10 * np.abs(Pd[0]).max()
    np.testing.assert_allclose(Kd[0], Pd[0] @ C.T @ Ri, rtol=1e-12)


def test_without_process_noise_fem_is_output_error():
    calm = turbulent_short_period_example(seed=4, sigma_alpha=0.0, sigma_q=0.0)
    # output error's R is diagonal: so is this filter error's
    fem = FilterError(calm.model, process_noise={"alpha": 0.0, "q": 0.0}, estimate_F=False, full_R=False).fit(
        calm.segments
    )
    oem = OutputError(calm.model).fit(calm.segments)
    names = oem.free_names
    d = (fem.params[names] - oem.params[names]).abs() / oem.std[names]
    assert d.max() < 0.05
    np.testing.assert_allclose(fem.std[names], oem.std[names], rtol=0.02)
    np.testing.assert_allclose(fem.extra["gain"][0], 0.0, atol=1e-12)


def test_nonlinear_fem_in_turbulence():
    ex = turbulent_longitudinal_example(seed=5, n=500)
    res = FilterError(ex.model, process_noise={"alpha": 0.01, "q": 0.01}, form="nonlinear").fit(ex.segments)
    assert res.method == "fem-nl" and res.converged
    within(res, {**ex.truth, "F_alpha": 0.005, "F_q": 0.01})
    assert res.settings["linearisation"].startswith("about x0")


@pytest.mark.slow
def test_compiled_filter_loop_with_selected_outputs():
    """A model observing a subset of its outputs (Model.select_outputs: data without qdot)
    runs FEM's compiled filter loop - it had fallen back to the numpy loop, numba cannot
    compile the selection's generator - with the same estimates as the numpy loop."""
    from estimators import Segment
    from estimators.filters.kernels import output_kernel

    ex = turbulent_longitudinal_example(seed=5, n=300)
    keep = [o for o in ex.model.outputs if o != "qdot"][::-1]  # a subset, reordered
    rows = [ex.model.outputs.index(o) for o in keep]
    model = ex.model.select_outputs(keep).select_outputs(keep[1:])  # twice: composed
    segs = [Segment(t=s.t, u=s.u, z=s.z[:, rows[1:]], x0=s.x0) for s in ex.segments]
    kw = dict(process_noise={"alpha": 0.01, "q": 0.01}, form="nonlinear")
    fast = FilterError(model, **kw).fit(segs)
    assert output_kernel(model) is not None
    slow = FilterError(model, compiled=False, **kw).fit(segs)
    # the same arithmetic in another order: rounding, compounded over the samples and the
    # iterations, must stay negligible against each estimate's std on any machine
    free = fast.free_names
    np.testing.assert_array_less(np.abs(fast.params[free] - slow.params[free]), 1e-4 * fast.std[free])
    within(fast, ex.truth)


def test_coloured_innovation_bounds(sp, fem):
    """Morelli-Klein on the innovations (extra["mk_cov"]): the right noise model gives
    white innovations and about the Cramér-Rao bounds back; a filter
    that leaves out the pitch-rate process noise gets coloured innovations, derivatives
    4.5-7.6 CRB std off (Cmde, Cmq, Cmalpha), and bounds 3.5-4.4x wider that cover them."""
    names = fem.extra["mk_names"]
    assert names == list(fem.free_names)
    ratio = {n: np.sqrt(fem.extra["mk_cov"][i, i]) / fem.std[n] for i, n in enumerate(names)}
    truth = {n: v for n, v in sp.truth.items() if n in ratio and n.startswith("C")}
    # the diagonal R ignores the innovations' correlation between outputs, which the
    # Morelli-Klein sandwich counts: the bounds it gives are up to a fifth tighter
    assert len(truth) == 5 and all(0.75 < ratio[n] < 1.15 for n in truth), ratio
    short = FilterError(sp.model, process_noise={"alpha": 0.01}).fit(sp.segments)
    names = short.extra["mk_names"]
    mk = {n: np.sqrt(short.extra["mk_cov"][i, i]) for i, n in enumerate(names)}
    crb_err = {n: abs(short.params[n] - v) / short.std[n] for n, v in truth.items()}
    mk_err = {n: abs(short.params[n] - v) / mk[n] for n, v in truth.items()}
    assert max(crb_err.values()) > 4.0, crb_err  # the bound the model believes
    assert max(mk_err.values()) < 3.0, mk_err  # the bound the innovations give
    assert min(mk[n] / short.std[n] for n in ("Cmalpha", "Cmq", "Cmde")) > 2.0


@pytest.mark.parametrize("form", ["linear", "nonlinear"])
def test_multi_rate_outputs_keep_their_information(sp, fem, form):
    """Outputs measured at a lower rate (NaN between samples): every sample counts, on the
    outputs measured there, with the gain of that set of outputs. Before, the likelihood
    took only the samples where every output was measured: with one output at a fifth of
    the rate the std grew 1.8x (HFB-320 Cmq, ad-hoc) - here the derivatives stay within 3
    std, the ones the other outputs carry keep their std, and a sample's missing output
    does not correct the states (its gain column is zero, the others are the gain of the
    measured outputs)."""
    from estimators import Segment
    from estimators.filters.steady_state import output_patterns, pattern_gains

    segs = []
    for s in sp.segments:
        z = s.z.copy()
        z[np.arange(s.n) % 5 != 0, 0] = np.nan  # the first output at 1/5 the rate
        segs.append(Segment(t=s.t, u=s.u, z=z, x0=s.x0, name=s.name))
    res = FilterError(sp.model, process_noise={"alpha": 0.01, "q": 0.01}, form=form).fit(segs)
    assert res.converged
    within(res, sp.truth)
    ratio = {n: res.std[n] / fem.std[n] for n in sp.truth if n in res.free_names}
    # Cmq comes from the pitch rate, measured at every sample: it keeps its std (1.01x;
    # counting only the samples with alpha it would be ~sqrt(5) = 2.2x); CLalpha comes from
    # alpha and loses some (1.8x)
    assert ratio["Cmq"] < 1.15 and ratio["CLalpha"] > 1.3, ratio
    masks, pat = output_patterns(segs[0].z)
    assert masks.shape[0] == 2 and np.bincount(pat).min() == segs[0].n // 5
    C = np.random.default_rng(0).standard_normal((1, len(sp.model.outputs), len(sp.model.states)))
    K = np.stack(res.extra["gain"][:1])
    Kp = pattern_gains(np.stack(res.extra["P"][:1]), C, np.stack(res.extra["innovation_cov"][:1]), K, masks)
    part = int(np.flatnonzero(~masks.all(axis=1))[0])
    assert np.all(Kp[0, part][:, 0] == 0.0) and np.all(Kp[0, 1 - part] == K[0])
