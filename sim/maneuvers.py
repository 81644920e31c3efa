"""Input signals of designed maneuvers (doublet, 3-2-1-1, multistep, sweeps, multisine).

Every shape is a vectorised function of time since the maneuver start, ``tau`` (s, any
shape), returning the deflection increment in the unit of its amplitude (rad for
surfaces, fraction for throttle), zero outside ``[0, duration)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

SHAPES = ("doublet", "3211", "multistep", "sweep", "multisine")
AXES = ("de", "da", "dr", "throttle")


@dataclass(frozen=True)
class Maneuver:
    """One designed input. Angles in rad, times in s, frequencies in Hz.

    ``axes`` holds one axis for every shape but ``multisine``, which may excite several
    axes at once with mutually orthogonal harmonics. ``amplitude`` is per axis (rad, or
    a throttle fraction): the step height for steps, the sine amplitude for sweeps and the
    peak of each axis' multisine.
    """

    name: str
    shape: str
    axes: tuple[str, ...]
    amplitude: tuple[float, ...]
    t_start: float
    pulse: float = 0.0  #: step width (doublet: each half), s
    levels: tuple[float, ...] = ()  #: multistep levels in units of amplitude
    f0: float = 0.0  #: sweep start / multisine lowest frequency, Hz
    f1: float = 0.0  #: sweep end / multisine highest frequency, Hz
    sweep: str = "linear"  #: linear | log
    length: float = 0.0  #: sweep length / multisine period, s
    cycles: int = 1  #: multisine periods
    harmonics: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    phases: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    scale: dict[str, float] = field(default_factory=dict, repr=False)

    @property
    def duration(self) -> float:
        """Length of the maneuver, s."""
        if self.shape in ("doublet", "3211", "multistep"):
            return self.pulse * len(self.step_levels())
        if self.shape == "sweep":
            return self.length
        return self.length * self.cycles

    @property
    def t_end(self) -> float:
        return self.t_start + self.duration

    @property
    def axis_label(self) -> str:
        """Axes joined with '+', e.g. 'de' or 'de+da+dr'."""
        return "+".join(self.axes)

    def step_levels(self) -> tuple[float, ...]:
        if self.shape == "doublet":
            return (1.0, -1.0)
        if self.shape == "3211":
            return (1.0, 1.0, 1.0, -1.0, -1.0, 1.0, -1.0)
        return self.levels

    def signal(self, t: np.ndarray, axis: str) -> np.ndarray:
        """Deflection increment on ``axis`` at absolute times ``t`` (s), same shape as t."""
        t = np.asarray(t, dtype=float)
        out = np.zeros_like(t)
        if axis not in self.axes:
            return out
        amp = self.amplitude[self.axes.index(axis)]
        tau = t - self.t_start
        inside = (tau >= 0) & (tau < self.duration - 1e-9)
        if self.shape in ("doublet", "3211", "multistep"):
            lv = np.asarray(self.step_levels())
            # round before flooring so that exact grid times land in the right pulse
            k = np.floor(np.round(tau[inside] / self.pulse, 9)).astype(int)
            k = np.clip(k, 0, len(lv) - 1)
            out[inside] = amp * lv[k]
        elif self.shape == "sweep":
            x = tau[inside]
            if self.sweep == "linear":
                phase = 2 * np.pi * (self.f0 * x + 0.5 * (self.f1 - self.f0) / self.length * x**2)
            else:
                kk = np.log(self.f1 / self.f0) / self.length
                phase = 2 * np.pi * self.f0 * (np.exp(kk * x) - 1.0) / kk
            out[inside] = amp * np.sin(phase)
        else:
            x = tau[inside]
            f = self.harmonics[axis]
            ph = self.phases[axis]
            s = np.sin(2 * np.pi * np.outer(x, f) + ph).sum(axis=1)
            out[inside] = amp * self.scale[axis] * s
        return out


def schroeder_multisine(
    axes: tuple[str, ...], f_min: float, f_max: float, period: float
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, float]]:
    """Harmonics k/period in [f_min, f_max] dealt round-robin to the axes (mutually
    orthogonal inputs), Schroeder phases per axis (low peak factor), and the scale that
    makes each axis' peak equal to 1. Returns (frequencies Hz, phases rad, scale) per axis.
    """
    k = np.arange(max(1, int(np.ceil(f_min * period - 1e-9))), int(np.floor(f_max * period + 1e-9)) + 1)
    if len(k) < len(axes):
        raise ValueError(
            f"only {len(k)} harmonics of 1/{period} s between {f_min} and {f_max} Hz "
            f"for {len(axes)} axes; widen the band or lengthen period_s"
        )
    freqs, phases, scale = {}, {}, {}
    grid = np.linspace(0.0, period, 4001)
    for i, ax in enumerate(axes):
        kk = k[i :: len(axes)]
        n = len(kk)
        j = np.arange(1, n + 1)
        ph = -np.pi * j * (j - 1) / n  # Schroeder (1970), equal power per harmonic
        f = kk / period
        s = np.sin(2 * np.pi * np.outer(grid, f) + ph).sum(axis=1)
        freqs[ax], phases[ax], scale[ax] = f, ph, 1.0 / float(np.max(np.abs(s)))
    return freqs, phases, scale


def input_histories(maneuvers: list[Maneuver], t: np.ndarray) -> dict[str, np.ndarray]:
    """Sum of all maneuvers' increments per axis on the time grid t (s): arrays like t."""
    out = {ax: np.zeros_like(np.asarray(t, dtype=float)) for ax in AXES}
    for m in maneuvers:
        for ax in m.axes:
            out[ax] += m.signal(t, ax)
    return out


