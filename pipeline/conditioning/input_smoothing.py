"""Zero-phase smoothing of measured model inputs.

Output error and filter error take a model's inputs as exact. A measured control-surface
position is not: its sensor noise drives the model's fast modes (the roll mode, the short
period) in a way the aircraft never saw, and the fit answers by shrinking the control
derivative and the damping together. Low-passed where their noise floor begins, the
measured positions no longer bias the derivatives that way.

The corner of each control input comes from its own spectrum at its native rate
(:func:`input_corner_hz`): the white-noise floor is the upper half of the native band,
which must be flat, and the corner is 1.5 times the top of the highest band where the
measured power is still twice that floor (signal above the noise: a Wiener filter's
crossover). Inputs without a flat noise floor (commands, servo outputs, noise-free steps,
data whose signal reaches the Nyquist frequency) keep their samples.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from scipy.signal import butter, sosfiltfilt

from pipeline.ingest.flightdata import CONTROL_INPUTS, FlightData

#: the lowest corner (Hz) an input is ever smoothed at: below it a maneuver's own band
MIN_CORNER_HZ = 2.0
#: measured power over the noise floor that counts as signal (2: signal = noise)
SIGNAL_OVER_FLOOR = 2.0
#: Butterworth order of the control-input filter: gain 0.996 at half the corner (second
#: order: 0.94), so a maneuver's band below the corner passes unchanged
INPUT_FILTER_ORDER = 4
#: the two upper quarters of the band's mean power, top over lower, of a white floor: 1
#: +- 0.05 with MIN_SAMPLES; noise-free steps (3211s, doublets through an actuator, servo
#: PWM steps) fall off as 1/f^2 and give 0.66-0.77 on the built-in scenarios, noisy
#: multisines 0.94-1.11
FLAT = (0.85, 1.2)
#: samples an input needs for its floor to be judged (200 periodogram bins per quarter)
MIN_SAMPLES = 1600
#: the corner over the top of the signal's band: gain 0.96 at that top (where the signal
#: is down at the noise), above 0.996 below two thirds of it
CORNER_MARGIN = 1.5
#: relative width of the frequency bands the spectrum is averaged over (third octaves)
BAND_RATIO = 2.0 ** (1.0 / 3.0)


def zero_phase(x: np.ndarray, rate_hz: float, fc: float, order: int = 2) -> np.ndarray:
    """Butterworth of ``order`` forwards and backwards at fc (Hz) on samples at rate_hz
    (gain 1 / (1 + (f / fc)^(2 order)), no phase); x unchanged when it is too short, has
    NaN, or fc is near the Nyquist frequency."""
    if x.size < 16 or not np.all(np.isfinite(x)) or fc >= 0.45 * rate_hz:
        return x
    return sosfiltfilt(_butterworth(order, fc / (0.5 * rate_hz)), x, padtype="even")


@functools.lru_cache(maxsize=64)
def _butterworth(order: int, wn: float) -> np.ndarray:
    """Second-order sections of a Butterworth low-pass at ``wn`` (of the Nyquist
    frequency), designed once per (order, wn): the problem builders filter each
    maneuver's signals with the same few, and designing a filter costs more than running
    it on a maneuver."""
    return butter(order, wn, output="sos")


def input_corner_hz(t: np.ndarray, x: np.ndarray) -> float | None:
    """Low-pass corner (Hz) that removes the white noise of one measured input.

    t, x : (n,) native sample times (s) and values. The samples are put on a uniform grid
    at their mean rate; the periodogram (linear trend between the ends removed, Hann
    window) is averaged over third-octave bands. The noise floor is the mean power of the
    upper half of the band (the median over ln 2, robust to a few tones there), and must be
    flat there (the mean power of its upper quarter over its lower one within FLAT: white
    noise, not a signal's 1/f^2 roll-off or an anti-aliasing filter's); the corner is
    the upper edge of the highest band whose mean power exceeds SIGNAL_OVER_FLOOR times
    the floor, times CORNER_MARGIN, at least MIN_CORNER_HZ. None when the input has no
    noise floor to remove:
    fewer than MIN_SAMPLES finite samples, a floor of zero or not flat (noise-free commands
    or steps, a constant, a resampled channel), or a corner above 0.4 times the native rate
    (signal up to the Nyquist frequency)."""
    ok = np.isfinite(t) & np.isfinite(x)
    t, x = t[ok], x[ok]
    if t.size < MIN_SAMPLES or t[-1] <= t[0]:
        return None
    rate = (t.size - 1) / (t[-1] - t[0])
    tu = t[0] + np.arange(t.size) / rate
    xu = np.interp(tu, t, x)
    xu = xu - np.linspace(xu[0], xu[-1], xu.size)
    power = np.abs(np.fft.rfft(xu * np.hanning(xu.size))) ** 2
    f = np.fft.rfftfreq(xu.size, 1.0 / rate)
    upper, top = power[(f > 0.25 * rate) & (f <= 0.375 * rate)], power[f > 0.375 * rate]
    floor = np.median(power[f > 0.25 * rate]) / np.log(2.0)
    if not floor > 0 or not FLAT[0] < np.mean(top) / np.mean(upper) < FLAT[1]:
        return None  # no white floor: nothing or signal up there
    # third-octave bands from 0.5 Hz up to the Nyquist frequency 0.5 rate
    n_bands = int(np.ceil(np.log(rate) / np.log(BAND_RATIO)))
    edges = 0.5 * BAND_RATIO ** np.arange(n_bands + 1)
    corner = MIN_CORNER_HZ
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (f >= lo) & (f < hi)
        if m.sum() >= 4 and power[m].mean() > SIGNAL_OVER_FLOOR * floor:
            corner = max(corner, CORNER_MARGIN * float(hi))
    return None if corner > 0.4 * rate else corner


def control_input_corners(fd: FlightData, channels: Sequence[str] = CONTROL_INPUTS) -> dict[str, float]:
    """{channel: corner Hz} of the control inputs of ``fd`` that have noise to remove
    (:func:`input_corner_hz` on each channel's native samples)."""
    out = {}
    for c in channels:
        if c in fd:
            fc = input_corner_hz(np.asarray(fd[c].t, float), np.asarray(fd[c].values, float))
            if fc is not None:
                out[c] = fc
    return out


def smooth_columns(df: pd.DataFrame, rate_hz: float, corners: Mapping[str, float], order: int = 2) -> pd.DataFrame:
    """A copy of ``df`` (uniform grid at rate_hz) with each column of ``corners`` low-pass
    filtered forwards and backwards (:func:`zero_phase`, Butterworth of ``order``); a
    column with NaN (a gap) is filtered through its gaps' linear interpolation and keeps
    its NaN."""
    df = df.copy()
    for k, fc in corners.items():
        if k not in df:
            continue
        x = df[k].to_numpy(dtype=float)
        ok = np.isfinite(x)
        if ok.sum() < 16:
            continue
        idx = np.arange(x.size)
        y = zero_phase(np.interp(idx, idx[ok], x[ok]), rate_hz, fc, order)
        df[k] = np.where(ok, y, np.nan)
    return df


def smoothed_control_inputs(
    fd: FlightData, df: pd.DataFrame, rate_hz: float, channels: Sequence[str] = CONTROL_INPUTS
) -> tuple[pd.DataFrame | None, str | None]:
    """A copy of ``df`` (the identification grid) with its measured control inputs
    ``channels`` smoothed at their noise floors, and the note saying so for the problem;
    (None, None) when none was (no channels, or none with a noise floor)."""
    corners = {c: fc for c, fc in control_input_corners(fd, channels).items() if c in df}
    if not corners:
        return None, None
    note = (
        f"control inputs low-passed zero-phase (Butterworth order {INPUT_FILTER_ORDER}) "
        "where their measured noise floor begins: " + ", ".join(f"{c} {fc:.1f} Hz" for c, fc in corners.items())
    )
    return smooth_columns(df, rate_hz, corners, INPUT_FILTER_ORDER), note
