"""Named modes of known linear systems, and the numerical linearisation."""

import numpy as np
import pytest

from estimators.validation import linearize, mode_properties, modes

G, V = 9.81, 50.0


def test_short_period_2x2_hand_computed():
    # alpha' = -alpha + q, q' = -4 alpha - 1.4 q: s^2 + 2.4 s + 5.4 = 0
    m = modes([[-1.0, 1.0], [-4.0, -1.4]], ["alpha", "q"])
    row = m.table.loc["short period"]
    assert list(m.table.index) == ["short period"]
    assert row["eigenvalue"] == pytest.approx(complex(-1.2, np.sqrt(5.4 - 1.44)), rel=1e-12)
    assert row["wn"] == pytest.approx(np.sqrt(5.4), rel=1e-12)  # 2.3238 rad/s
    assert row["zeta"] == pytest.approx(2.4 / (2 * np.sqrt(5.4)), rel=1e-12)  # 0.5164
    assert row["period"] == pytest.approx(2 * np.pi / np.sqrt(3.96), rel=1e-12)  # 3.157 s
    assert row["t_half"] == pytest.approx(np.log(2) / 1.2, rel=1e-12)  # 0.5776 s
    assert np.isnan(row["t_double"]) and row["stable"]
    ev = m.eigenvectors["short period"]
    # eigenvector: q = (lambda + 1) alpha
    lam = row["eigenvalue"]
    assert ev["q"] / ev["alpha"] == pytest.approx(lam + 1.0, rel=1e-10)
    assert np.linalg.norm(ev.to_numpy()) == pytest.approx(1.0)
    assert np.isclose(ev.abs().max(), ev.to_numpy()[np.argmax(ev.abs())].real)


def charpoly_long(s, a):
    """det(sI - A) for the 4x4 [V, alpha, q, theta] structure, expanded by hand."""
    d3 = (s - a[0, 0]) * ((s - a[1, 1]) * (s - a[2, 2]) - a[2, 1]) + a[0, 1] * (-a[1, 0] * (s - a[2, 2]) - a[2, 0])
    return s * d3 - a[0, 3] * (a[1, 0] * a[2, 1] + a[2, 0] * (s - a[1, 1]))


A_LONG = np.array(
    [[-0.03, 5.0, 0.0, -G], [-2 * G / V**2, -1.0, 1.0, 0.0], [0.001, -4.0, -1.4, 0.0], [0.0, 0.0, 1.0, 0.0]]
)


def test_longitudinal_4x4_short_period_and_phugoid():
    m = modes(A_LONG, ["V", "alpha", "q", "theta"])
    t = m.table
    assert list(t.index) == ["short period", "phugoid"]
    assert len(m.eigenvalues) == 4
    for lam in m.eigenvalues:
        assert abs(charpoly_long(lam, A_LONG)) < 1e-9 * max(1.0, abs(lam) ** 4)
    sp, ph = t.loc["short period"], t.loc["phugoid"]
    # the short period is close to the 2x2 approximation, the phugoid to Lanchester's
    assert sp["wn"] == pytest.approx(np.sqrt(5.4), rel=0.02)
    assert ph["wn"] == pytest.approx(np.sqrt(2) * G / V, rel=0.2)
    assert ph["zeta"] < 0.1 < sp["zeta"]
    for _, row in t.iterrows():  # hand formulas on each eigenvalue
        lam = row["eigenvalue"]
        assert row["wn"] == pytest.approx(abs(lam))
        assert row["zeta"] * row["wn"] == pytest.approx(-lam.real)
        assert row["period"] == pytest.approx(2 * np.pi / lam.imag)
        assert row["t_half"] == pytest.approx(np.log(2) / -lam.real)
    # phugoid is a speed / pitch-attitude motion, the short period an alpha / q motion
    mag = m.eigenvector_magnitude
    assert mag.loc["V", "phugoid"] > 10 * mag.loc["alpha", "phugoid"]
    assert mag.loc["alpha", "short period"] > 10 * mag.loc["alpha", "phugoid"]


