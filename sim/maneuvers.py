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
