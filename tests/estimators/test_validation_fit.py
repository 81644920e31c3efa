"""Fit metrics against hand-computed values (TIC and its proportions, R^2, RMS, det R)."""

import numpy as np
import pandas as pd
import pytest

from estimators.validation import det_r, fit_metrics, r_squared, rms, theil

# three outputs, each error of one pure kind (hand computed below)
Z = np.array([[1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [3.0, 3.0, 3.0]])
Y = np.array([[2.0, 2.0, 3.0], [2.0, 3.0, 2.0], [2.0, 4.0, 1.0]])


def test_theil_hand_computed_cases():
    t = theil(Z, Y)
    # col 0: y = 2 (constant): e = [-1, 0, 1], mse = 2/3, only a variance error
    # col 1: y = z + 1: e = -1, mse = 1, only a bias error
    # col 2: y = 4 - z: same mean and std, only a covariance error, mse = 8/3
    expected_U = [
        np.sqrt(2 / 3) / (np.sqrt(14 / 3) + 2.0),
        1.0 / (np.sqrt(14 / 3) + np.sqrt(29 / 3)),
        np.sqrt(8 / 3) / (2 * np.sqrt(14 / 3)),
    ]
    np.testing.assert_allclose(t.U, expected_U, rtol=1e-12)
    np.testing.assert_allclose(t.U[2], 0.3779644730, rtol=1e-9)
    np.testing.assert_allclose(t.UM, [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(t.US, [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(t.UC, [0.0, 0.0, 1.0], atol=1e-12)


def test_theil_proportions_sum_to_one_and_bounds():
    rng = np.random.default_rng(3)
    z = rng.normal(size=(500, 4)) + [0.0, 1.0, -2.0, 5.0]
    y = 0.7 * z + 0.3 * rng.normal(size=(500, 4)) + [0.1, -0.2, 0.0, 0.4]
    t = theil(z, y)
    np.testing.assert_allclose(t.UM + t.US + t.UC, 1.0, rtol=1e-12)
    assert np.all((t.U > 0) & (t.U < 1))
    assert np.all(t.UM >= 0) and np.all(t.US >= 0) and np.all(t.UC >= 0)
    # limits: a perfect fit gives 0, y = -z gives the worst value 1
    assert theil(z, z).U.max() == 0.0
    np.testing.assert_allclose(theil(z, -z).U, 1.0, rtol=1e-12)


def test_r2_rms_det_r_hand_computed():
    np.testing.assert_allclose(r_squared(Z, Y)[0], 0.0, atol=1e-15)  # 1 - 2/2
    np.testing.assert_allclose(r_squared(Z, Y)[1], 1.0 - 3.0 / 2.0)  # 1 - 3/2
    np.testing.assert_allclose(rms(Z - Y), [np.sqrt(2 / 3), 1.0, np.sqrt(8 / 3)])
    e = np.array([[1.0, 2.0], [-1.0, 0.0], [0.0, -2.0]])  # R = [[2, 2], [2, 8]] / 3
    np.testing.assert_allclose(det_r(e), 4.0 / 3.0, rtol=1e-12)


def test_fit_metrics_table_names_and_values():
    z = pd.DataFrame(Z, columns=["q", "alpha", "az"])
    df = fit_metrics(z, Y)
    assert list(df.index) == ["q", "alpha", "az"]
    assert {"TIC", "UM", "US", "UC", "R2", "RMS", "NRMS", "mean", "std"} <= set(df.columns)
    np.testing.assert_allclose(df.loc["alpha", "mean"], -1.0)
    np.testing.assert_allclose(df.loc["alpha", "std"], 0.0, atol=1e-15)
    np.testing.assert_allclose(df.loc["q", "NRMS"], np.sqrt(2 / 3) / 2.0)
    np.testing.assert_allclose(df.attrs["det_R"], np.linalg.det((Z - Y).T @ (Z - Y) / 3), atol=1e-12)
    with pytest.raises(ValueError):
        fit_metrics(Z, Y[:, :2])


def test_segment_lists_are_concatenated():
    z = pd.DataFrame(Z, columns=["q", "alpha", "az"])
    df = fit_metrics([z.iloc[:2], z.iloc[2:]], [Y[:2], Y[2:]])
    pd.testing.assert_frame_equal(df, fit_metrics(z, Y))
