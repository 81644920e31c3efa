"""Proof of match against tolerance bands, plausibility against a-priori values, inverse
simulation."""

import numpy as np
import pandas as pd
import pytest
from scipy import signal

from estimators.validation import (
    agreement,
    default_tolerances,
    inverse_simulation,
    load_apriori,
    plausibility,
    proof_of_match,
)
from tests._roll import roll_model, roll_segment

DEG = np.pi / 180


def contrived():
    t = np.linspace(0, 10, 501)
    meas = pd.DataFrame({"q": 0.1 * np.sin(t), "az": -9.81 + np.sin(2 * t), "theta": 0.05 * np.cos(t), "V": 50 + t})
    pred = meas.copy()
    pred["q"] += 1.0 * DEG * np.sin(5 * t)  # within 1.5 deg/s everywhere
    pred["az"] += 0.15 * 9.80665 * (t > 5)  # 0.15 g error on the second half
    pred["theta"] += 1.0 * DEG  # 1 deg constant bias, within 1.5 deg
    pred["V"] += 3.0  # no default band for V
    return t, meas, pred


def test_default_tolerances_in_si():
    tol = default_tolerances()
    assert tol["q"] == pytest.approx(1.5 * DEG)  # rad/s
    assert tol["az"] == pytest.approx(0.980665)  # m/s^2
    assert tol["alpha"] == pytest.approx(0.02617993878)  # rad
    assert default_tolerances(rate_deg_s=3.0)["p"] == pytest.approx(3 * DEG)


def test_proof_of_match_pass_fail_per_channel():
    _, meas, pred = contrived()
    df = proof_of_match(meas, pred)
    assert bool(df.loc["q", "pass"]) and bool(df.loc["theta", "pass"])
    assert not bool(df.loc["az", "pass"])
    assert pd.isna(df.loc["V", "pass"])  # not judged
    assert df.attrs["all_pass"] is False
    assert df.loc["az", "max_abs_error"] == pytest.approx(0.15 * 9.80665)
    assert df.loc["az", "fraction_within"] == pytest.approx(251 / 501)  # t <= 5: samples 0..250
    assert df.loc["theta", "rms_error"] == pytest.approx(1.0 * DEG)
    # configurable: a wider az band, a V band
    df2 = proof_of_match(meas, pred, tolerances={"az": 0.2 * 9.80665, "V": 2.0})
    assert bool(df2.loc["az", "pass"]) and not bool(df2.loc["V", "pass"])
    # a required fraction of 45 % lets the half-failing az channel pass
    assert bool(proof_of_match(meas, pred, required_fraction=0.45).loc["az", "pass"])
    # an allowed bias of 3 m/s removes the V offset entirely
    df3 = proof_of_match(meas, pred, tolerances={"V": 0.5, "az": 0.2 * 9.80665}, allowed_bias={"V": 3.0})
    assert df3.loc["V", "bias_removed"] == pytest.approx(-3.0)
    assert bool(df3.loc["V", "pass"]) and df3.attrs["all_pass"] is True
    # a smaller allowed bias is clipped
    df4 = proof_of_match(meas, pred, tolerances={"V": 0.5}, allowed_bias={"V": 1.0})
    assert df4.loc["V", "bias_removed"] == pytest.approx(-1.0)
    assert not bool(df4.loc["V", "pass"])


