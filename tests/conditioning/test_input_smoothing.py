"""Zero-phase smoothing of measured control inputs at their noise floor
(pipeline.conditioning.input_smoothing), on synthetic surface positions with known content."""

import numpy as np
import pandas as pd
import pytest

from pipeline.conditioning.input_smoothing import (
    INPUT_FILTER_ORDER,
    MIN_CORNER_HZ,
    MIN_SAMPLES,
    control_input_corners,
    input_corner_hz,
    smooth_columns,
    zero_phase,
)
from pipeline.ingest.readers import read_log

RATE = 100.0
T = np.arange(0, 60, 1 / RATE)
NOISE = np.radians(0.05)


def multisine(t):
    """Harmonics 0.1-1.5 Hz of a 10 s period, Schroeder phases, ~0.7 deg rms."""
    k = np.arange(1, 16)
    ph = -np.pi * k * (k - 1) / k.size
    return np.radians(0.27) * np.sum(np.cos(2 * np.pi * np.outer(t, k) / 10.0 + ph), axis=1)


def steps_3211(t):
    """A 3-2-1-1 of 1 deg (0.3 s unit) every 10 s through a 20 ms first-order actuator."""
    cmd = np.zeros_like(t)
    for t0 in np.arange(2.0, t[-1] - 3, 10.0):
        for a, b, v in ((0, 0.9, 1), (0.9, 1.5, -1), (1.5, 1.8, 1), (1.8, 2.1, -1)):
            cmd[(t >= t0 + a) & (t < t0 + b)] = np.radians(v)
    out, y, h = np.empty_like(cmd), 0.0, 1 / RATE
    for i, c in enumerate(cmd):
        y += h / 0.02 * (c - y) if h < 0.02 else c - y
        out[i] = y
    return out


def rms(x):
    return float(np.sqrt(np.mean(x**2)))


def test_corner_of_a_noisy_multisine_removes_the_noise_not_the_signal():
    rng = np.random.default_rng(0)
    clean = multisine(T)
    fc = input_corner_hz(T, clean + NOISE * rng.standard_normal(T.size))
    # the signal ends at 1.5 Hz and meets the 0.05 deg floor between 2 and 8 Hz
    assert fc is not None and 2.0 <= fc <= 8.0
    errs = []
    for seed in range(3):
        noisy = clean + NOISE * np.random.default_rng(seed).standard_normal(T.size)
        sm = smooth_columns(pd.DataFrame({"da": noisy}), RATE, {"da": fc}, INPUT_FILTER_ORDER)
        errs.append(rms((sm["da"].to_numpy() - clean)[100:-100]) / NOISE)
    # white noise keeps ~ sqrt(fc / 50 Hz) of its rms (0.2-0.4); the signal passes whole
    assert max(errs) < 0.45 and min(errs) > 0.15, errs
    passed = zero_phase(clean, RATE, fc, INPUT_FILTER_ORDER)
    inner = slice(100, -100)  # the record's ends: the padding's transient
    assert rms((passed - clean)[inner]) < 0.01 * rms(clean)


def test_steps_get_a_higher_corner_than_a_multisine():
    rng = np.random.default_rng(1)
    fc_ms = input_corner_hz(T, multisine(T) + NOISE * rng.standard_normal(T.size))
    fc_st = input_corner_hz(T, steps_3211(T) + NOISE * rng.standard_normal(T.size))
    assert fc_st is not None and fc_st > 1.5 * fc_ms, (fc_ms, fc_st)


def test_no_noise_floor_no_smoothing():
    assert input_corner_hz(T, multisine(T)) is None  # noise-free
    # noise-free steps through an actuator: a steep roll-off up there, no white floor
    assert input_corner_hz(T, steps_3211(T)) is None
    assert input_corner_hz(T, np.full(T.size, 0.01)) is None  # constant
    short = T[: MIN_SAMPLES - 1]
    assert (
        input_corner_hz(short, multisine(short) + NOISE * np.random.default_rng(5).standard_normal(short.size)) is None
    )  # too short to judge
    # white noise alone (a surface that did not move): the lowest corner
    noise = NOISE * np.random.default_rng(2).standard_normal(T.size)
    assert input_corner_hz(T, noise) == pytest.approx(MIN_CORNER_HZ)


def test_corner_on_jittered_native_times():
    rng = np.random.default_rng(3)
    t = T + rng.uniform(-2e-3, 2e-3, T.size)  # logger jitter
    fc = input_corner_hz(t, multisine(t) + NOISE * rng.standard_normal(t.size))
    assert fc is not None and 2.0 <= fc <= 8.0


def test_smooth_columns_keeps_gaps_and_other_columns():
    rng = np.random.default_rng(4)
    x = multisine(T) + NOISE * rng.standard_normal(T.size)
    x[1000:1010] = np.nan
    df = pd.DataFrame({"t": T, "da": x, "dr": x.copy()})
    out = smooth_columns(df, RATE, {"da": 5.0, "de": 5.0}, INPUT_FILTER_ORDER)
    assert np.isnan(out["da"].to_numpy()[1000:1010]).all()
    assert np.isfinite(out["da"].to_numpy()[:1000]).all()
    assert rms(out["da"].to_numpy()[:1000] - multisine(T[:1000])) < 0.5 * NOISE
    assert np.array_equal(out["dr"].to_numpy(), x, equal_nan=True)  # not named: untouched
    assert np.array_equal(df["da"].to_numpy(), x, equal_nan=True)  # input not modified


def test_clean_servo_steps_of_the_default_scenario_keep_their_samples():
    """scenarios/default.toml logs its surfaces without noise (servo PWM steps through
    JSBSim's actuators): no corner for any of them. The flatness window first tried (the
    upper quarters within a factor 2) smoothed its elevator at 24 Hz, 0.11 deg rms off the
    true surface position."""
    from _simdata import flown, written

    fd = read_log(written("default") / "flight.mcap")
    truth = flown("default").truth
    assert control_input_corners(fd) == {}
    for c in ("de", "da", "dr"):  # the log is the true surface indeed
        assert rms(np.interp(truth["t"], fd[c].t, fd[c].values) - truth[c].to_numpy()) < 1e-6
