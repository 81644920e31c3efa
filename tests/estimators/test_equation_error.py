"""Equation error: OLS, TLS, recursive LS and Fourier-transform regression on known regressions."""

import numpy as np
import pandas as pd
import pytest

from estimators import EstimationResult, FourierRegression, IdentifiabilityError, LeastSquares, RecursiveLeastSquares
from estimators.equation_error import RecursiveDFT

TRUTH = {"alpha": 1.5, "qhat": -0.7, "de": 0.3}
DT = 0.02


def data(seed=1, n=2000, bias=0.4, noise=0.1):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    X = np.column_stack(
        [
            np.sin(0.7 * t) + 0.3 * rng.standard_normal(n),
            np.cos(1.9 * t) + 0.5 * rng.standard_normal(n),
            rng.standard_normal(n),
        ]
    )
    y = X @ np.array(list(TRUTH.values())) + bias + noise * rng.standard_normal(n)
    return pd.DataFrame(X, columns=list(TRUTH), index=pd.Index(t, name="t")), y


def within(res, truth, k=3.0):
    err = {n: abs(res.params[n] - v) / res.std[n] for n, v in truth.items()}
    bad = {n: round(e, 2) for n, e in err.items() if not e < k}
    assert not bad, f"outside {k} std: {bad}"


def test_ols_recovers_truth_with_textbook_covariance():
    X, y = data()
    res = LeastSquares(intercept=True).fit(X, y)
    assert isinstance(res, EstimationResult) and res.method == "ols"
    within(res, {**TRUTH, "bias": 0.4})
    A = np.column_stack([np.ones(len(y)), X.to_numpy()])
    e = y - A @ res.values
    s2 = e @ e / (len(y) - 4)
    np.testing.assert_allclose(res.cov, s2 * np.linalg.inv(A.T @ A), rtol=1e-8)
    np.testing.assert_allclose(res.residuals[0]["y"].to_numpy(), e)
    assert res.R[0, 0] == pytest.approx(s2)
    text = res.summary(truth={**TRUTH, "bias": 0.4})
    assert "OLS" in text and "alpha" in text and "bias" in text


def test_ols_collinear_regressors_are_named():
    X, y = data()
    X["alpha2"] = 2.0 * X["alpha"]
    with pytest.raises(IdentifiabilityError) as info:
        LeastSquares().fit(X, y)
    assert set(info.value.parameters) >= {"alpha", "alpha2"}


def test_tls_handles_errors_in_regressors_where_ols_is_biased():
    rng = np.random.default_rng(5)
    n = 4000
    Xt = rng.standard_normal((n, 3)) * [1.0, 0.8, 1.2]
    theta = np.array(list(TRUTH.values()))
    yt = Xt @ theta
    sd = 0.3  # equal noise on every column of [X y]
    X = Xt + sd * rng.standard_normal(Xt.shape)
    y = yt + sd * rng.standard_normal(n)
    tls = LeastSquares(list(TRUTH), method="tls").fit(X, y)
    within(tls, TRUTH)
    ols = LeastSquares(list(TRUTH)).fit(X, y)
    # errors in the regressors attenuate OLS (biased towards zero by many std)
    assert abs(ols.params["alpha"] - TRUTH["alpha"]) / ols.std["alpha"] > 5
    # TLS std from the errors-in-variables covariance is larger than OLS's naive one
    assert tls.std["alpha"] > ols.std["alpha"]
    # with an intercept and column scaling (noise std per column)
    tls_b = LeastSquares(list(TRUTH), method="tls", intercept=True, scale=[sd, sd, sd, sd]).fit(X, y + 0.4)
    within(tls_b, {**TRUTH, "bias": 0.4})


