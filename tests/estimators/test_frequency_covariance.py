"""The frequency-domain sandwich covariance against the scatter of its estimates where a
few frequencies carry the information and the residuals are largest there (gusts at the low
end of a short band): the leverage-corrected scores keep the std from understating."""

import numpy as np

from estimators.frequency.covariance import frequency_covariances


def test_sandwich_holds_where_few_frequencies_carry_the_information():
    rng = np.random.default_rng(0)
    nf, theta = 20, np.array([1.0, -2.0, 0.5])
    X = rng.standard_normal((nf, 3)) + 1j * rng.standard_normal((nf, 3))
    X[:3] *= 5.0  # three frequencies with most of the information
    sig = np.where(np.arange(nf) < 3, 3.0, 1.0)  # and three times the noise there
    A = np.real(X.conj().T @ X)
    est, sw, plain = [], [], []
    for _ in range(400):
        y = X @ theta + sig * (rng.standard_normal(nf) + 1j * rng.standard_normal(nf)) / np.sqrt(2)
        th = np.linalg.solve(A, np.real(X.conj().T @ y))
        E = y - X @ th
        s2 = float(np.real(E.conj() @ E)) / (nf - 3)
        c = frequency_covariances(-X[:, None, :], E[:, None], np.array([[1.0 / s2]]))
        est.append(th)
        sw.append(np.sqrt(np.diag(c["sandwich"])))
        s = np.real(X.conj() * E[:, None]) / s2  # the scores without the leverage correction
        Mi = np.linalg.inv(A / s2)
        plain.append(np.sqrt(np.diag(Mi @ (s.T @ s) @ Mi)))
    emp = np.std(est, axis=0, ddof=1)
    # 400 fits: the ratio of std is known to about 4 %; the corrected sandwich holds (<= 1.1)
    # without being far too large, where the plain one understates by a third or more
    ratio = emp / np.mean(sw, axis=0)
    assert np.all(ratio < 1.1) and np.all(ratio > 0.6), ratio
    assert np.all(emp / np.mean(plain, axis=0) > 1.3)
