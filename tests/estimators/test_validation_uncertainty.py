"""Cramér-Rao bounds and their Morelli-Klein correction for coloured residuals."""

import numpy as np
import pytest
from scipy import signal

from estimators.covariance.uncertainty import _middle
from estimators.validation import correlation, correlation_flags, crb, morelli_klein

N, FS = 4000, 50.0
T = np.arange(N) / FS
# sensitivities of 2 outputs to 3 parameters: two low-frequency signals and a bias-like one
S = np.stack(
    [
        np.stack([np.sin(2 * np.pi * 0.3 * T), np.cos(2 * np.pi * 0.7 * T) + 0.3, np.ones(N)], -1),
        np.stack([0.5 * np.sin(2 * np.pi * 0.5 * T + 1), np.sin(2 * np.pi * 0.2 * T), 0.2 * np.ones(N)], -1),
    ],
    1,
)  # (N, 2, 3)
SIG = np.array([0.1, 0.5])
PHI = 0.9


def coloured(rng, n=N):
    """AR(1) noise with phi = 0.9 and the variances SIG^2."""
    e = rng.normal(size=(n, 2))
    return signal.lfilter([1.0], [1.0, -PHI], e, axis=0) * SIG * np.sqrt(1 - PHI**2)


def test_crb_hand_computed():
    # one output, one bias parameter: var = sigma^2 / N
    np.testing.assert_allclose(crb(np.ones((200, 1, 1)), [[0.25]]), [[0.25 / 200]])
    np.testing.assert_allclose(crb(np.ones((200, 1)), 0.25), [[0.25 / 200]])


def test_middle_term_equals_brute_force_double_sum():
    rng = np.random.default_rng(0)
    n, no, npar = 40, 2, 3
    s = rng.normal(size=(n, no, npar))
    v = rng.normal(size=(n, no))
    v[:, 1] += 0.5 * v[:, 0]
    Ri = np.linalg.inv(v.T @ v / n)
    W = np.einsum("ab,nbp->nap", Ri, s)
    for L, win, unb in [
        (0, "none", False),
        (5, "none", False),
        (5, "bartlett", True),
        (n - 1, "none", True),
        (n - 1, "bartlett", False),
    ]:
        r = np.array(
            [
                v[: n - k].T @ v[k:] / ((n - k) if unb else n) * ((1 - k / (L + 1)) if win == "bartlett" else 1.0)
                for k in range(L + 1)
            ]
        )
        # full block-Toeplitz residual covariance, (n*no, n*no)
        big = np.zeros((n, no, n, no))
        for i in range(n):
            for j in range(max(0, i - L), min(n, i + L + 1)):
                big[i, :, j, :] = r[j - i] if j >= i else r[i - j].T
        Wf = W.reshape(n * no, npar)
        brute = Wf.T @ big.reshape(n * no, n * no) @ Wf
        np.testing.assert_allclose(_middle(s, v, Ri, L, win, unb), brute, rtol=1e-10, atol=1e-12)


def test_zero_lag_is_plain_crb():
    v = np.random.default_rng(1).normal(size=(N, 2)) * SIG
    r = morelli_klein(S, v, max_lag=0)
    np.testing.assert_allclose(r.cov, r.crb_cov, rtol=1e-10, atol=1e-18)
    np.testing.assert_allclose(r.ratio, 1.0, rtol=1e-10)
    np.testing.assert_allclose(r.crb_cov, crb(S, v.T @ v / N), rtol=1e-10, atol=1e-18)


def test_white_residuals_leave_bounds_unchanged():
    v = np.random.default_rng(2).normal(size=(N, 2)) * SIG
    r = morelli_klein(S, v, names=["a", "b", "c"])
    np.testing.assert_allclose(r.ratio, 1.0, atol=0.1)
    assert list(r.to_frame().index) == ["a", "b", "c"]


def test_coloured_residuals_enlarge_bounds_like_monte_carlo():
    """For a linear model the estimate error is M^-1 sum S^T R^-1 v exactly: its scatter over
    realisations is the truth the corrected bound must approach, the plain CRB misses it."""
    rng = np.random.default_rng(3)
    R = np.diag(SIG**2)
    Ri = np.linalg.inv(R)
    M = np.einsum("nap,ab,nbq->pq", S, Ri, S)
    Minv = np.linalg.inv(M)
    errs = np.array([Minv @ np.einsum("nap,ab,nb->p", S, Ri, coloured(rng)) for _ in range(300)])
    empirical = errs.std(axis=0)
    v = coloured(rng)
    r = morelli_klein(S, v, R=R, info=M)
    np.testing.assert_allclose(r.crb_std, np.sqrt(np.diag(Minv)))
    assert np.all(r.ratio > 2.5)  # much larger than the plain bound
    np.testing.assert_allclose(r.std, empirical, rtol=0.3)
    assert np.all(empirical / r.crb_std > 2.5)
    # the bias-like parameter: theory sqrt((1 + phi) / (1 - phi)) = sqrt(19) for a mean
    assert r.ratio[2] == pytest.approx(np.sqrt(19.0), rel=0.25)


def test_segments_do_not_mix():
    v = np.random.default_rng(4).normal(size=(N, 2)) * SIG
    half = N // 2
    r_seg = morelli_klein([S[:half], S[half:]], [v[:half], v[half:]], max_lag=0)
    r_all = morelli_klein(S, v, max_lag=0)
    np.testing.assert_allclose(r_seg.cov, r_all.cov, rtol=1e-10, atol=1e-18)
    assert r_seg.max_lag == [0, 0]


def test_correlation_flags():
    cov = np.array([[1.0, 0.95 * 2, 0.0], [0.95 * 2, 4.0, 0.3], [0.0, 0.3, 1.0]])
    rho = correlation(cov, ["Cmq", "Cmalphadot", "Cm0"])
    np.testing.assert_allclose(rho.loc["Cmq", "Cmalphadot"], 0.95)
    np.testing.assert_allclose(rho.loc["Cmalphadot", "Cm0"], 0.15)
    flags = correlation_flags(cov, ["Cmq", "Cmalphadot", "Cm0"])
    assert len(flags) == 1 and set(flags.iloc[0][["a", "b"]]) == {"Cmq", "Cmalphadot"}
    assert correlation_flags(cov, ["a", "b", "c"], threshold=0.1).shape[0] == 2