def test_lateral_4x4_roll_dutch_roll_unstable_spiral():
    A = np.array([[-0.2, 0.05, -1.0, G / V], [-10.0, -3.0, 0.8, 0.0], [4.0, -0.2, -0.6, 0.0], [0.0, 1.0, 0.0, 0.0]])
    A[1, 2] = 2.0  # strong Clr makes the spiral divergent
    m = modes(A, ["beta", "p", "r", "phi"])
    t = m.table
    assert set(t.index) == {"roll", "Dutch roll", "spiral"}
    assert t.loc["roll", "imag"] == 0 and t.loc["spiral", "imag"] == 0
    assert t.loc["Dutch roll", "imag"] > 0
    assert abs(t.loc["roll", "real"]) > 10 * abs(t.loc["spiral", "real"])
    sp = t.loc["spiral"]
    assert sp["real"] > 0 and not sp["stable"]
    assert sp["t_double"] == pytest.approx(np.log(2) / sp["real"])
    assert np.isnan(sp["t_half"]) and sp["zeta"] == -1.0
    assert np.all(t["axis"] == "lateral")


def test_coupled_8_states_name_all_five_modes():
    Z = np.zeros((4, 4))
    A_lat = np.array([[-0.2, 0.05, -1.0, G / V], [-10.0, -3.0, 0.8, 0.0], [4.0, -0.2, -0.6, 0.0], [0.0, 1.0, 0.0, 0.0]])
    A = np.block([[A_LONG, Z], [Z, A_lat]])
    m = modes(A, ["V", "alpha", "q", "theta", "beta", "p", "r", "phi"])
    assert list(m.table.index) == ["short period", "phugoid", "roll", "Dutch roll", "spiral"]


def test_mode_properties_real_and_zero_roots():
    p = mode_properties([-2.0, 0.5, 0.0])
    np.testing.assert_allclose(p["time_constant"][:2], [0.5, 2.0])
    np.testing.assert_allclose(p["t_half"][0], np.log(2) / 2)
    np.testing.assert_allclose(p["t_double"][1], np.log(2) / 0.5)
    np.testing.assert_allclose(p["zeta"][:2], [1.0, -1.0])
    assert np.isinf(p["period"]).all() and np.isnan(p["zeta"][2])


def test_linearize_matches_analytic_jacobian():
    def f(x, u, p, c):
        V, alpha, q = x
        (de,) = u
        return (-p["k"] * V**2 + c["g"] * np.sin(alpha), q - V * alpha * de, p["m"] * alpha + 3.0 * de + 0.0 * V)

    x0, u0 = np.array([50.0, 0.1, 0.02]), np.array([-0.05])
    p, c = {"k": 0.001, "m": -4.0}, {"g": 9.81}
    A, B = linearize(f, x0, u0, p, c)
    V, al, q = x0
    de = u0[0]
    A_true = np.array([[-2 * 0.001 * V, 9.81 * np.cos(al), 0.0], [-al * de, -V * de, 1.0], [0.0, -4.0, 0.0]])
    B_true = np.array([[0.0], [-V * al], [3.0]])
    np.testing.assert_allclose(A, A_true, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(B, B_true, rtol=1e-7, atol=1e-9)
    # a linear f returns its matrices; works on the stacked-array return form as well
    Al, Bl = linearize(
        lambda x, u, p, c: A_LONG @ x + np.array([[0.0], [-0.1], [-6.0], [0.0]]) @ u,
        np.zeros(4),
        np.zeros(1),
        None,
        None,
    )
    np.testing.assert_allclose(Al, A_LONG, atol=1e-8)
    np.testing.assert_allclose(Bl[:, 0], [0.0, -0.1, -6.0, 0.0], atol=1e-8)


def test_statically_unstable_short_period_hand_computed():
    # M_alpha > 0: s^2 + 2.4 s - 1.6 = 0, roots -1.2 +/- sqrt(3.04), one divergent
    m = modes([[-1.0, 1.0], [3.0, -1.4]], ["alpha", "q"])
    t = m.table
    assert list(t.index) == ["short period (real) 1", "short period (real) 2"]
    div = t.loc["short period (real) 2"]
    assert div["eigenvalue"] == pytest.approx(-1.2 + np.sqrt(3.04))
    assert div["t_double"] == pytest.approx(np.log(2) / (-1.2 + np.sqrt(3.04)))
    assert not div["stable"]
    # in the 4x4 model the stable oscillatory pair is the phugoid, the real roots short period
    A = A_LONG.copy()
    A[2, 1] = 3.0
    t4 = modes(A, ["V", "alpha", "q", "theta"]).table
    assert set(t4.index) == {"short period (real) 1", "short period (real) 2", "phugoid"}
    assert (t4["real"] > 0).sum() == 1 and t4.loc["short period (real) 2", "real"] > 0