def test_an_input_timing_envelope_judges_the_distance_from_the_range():
    """envelope=(lower, upper): the prediction's range under an input's own uncertainty (a
    step's unknown time between two slow samples); the error is the distance from it."""
    meas = pd.DataFrame({"p": np.zeros(5), "r": np.zeros(5)})
    pred = pd.DataFrame({"p": [0.0, 3.0, 0.0, 0.0, 0.0], "r": [0.0, 0.0, 0.0, 0.0, 4.0]}) * DEG
    lower = pred.copy()
    upper = pred.copy()
    lower.loc[1, "p"] = -1.0 * DEG  # the measurement 1 deg/s inside the range
    upper.loc[4, "r"] = 5.0 * DEG  # a range above the prediction: r stays 4 off
    plain = proof_of_match(meas, pred)
    assert not bool(plain.loc["p", "pass"]) and plain.loc["p", "max_abs_error"] == pytest.approx(3 * DEG)
    assert plain.loc["p", "envelope_max_width"] == 0.0
    df = proof_of_match(meas, pred, envelope=(lower, upper))
    assert bool(df.loc["p", "pass"]) and df.loc["p", "max_abs_error"] == 0.0
    assert df.loc["p", "nominal_max_abs_error"] == pytest.approx(3 * DEG)
    assert df.loc["p", "envelope_max_width"] == pytest.approx(4 * DEG)
    # the range always holds the prediction: r is judged 4 deg/s off either way
    assert df.loc["r", "max_abs_error"] == pytest.approx(4 * DEG) and not bool(df.loc["r", "pass"])
    assert df.loc["r", "envelope_max_width"] == pytest.approx(1 * DEG)
    assert df.loc["r", "rms_error"] == pytest.approx(4 * DEG / np.sqrt(5))
    # an allowed bias is taken from the prediction itself, then the range judged
    shifted = meas + 0.5 * DEG
    db = proof_of_match(shifted, pred, envelope=(lower, upper), allowed_bias={"p": 0.2 * DEG})
    assert db.loc["p", "bias_removed"] == pytest.approx(-0.1 * DEG)  # mean(z - y), within 0.2
    assert db.loc["p", "max_abs_error"] == pytest.approx(0.6 * DEG)  # 0.5 + 0.1 off a 0-wide range
    with pytest.raises(ValueError, match="envelope"):
        proof_of_match(meas, pred, envelope=(lower.iloc[:3], upper))


def test_white_noise_alone_fails_a_channel_in_5_percent_of_segments():
    """noise_std: the band widened by what the noise reaches over the channel's samples
    (noise_reach: all of n N(0, 1) samples within +-z with probability 95 %), so a perfect
    model is not failed for its data's noise; a model error beyond band + reach still is."""
    from scipy.stats import norm

    from estimators.validation import noise_reach

    assert noise_reach(1) == pytest.approx(1.959964, abs=1e-6)
    for n in (10, 1000):  # (1 - 2 Phi(-z))^n = 0.95
        assert (1 - 2 * norm.cdf(-noise_reach(n))) ** n == pytest.approx(0.95, abs=1e-12)
    sd, n, draws = 0.5 * DEG, 1000, 400
    rng = np.random.default_rng(3)
    meas = pd.DataFrame({"q": sd * rng.standard_normal(n)})
    pred = pd.DataFrame({"q": np.zeros(n)})
    plain = proof_of_match(meas, pred)  # 0.5 deg/s noise, 1.5 deg/s band
    assert not bool(plain.loc["q", "pass"]) and plain.loc["q", "noise_allowance"] == 0.0
    df = proof_of_match(meas, pred, noise_std={"q": sd})
    assert bool(df.loc["q", "pass"])
    assert df.loc["q", "noise_allowance"] == pytest.approx(noise_reach(n) * sd)
    fails = sum(
        not bool(
            proof_of_match(pd.DataFrame({"q": sd * rng.standard_normal(n)}), pred, noise_std={"q": sd}).loc["q", "pass"]
        )
        for _ in range(draws)
    )
    # the 1.5 deg/s band comes on top of the reach: far fewer than 5 % fail; without it 5 %
    assert fails / draws < 0.01
    zero = sum(
        not bool(
            proof_of_match(
                pd.DataFrame({"q": sd * rng.standard_normal(n)}), pred, tolerances={"q": 0.0}, noise_std={"q": sd}
            ).loc["q", "pass"]
        )
        for _ in range(draws)
    )
    assert 0.02 < zero / draws < 0.09, zero / draws
    # a model 2.5 deg/s off over a tenth of the samples still fails (1.5 + 4.05 x 0.5 = 3.5)
    off = pred.copy()
    off.loc[:99, "q"] = 4.0 * DEG
    assert not bool(proof_of_match(meas, off, noise_std={"q": sd}).loc["q", "pass"])


APRIORI = """
[Cmq]
value = -25.0
std = 4.0
source = "DATCOM"

[Cmde]
value = 1.0
std = 0.1

[Clp]
value = -0.5
rel_std = 0.2
"""


