"""Transfer functions with a delay fitted in the frequency domain (estimators.TransferFunction)
and the short-period LOES figures (estimators.loes_parameters): a pitch-rate response of
known numerator, denominator and delay, flown with a chirp and measured with noise."""

import numpy as np
import pytest
import scipy.signal as ss

from estimators import ModelDefinitionError, TransferFunction, frequency_response, loes_parameters

DT = 0.01
K, Z, WN, ZETA, TAU = 6.0, 1.5, 3.0, 0.5, 0.08
TRUTH = {"b1": K, "b0": K * Z, "a1": 2 * ZETA * WN, "a0": WN**2, "tau": TAU}


def _flight(seed: int, noise: float = 0.05):
    t = np.arange(0, 40, DT)
    # a logarithmic sweep from rest to rest (tapered in, 3 s of rest at the end): a
    # finite record's transform is H U only when the response has died out at its ends
    u = ss.chirp(t, 0.1, 37.0, 3.0, method="logarithmic") * np.hanning(t.size) ** 0.2 * (t < 37.0)
    n = int(round(TAU / DT))
    delayed = np.concatenate([np.zeros(n), u[:-n]])
    y = ss.lsim(ss.TransferFunction([K, K * Z], [1, 2 * ZETA * WN, WN**2]), delayed, t)[1]
    rng = np.random.default_rng(seed)
    return t, u, y + noise * np.std(y) * rng.standard_normal(t.size)


W = 2 * np.pi * np.linspace(0.15, 3.0, 60)


@pytest.mark.parametrize("method", ["oe", "ee"])
def test_time_histories_give_the_truth_within_the_bounds(method):
    t, u, y = _flight(0)
    res = TransferFunction(1, 2, delay=True).fit(t, u, y, w=W, method=method)
    assert res.method == f"tf-{method}" and list(res.params.index) == ["b1", "b0", "a1", "a0", "tau"]
    for n, v in TRUTH.items():
        assert abs(res.params[n] - v) < 3 * max(res.std[n], res.std_of("sandwich")[n]), (n, res.params[n], v)
    np.testing.assert_allclose(res.extra["num"], res.params[["b1", "b0"]])
    np.testing.assert_allclose(res.extra["den"], [1.0, res.params["a1"], res.params["a0"]])
    hq = loes_parameters(res)
    assert hq["omega_sp"] == pytest.approx(np.sqrt(res.params["a0"]))
    assert hq["zeta_sp"] == pytest.approx(res.params["a1"] / (2 * hq["omega_sp"]))
    assert hq["one_over_T_theta2"] == pytest.approx(res.params["b0"] / res.params["b1"])
    assert abs(hq["omega_sp"] - WN) < 0.1 and abs(hq["zeta_sp"] - ZETA) < 0.05 and abs(hq["tau"] - TAU) < 0.01


@pytest.mark.slow  # a Monte Carlo of fits: the edit loop's tier goes without it
def test_output_error_bounds_hold_over_noise_draws():
    """Over 30 noise draws output error is unbiased, and the scatter agrees with both the
    reference's Cramér-Rao std (M = Re sum dv^H dv / s2) and the sandwich std within the
    sampling spread of 30 draws (a std ratio spreads by about 1/sqrt(60), 13 %) and the
    reference's convention (it counts the complex residuals once: up to sqrt(2) above the
    scatter for independent frequencies)."""
    est, crb, sw = [], [], []
    tf = TransferFunction(1, 2, delay=True)
    for seed in range(30):
        r = tf.fit(*_flight(100 + seed), w=W, method="oe")
        est.append(r.values)
        crb.append(r.std.to_numpy())
        sw.append(r.std_of("sandwich").to_numpy())
    est = np.array(est)
    spread = est.std(axis=0)
    bias = (est.mean(axis=0) - np.array(list(TRUTH.values()))) / (spread / np.sqrt(30))
    assert np.all(np.abs(bias) < 3.5), bias
    assert np.all((0.6 < spread / np.mean(crb, axis=0)) & (spread / np.mean(crb, axis=0) < 1.3))
    assert np.all((0.6 < spread / np.mean(sw, axis=0)) & (spread / np.mean(sw, axis=0) < 1.4))


def test_a_frequency_response_is_fitted_by_cifers_cost():
    t, u, y = _flight(1)
    fr = frequency_response(t, u, y, f=np.geomspace(0.1, 3.0, 40))
    res = TransferFunction(1, 2, delay=True).fit(fr, f_band=(0.15, 3.0))
    assert res.method == "tf-fr" and res.extra["J"] < 100  # the usual acceptance
    hq = loes_parameters(res)
    assert abs(hq["omega_sp"] - WN) < 0.25 and abs(hq["zeta_sp"] - ZETA) < 0.08 and abs(hq["tau"] - TAU) < 0.015
    # a wrong structure (first order) cannot follow the resonance: J far above
    assert TransferFunction(0, 1).fit(fr, f_band=(0.15, 3.0)).extra["J"] > 5 * res.extra["J"]


def test_the_canonical_model_simulates_the_fitted_response():
    from estimators import Segment, simulate_outputs

    t, u, y = _flight(2, noise=0.0)
    res = TransferFunction(1, 2, delay=True).fit(t, u, y, w=W)
    n = int(round(res.params["tau"] / DT))
    seg = Segment(t=t, u=np.concatenate([np.zeros(n), u[:-n]])[:, None], z=y[:, None], x0=np.zeros(2))
    sim = simulate_outputs(res.model, seg, res.params.to_dict())["y"].to_numpy()
    assert np.max(np.abs(sim - y)) < 0.02 * np.max(np.abs(y))


def test_bad_structures_and_inputs_are_refused():
    with pytest.raises(ModelDefinitionError, match="num_order <= den_order"):
        TransferFunction(3, 2)
    t, u, y = _flight(3)
    with pytest.raises(ModelDefinitionError, match="method"):
        TransferFunction(1, 2).fit(t, u, y, w=W, method="ls")
    fr = frequency_response(t, np.column_stack([u, u + 0.1 * np.sin(t)]), y, f=np.geomspace(0.1, 3.0, 40))
    with pytest.raises(ModelDefinitionError, match="one input-output pair"):
        TransferFunction(1, 2).fit(fr)
    first = TransferFunction(0, 1).fit(t, u, y, w=W)
    with pytest.raises(ModelDefinitionError, match="num_order=1, den_order=2"):
        loes_parameters(first)