#: the sharpness (1 / rms units) of the smooth max and min the phase search minimises, in turn
PHASE_SHARPNESS = (4.0, 16.0, 64.0)


def relative_peak_factor(u: np.ndarray) -> float:
    """RPF = (max - min) / (2 sqrt(2) rms) of a signal (1 for a sine): how much larger its
    excursions are than a sine's of the same energy."""
    u = np.asarray(u, dtype=float)
    rms = float(np.sqrt(np.mean(u**2)))
    return float((u.max() - u.min()) / (2 * np.sqrt(2) * rms)) if rms > 0 else float("inf")


def _sines(k: np.ndarray, phases: np.ndarray, m: int) -> np.ndarray:
    """sum_i sin(2 pi k_i s / m + phase_i) for s = 0..m-1 (one period), by an inverse FFT."""
    C = np.zeros(m // 2 + 1, dtype=complex)
    C[k] = np.exp(1j * (phases - np.pi / 2)) * (m / 2)
    return np.fft.irfft(C, m)


def _clipped(k: np.ndarray, ph: np.ndarray, m: int, iterations: int) -> np.ndarray:
    """Phases improved by clipping the signal's peaks and taking the phases of what is left
    (van der Ouderaa, Schoukens & Renneboog, IEEE Trans. Instrum. Meas. 37(1), 1988)."""
    best, best_rpf, level = ph, relative_peak_factor(_sines(k, ph, m)), 0.9
    for _ in range(iterations):
        x = _sines(k, ph, m)
        c = level * np.max(np.abs(x))
        ph = np.angle(np.fft.rfft(np.clip(x, -c, c))[k]) + np.pi / 2
        level = max(0.6, level * 0.99)
        r = relative_peak_factor(_sines(k, ph, m))
        if r < best_rpf:
            best, best_rpf = ph, r
    return best


def _span_refined(k: np.ndarray, ph: np.ndarray, m: int) -> np.ndarray:
    """Phases that minimise max - min of the signal over a period, through its smooth
    log-sum-exp bounds at increasing sharpness (L-BFGS with the exact gradient): the peak
    factor itself, not a norm that stands in for it."""
    from scipy.optimize import minimize
    from scipy.special import logsumexp, softmax

    a = 2 * np.pi * np.outer(np.arange(m) / m, k)
    Sa, Ca = np.sin(a), np.cos(a)
    rms = np.sqrt(k.size / 2)

    def span(phi: np.ndarray, b: float) -> tuple[float, np.ndarray]:
        c, s = np.cos(phi), np.sin(phi)
        x = (Sa @ c + Ca @ s) / rms
        dx = (Ca * c - Sa * s) / rms  # d x / d phi_i = cos(a_i + phi_i)
        f = (logsumexp(b * x) + logsumexp(-b * x)) / b
        return f, (softmax(b * x) - softmax(-b * x)) @ dx

    for b in PHASE_SHARPNESS:
        ph = minimize(span, ph, args=(b,), jac=True, method="L-BFGS-B", options={"maxiter": 300}).x
    return ph


def min_peak_phases(k: np.ndarray, *, starts: int = 8, seed: int = 0) -> np.ndarray:
    """Phases of equal-amplitude harmonics ``k`` (of one period) for a low relative peak
    factor: from Schroeder's phases (clipped first) and ``starts`` - 1 random ones, each
    refined by :func:`_span_refined`; the phases of the lowest RPF found (the problem has
    many local minima)."""
    k = np.asarray(k, dtype=int)
    n = k.size
    m = int(2 ** np.ceil(np.log2(max(16 * int(k.max()), 256))))
    j = np.arange(1, n + 1)
    rng = np.random.default_rng(seed)
    inits = [_clipped(k, -np.pi * j * (j - 1) / n, m, 100)] + [rng.uniform(-np.pi, np.pi, n) for _ in range(starts - 1)]
    fine = 4 * m
    best, best_rpf = inits[0], relative_peak_factor(_sines(k, inits[0], fine))
    for ph in inits:
        ph = _span_refined(k, ph, m)
        r = relative_peak_factor(_sines(k, ph, fine))
        if r < best_rpf:
            best, best_rpf = ph, r
    return best


def orthogonal_multisines(
    inputs: list[str] | tuple[str, ...],
    band: tuple[float, float],
    duration: float,
    dt: float,
    amplitude: float | dict[str, float] = 1.0,
):
    """Mutually orthogonal multisines for several inputs flown at once (Morelli, "Multiple
    input design for real-time parameter estimation in the frequency domain", IFAC SYSID
    2003): the harmonics of 1/duration inside ``band`` (Hz) dealt round-robin to the inputs,
    equal amplitudes, phases for a low relative peak factor (:func:`min_peak_phases`), each
    input shifted in time to start and end at zero, scaled to its peak ``amplitude`` (one
    value, or per input).

    Returns a DataFrame on t (s, index "t", 0..duration in steps of dt) with one column per
    input; ``attrs["frequencies"][name]`` (Hz) and ``attrs["rpf"][name]``; and the closed
    form u(t) = scale sum_k sin(2 pi f_k t + phase_k) for players that evaluate it at their
    own times: ``attrs["phases"][name]`` (rad) and ``attrs["scale"][name]`` (the input's
    unit).
    """
    import pandas as pd

    inputs = list(inputs)
    n_steps = duration / dt
    if not (duration > 0 and dt > 0 and abs(n_steps - round(n_steps)) < 1e-6):
        raise ValueError(f"duration {duration} s must be a whole number of steps dt = {dt} s")
    lo, hi = band
    if not 0 <= lo < hi or hi > 0.5 / dt:
        raise ValueError(f"band {band} Hz must satisfy 0 <= lo < hi <= the Nyquist frequency {0.5 / dt:g} Hz")
    k_all = np.arange(max(1, int(np.ceil(lo * duration - 1e-9))), int(np.floor(hi * duration + 1e-9)) + 1)
    if k_all.size < len(inputs):
        raise ValueError(
            f"{k_all.size} harmonics of 1/{duration:g} s in {lo:g}-{hi:g} Hz for {len(inputs)} inputs: "
            "widen the band or lengthen the duration"
        )
    n = int(round(n_steps))
    t = np.arange(n + 1) * dt
    amp = amplitude if isinstance(amplitude, dict) else {u: float(amplitude) for u in inputs}
    cols, freqs, rpfs, phases, scales = {}, {}, {}, {}, {}
    for i, name in enumerate(inputs):
        k = k_all[i :: len(inputs)]
        ph = min_peak_phases(k, seed=i)
        m = int(2 ** np.ceil(np.log2(max(64 * int(k.max()), 1024))))
        x = _sines(k, ph, m)
        # start at a zero crossing: the time shift moves every harmonic's phase, not its
        # amplitude, so orthogonality and peak factor stay; the period ends where it began
        s = int(np.flatnonzero(np.signbit(x) != np.signbit(np.roll(x, -1)))[0])
        frac = x[s] / (x[s] - x[(s + 1) % m])
        tau = (s + frac) / m * duration
        ph = ph + 2 * np.pi * k * tau / duration
        u = np.sin(2 * np.pi * np.outer(t, k / duration) + ph).sum(axis=1)
        u[0] = u[-1] = 0.0  # zero to round-off already: exactly at both ends
        scales[name] = amp[name] / np.max(np.abs(u))
        u *= scales[name]
        cols[name], freqs[name], rpfs[name] = u, k / duration, relative_peak_factor(u[:-1])
        phases[name] = np.mod(ph, 2 * np.pi)
    df = pd.DataFrame(cols, index=pd.Index(t, name="t"))
    df.attrs["frequencies"] = freqs
    df.attrs["rpf"] = rpfs
    df.attrs["phases"] = phases
    df.attrs["scale"] = scales
    return df