def test_plausibility_flags_hand_computed(tmp_path):
    path = tmp_path / "apriori.toml"
    path.write_text(APRIORI)
    ap = load_apriori(path)
    assert ap.loc["Clp", "std"] == pytest.approx(0.1)
    assert ap.loc["Cmq", "source"] == "DATCOM"
    est = pd.Series({"Cmq": -20.0, "Cmde": 0.5, "Clp": -0.45, "CL0": 0.3})
    std = pd.Series({"Cmq": 3.0, "Cmde": 0.1, "Clp": 0.05, "CL0": 0.01})
    df = plausibility(est, std, path, k=3.0)
    assert list(df.index) == ["Cmq", "Cmde", "Clp"]  # CL0 has no a-priori value
    assert df.loc["Cmq", "combined_std"] == pytest.approx(5.0)  # sqrt(3^2 + 4^2)
    assert df.loc["Cmq", "z"] == pytest.approx(1.0)
    assert df.loc["Cmde", "z"] == pytest.approx(0.5 / np.sqrt(0.02))  # 3.54
    assert df.loc["Clp", "z"] == pytest.approx(0.05 / np.sqrt(0.0125))
    assert df["flag"].tolist() == [False, True, False]
    assert plausibility(est, std, ap, k=4.0)["flag"].sum() == 0


def test_method_agreement_hand_computed():
    est = {
        "oem": ({"Cmq": -20.0, "Cmde": -1.0, "CL0": 0.3}, {"Cmq": 3.0, "Cmde": 0.03, "CL0": 0.01}),
        "fem": ({"Cmq": -24.0, "Cmde": -1.2, "F_q": 0.1}, {"Cmq": 4.0, "Cmde": 0.04, "F_q": 0.01}),
        "ekf": ({"Cmq": -21.0, "Cmde": -1.1}, {"Cmq": 1.0, "Cmde": np.nan}),
    }
    df = agreement(est, k=3.0)
    # pairs in the order given; CL0 and F_q in one method only; ekf's Cmde has no std
    assert [(r.parameter, r.method_a, r.method_b) for r in df.itertuples()] == [
        ("Cmq", "oem", "fem"),
        ("Cmde", "oem", "fem"),
        ("Cmq", "oem", "ekf"),
        ("Cmq", "fem", "ekf"),
    ]
    assert df["combined_std"].tolist() == pytest.approx([5.0, 0.05, np.sqrt(10.0), np.sqrt(17.0)])
    assert df["diff"].tolist() == pytest.approx([4.0, 0.2, 1.0, -3.0])
    assert df["z"].tolist() == pytest.approx([0.8, 4.0, 1 / np.sqrt(10), 3 / np.sqrt(17)])
    assert df["flag"].tolist() == [False, True, False, False]
    assert agreement(est, k=4.5)["flag"].sum() == 0
    assert agreement({"oem": est["oem"]}).empty  # nothing to compare


def test_load_apriori_errors_and_section(tmp_path):
    with pytest.raises(ValueError, match="Cmq"):
        load_apriori({"Cmq": {"value": -25.0}})
    with pytest.raises(ValueError, match="Cmq"):
        load_apriori({"Cmq": -25.0})
    ap = load_apriori({"apriori": {"Cmq": {"value": -25.0, "std": 1.0}}})
    assert ap.loc["Cmq", "value"] == -25.0


A = np.array([[-1.0, 1.0], [-4.0, -1.4]])  # alpha, q
B = np.array([[-0.1], [-6.0]])  # elevator
T = np.arange(0, 10, 0.02)
U = (np.where((T > 1) & (T < 2), 0.05, 0) - np.where((T >= 2) & (T < 3), 0.05, 0))[:, None]


def measured(Bm=B, C=np.eye(2)):
    _, y, _ = signal.lsim((A, Bm, C, np.zeros((C.shape[0], 1))), U, T, interp=False)
    return y.reshape(T.size, -1)


def test_inverse_simulation_exact_model_has_no_residual_inputs():
    z = measured()
    r = inverse_simulation(A, B, np.eye(2), None, T, z, u_ref=U)
    np.testing.assert_allclose(r.residual_inputs, 0.0, atol=1e-12)
    np.testing.assert_allclose(r.tracking_error, 0.0, atol=1e-12)
    # without the measured inputs the loop reconstructs the doublet from the outputs alone
    r0 = inverse_simulation(A, B, np.eye(2), None, T, z)
    assert r0.u.shape == (T.size, 1)
    err = np.abs(r0.u - U)[:, 0]
    assert np.median(err) < 0.002 and err.mean() < 0.005  # doublet amplitude 0.05
    assert np.abs(r0.tracking_error).max() < 0.02