def test_rls_without_forgetting_equals_ols_and_update_matches_fit():
    X, y = data(seed=2, n=1500)
    ols = LeastSquares(intercept=True).fit(X, y)
    rls = RecursiveLeastSquares(intercept=True, p0=1e8).fit(X, y)
    np.testing.assert_allclose(rls.values, ols.values, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(rls.std.to_numpy(), ols.std.to_numpy(), rtol=0.05)
    within(rls, {**TRUTH, "bias": 0.4})
    traj = rls.extra["trajectory"]
    assert traj.shape == (1500, 4) and list(traj.columns) == ["bias", *TRUTH]
    np.testing.assert_allclose(traj.iloc[-1].to_numpy(), rls.values)
    # sample-by-sample use gives the same estimate
    on = RecursiveLeastSquares(intercept=True, p0=1e8)
    for xk, yk in zip(X.to_numpy(), y):
        est = on.update(xk, yk)
    np.testing.assert_allclose(est, rls.values, rtol=1e-9)


def test_rls_forgetting_tracks_a_parameter_change():
    X, y = data(seed=3, n=3000, bias=0.0)
    y = y.copy()
    y[1500:] += 0.5 * X["alpha"].to_numpy()[1500:]  # alpha derivative jumps 1.5 -> 2.0
    fixed = RecursiveLeastSquares(forgetting=1.0).fit(X, y)
    forget = RecursiveLeastSquares(forgetting=0.99).fit(X, y)
    assert abs(forget.params["alpha"] - 2.0) < 3 * forget.std["alpha"] + 0.01
    assert abs(fixed.params["alpha"] - 2.0) > 0.2  # the infinite memory averages the two
    assert forget.extra["trajectory"]["alpha"].iloc[1400] == pytest.approx(1.5, abs=0.05)


def test_ftr_recovers_truth_and_matches_ols_on_the_same_band():
    X, y = data(seed=4, n=2000, bias=0.7)
    N = len(y)
    band = (0.05, 4.0)
    ftr = FourierRegression(band=band).fit(X, y, dt=DT)
    assert ftr.method == "ftr" and ftr.settings["detrend"] == "ends"
    within(ftr, TRUTH)  # bias drops out at w > 0
    # OLS on the data band-passed to exactly the FTR frequencies (DFT bins) is the plain
    # DFT sum's regression (Parseval); the transform of the cubic interpolant differs from
    # that sum at the record's ends and by its weight W(w dt), which moves the estimate by
    # a fraction of its std, not more
    f = np.fft.rfftfreq(N, DT)
    keep = np.isin(np.round(f / (f[1])), np.round(ftr.extra["frequencies"] / f[1]))

    def bandpass(v):
        F = np.fft.rfft(v)
        F[~keep] = 0.0
        return np.fft.irfft(F, N)

    Xb = pd.DataFrame({c: bandpass(X[c].to_numpy()) for c in X.columns}, index=X.index)
    ols_band = LeastSquares().fit(Xb, bandpass(y))
    assert np.max(np.abs(ftr.values - ols_band.values) / ftr.std.to_numpy()) < 0.5
    # the real-time form (recursive DFT, sample by sample, first samples subtracted) ends
    # within a fraction of a std of the whole-record fit
    rt = FourierRegression(frequencies=ftr.extra["frequencies"])
    rt.start(DT, 3)
    for xk, yk in zip(X.to_numpy(), y):
        rt.update(xk, yk)
    theta, cov = rt.estimate()
    assert np.max(np.abs(theta - ftr.values) / ftr.std.to_numpy()) < 0.5
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), ftr.std.to_numpy(), rtol=0.1)


def test_ftr_over_several_records():
    # records of different lengths and biases: each transformed on its own, one solution
    parts = [data(seed=s, n=n, bias=b) for s, n, b in ((5, 900, 0.2), (6, 1200, -0.5), (7, 1500, 1.0))]
    f = np.arange(0.1, 4.0, 1.0 / (900 * DT))
    res = FourierRegression(frequencies=f).fit_records([(X.index.to_numpy(), X, y) for X, y in parts])
    within(res, TRUTH)
    assert set(res.covariances) == {"crb", "sandwich"} and res.extra["n_records"] == 3
    assert len(res.extra["Y_f"]) == 3 * f.size
    # one record: the whole-record fit at the same frequencies
    X, y = parts[0]
    one = FourierRegression(frequencies=f).fit_records([(X.index.to_numpy(), X, y)])
    np.testing.assert_allclose(one.values, FourierRegression(frequencies=f).fit(X, y).values, rtol=1e-12)


def test_recursive_dft_equals_fft_bins():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((256, 2))
    freqs = np.fft.rfftfreq(256, 0.01)[3:9]
    d = RecursiveDFT(freqs, 0.01, 2)
    for xk in x:
        d.update(xk)
    # the first sample subtracted: at these (nonzero) bins only its k = 0 term differs
    np.testing.assert_allclose(d.X, np.fft.rfft(x - x[0], axis=0)[3:9] * 0.01, rtol=1e-10, atol=1e-12)