def test_inverse_simulation_reveals_control_effectiveness_error():
    # the data come from an aircraft 25 % more effective than the model (B_model = 0.8 B)
    z = measured(C=np.array([[0.0, 1.0]]))
    r = inverse_simulation(A, 0.8 * B, np.array([[0.0, 1.0]]), None, T, z, u_ref=U)
    hold = (T > 1.5) & (T < 2.0)
    # the model needs u / 0.8: residual input = 0.25 u
    np.testing.assert_allclose(r.residual_inputs[hold, 0], 0.25 * 0.05, rtol=0.25)
    assert np.abs(r.residual_inputs[T < 1.0]).max() < 1e-12
    with pytest.raises(ValueError, match="unstable"):
        inverse_simulation(A, B, np.eye(2), None, T, measured(), bandwidth=500.0)


def test_the_pipeline_judges_a_held_out_maneuver_with_its_own_noise_level():
    """pipeline.validation.validate: the held-out data's white-noise level (second differences) widens
    each band by its reach; a true roll-rate model on data with 0.5 deg/s gyro noise passes
    (it failed on the noise alone: a 1.5 deg/s band, 3 sigma, over 300 samples), a 30 %
    wrong control derivative still fails."""

    from estimators import OutputError
    from pipeline.validation import validate

    t = np.round(np.arange(0.0, 3.0, 0.01), 10)
    da = np.radians(4.0) * ((t >= 0.5) & (t < 1.5)) - np.radians(4.0) * ((t >= 1.5) & (t < 2.5))
    segs = [roll_segment(t, da, 0.5 * DEG, seed) for seed in (5, 6)]
    res = OutputError(roll_model()).fit(segs[0], estimate_x0=False)
    p = validate(res, held_out=[segs[1]])["proof_of_match"]["segments"][0]["channels"]["p"]
    assert p["pass"] and p["max_abs_error_display"] > 1.5, p  # noise beyond the band
    assert 0.5 * 3.0 < p["noise_allowance_display"] < 0.5 * 4.5, p  # about 3.8 sigma
    wrong = res.replace(values=np.where(np.array(res.names) == "Lda", 0.7 * float(res.params["Lda"]), res.values))
    q = validate(wrong, held_out=[segs[1]])["proof_of_match"]["segments"][0]["channels"]["p"]
    assert not q["pass"], q


def test_a_tic_at_the_noise_floor_is_noted_not_failed():
    """pipeline.validation.validate: a channel the maneuver hardly moves (a 0.2 deg aileron doublet: p
    about 1 deg/s against 0.5 deg/s of gyro noise) has TIC >= 0.1 with the true model; its
    residuals are its noise, so the verdict notes it (tic_noise_floor) instead of failing.
    A model whose residuals exceed the noise by more than NOISE_FLOOR_RATIO still fails."""

    from estimators import OutputError, simulate_outputs
    from pipeline.validation import NOISE_FLOOR_RATIO, validate

    t = np.round(np.arange(0.0, 6.0, 0.01), 10)
    ph = t % 2
    da = np.radians(0.2) * (((ph >= 0.5) & (ph < 1.0)).astype(float) - ((ph >= 1.0) & (ph < 1.5)))
    seg = roll_segment(t, da, 0.5 * DEG, seed=7)
    res = OutputError(roll_model()).fit(seg, estimate_x0=False)
    v = validate(res)
    fit = v["fit"]
    assert fit["per_output"]["p"]["TIC"] >= 0.1 and not fit["tic_ok"]
    assert fit["tic_noise_floor"] == ["p"]
    assert fit["per_output"]["p"]["noise_std"] == pytest.approx(0.5 * DEG, rel=0.1)
    assert not any("TIC" in r for r in v["verdict"]["reasons"])
    assert any("noise floor" in n for n in v["verdict"]["notes"])
    wrong = res.replace(values=np.where(np.array(res.names) == "Lda", 0.3 * float(res.params["Lda"]), res.values))
    pred = [simulate_outputs(wrong.model_with_estimates(), seg)]  # the prediction of a model with Lda 70 % low
    resid = [pd.DataFrame(seg.z - pred[0].to_numpy(), index=pred[0].index, columns=["p"])]
    wrong = wrong.replace(predicted=pred, residuals=resid)
    w = validate(wrong)["fit"]
    assert w["per_output"]["p"]["RMS"] > NOISE_FLOOR_RATIO * w["per_output"]["p"]["noise_std"]
    assert w["tic_noise_floor"] == [] and not w["tic_ok"]
