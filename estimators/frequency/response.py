"""Frequency responses from time histories: composite windows, conditioned (MIMO)
responses, coherence and random error.

The spectra are Welch averages of Hann-windowed, 50 %-overlapped segments for several
window lengths. A long window resolves low frequencies but averages few segments; a short
one averages many but resolves only high frequencies. At each frequency the windows that
resolve it (at least two periods per window) are combined, weighted by their numbers of
averages (the inverse variance of their spectra for a common coherence; after the
composite-window method of CIFER: Tischler & Remple, *Aircraft and Rotorcraft System
Identification*, 2nd ed., 2012, ch. 8).

With several inputs the response of each output to each input is conditioned on the other
inputs: H^T = Guu^-1 Guy at each frequency, so inputs that move together (aileron with
rudder, a pilot with the autopilot) give each input's own response where the single-input
estimate mixes them. Coherence is then the partial coherence of the output with that input,
the other inputs removed; the multiple coherence says how much of each output all the
inputs explain. The random error of |H| is Bendat & Piersol's, (Random Data, 4th ed., eq.
9.90): eps = sqrt((1 - gamma^2_multiple) Gyy / (2 n (G_uu.rest) |H|^2)) with n the
effective number of averages less the other inputs and the multiple coherence's bias from
few averages taken out; the phase error in rad is the same number.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from estimators.errors import ModelDefinitionError
from estimators.frequency.transform import uniform_step

#: segment overlap of the Welch averages
OVERLAP = 0.5
#: default number of window lengths and of frequencies
N_WINDOWS = 5
N_FREQUENCIES = 100
#: a window resolves frequencies from this many periods per window up
PERIODS_PER_WINDOW = 5.0
#: the default highest frequency as a fraction of the sample rate
F_MAX_OF_RATE = 0.2


@dataclass(frozen=True)
class FrequencyResponse:
    """Frequency responses of ``outputs`` to ``inputs``.

    f : (n_f,) Hz.
    H : (n_f, n_y, n_u) complex, output units per input unit (conditioned on the other
        inputs when there are several).
    coherence : (n_f, n_y, n_u) ordinary (one input) or partial coherence, 0..1.
    random_error : (n_f, n_y, n_u) normalised random error of |H| (a fraction); of the
        phase, the same number in rad.
    multiple_coherence : (n_f, n_y) the share of each output's power all inputs explain.
    inputs, outputs : channel names.
    windows : (n_w,) the window lengths combined (s).
    input_spectra : (n_f, n_u) the inputs' one-sided auto-spectra (units^2/Hz): where an
        input carries power.
    n_averages : (n_f,) the averages behind each frequency: the effective numbers of the
        windows that resolve it, summed (their segments overlap in time but each window
        length resolves its own bandwidth; the random error's scatter over repeated
        experiments bears this out).
    """

    f: np.ndarray
    H: np.ndarray
    coherence: np.ndarray
    random_error: np.ndarray
    multiple_coherence: np.ndarray
    inputs: list[str] = field(default_factory=list)
    outputs: list[str] = field(default_factory=list)
    windows: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_averages: np.ndarray = field(default_factory=lambda: np.zeros(0))
    input_spectra: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def w(self) -> np.ndarray:
        """(n_f,) rad/s."""
        return 2 * np.pi * self.f

    @property
    def magnitude_db(self) -> np.ndarray:
        """(n_f, n_y, n_u) 20 log10 |H|."""
        with np.errstate(divide="ignore"):
            return 20 * np.log10(np.abs(self.H))

    @property
    def phase_deg(self) -> np.ndarray:
        """(n_f, n_y, n_u) phase in degrees, unwrapped along frequency."""
        return np.degrees(np.unwrap(np.angle(self.H), axis=0))

    def pair(self, output: str, input: str) -> pd.DataFrame:
        """One input-output pair on f: magnitude (dB), phase (deg), coherence, random
        error, the complex H."""
        k, i = self.outputs.index(output), self.inputs.index(input)
        return pd.DataFrame(
            {
                "magnitude_db": self.magnitude_db[:, k, i],
                "phase_deg": self.phase_deg[:, k, i],
                "coherence": self.coherence[:, k, i],
                "random_error": self.random_error[:, k, i],
                "H": self.H[:, k, i],
            },
            index=pd.Index(self.f, name="f_hz"),
        )

    def select(self, output: str, input: str) -> FrequencyResponse:
        """The single pair as a (n_f, 1, 1) response (what a transfer-function fit takes)."""
        k, i = self.outputs.index(output), self.inputs.index(input)
        return FrequencyResponse(
            self.f,
            self.H[:, k : k + 1, i : i + 1],
            self.coherence[:, k : k + 1, i : i + 1],
            self.random_error[:, k : k + 1, i : i + 1],
            self.multiple_coherence[:, k : k + 1],
            [input],
            [output],
            self.windows,
            self.n_averages,
            self.input_spectra[:, i : i + 1],
        )


def _as_2d(a: np.ndarray, n: int, what: str) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    a = a[:, None] if a.ndim == 1 else a
    if a.ndim != 2 or a.shape[0] != n:
        raise ModelDefinitionError(f"frequency_response: {what} has shape {a.shape}, t has {n} samples")
    if not np.all(np.isfinite(a)):
        raise ModelDefinitionError(f"frequency_response: {what} holds NaN or inf; fill or cut them out first")
    return a


def default_windows(duration: float, dt: float, n: int = N_WINDOWS) -> np.ndarray:
    """Window lengths (s): geometric from the longer of a tenth of the longest and 64
    samples to half the record (at least three overlapped segments in the longest)."""
    t_max = duration / 2
    t_min = min(max(t_max / 10, 64 * dt), t_max)
    return np.geomspace(t_min, t_max, n) if t_max > t_min else np.array([t_max])


def overlap_correlation(L: int, overlap: float = OVERLAP) -> float:
    """The correlation of the squared Hann windows of two segments ``overlap`` apart
    (Welch): with K segments the variance of the average is (1 + 2 rho^2) / K of one's."""
    wd = np.hanning(L + 2)[1:-1]
    s = int(round(L * (1 - overlap)))
    if s >= L:
        return 0.0
    return float(np.sum(wd[:-s] * wd[s:]) ** 2 / np.sum(wd**2) ** 2) ** 0.5


def _window_spectra(x: np.ndarray, dt: float, L: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(bin frequencies (n_b,) Hz, averaged cross spectra (n_b, n_c, n_c) with G[a, b] =
    E[conj(X_a) X_b] (one-sided, units^2/Hz), effective number of averages) of the channels
    ``x`` (N, n_c) with Hann windows of L samples, 50 % overlap, means removed per segment."""
    N = x.shape[0]
    step = max(1, int(round(L * (1 - OVERLAP))))
    starts = np.arange(0, N - L + 1, step)
    wd = np.hanning(L + 2)[1:-1]
    idx = starts[:, None] + np.arange(L)[None, :]
    seg = x[idx]  # (K, L, n_c)
    seg = seg - seg.mean(axis=1, keepdims=True)
    X = np.fft.rfft(seg * wd[None, :, None], axis=1)  # (K, n_b, n_c)
    G = np.einsum("kba,kbc->bac", np.conj(X), X) / len(starts)
    G *= 2 * dt / np.sum(wd**2)
    rho = overlap_correlation(L)
    K = len(starts)
    n_eff = K / (1 + 2 * rho**2 * (K - 1) / K) if K > 1 else 1.0
    return np.fft.rfftfreq(L, dt), G, n_eff


def _interp(fb: np.ndarray, G: np.ndarray, f: np.ndarray) -> np.ndarray:
    """G (n_b, n_c, n_c) at f by linear interpolation in frequency."""
    flat = G.reshape(G.shape[0], -1)
    out = np.empty((f.size, flat.shape[1]), dtype=complex)
    for j in range(flat.shape[1]):
        out[:, j] = np.interp(f, fb, flat[:, j].real) + 1j * np.interp(f, fb, flat[:, j].imag)
    return out.reshape(f.size, *G.shape[1:])


def _solve(G: np.ndarray, n_u: int, n_avg: np.ndarray) -> tuple[np.ndarray, ...]:
    """H (n_f, n_y, n_u), partial coherence, random error, multiple coherence from the
    spectral matrices G (n_f, n_c, n_c) of [inputs, outputs] and the averages n_avg (n_f,)."""
    Guu, Guy = G[:, :n_u, :n_u], G[:, :n_u, n_u:]
    Gyy = np.real(np.einsum("fkk->fk", G[:, n_u:, n_u:]))
    n_f, n_y = Gyy.shape
    Ginv = np.linalg.pinv(Guu, hermitian=True)
    Ht = Ginv @ Guy  # (n_f, n_u, n_y)
    H = np.transpose(Ht, (0, 2, 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        explained = np.real(np.einsum("fik,fij,fjk->fk", np.conj(Guy), Ginv, Guy))
        mult = np.clip(explained / Gyy, 0.0, 1.0)
        coh = np.empty((n_f, n_y, n_u))
        cond_uu = np.empty((n_f, n_u))
        for i in range(n_u):
            r = [j for j in range(n_u) if j != i]
            if r:
                Grr_inv = np.linalg.pinv(Guu[:, r][:, :, r], hermitian=True)
                gi_r = Guu[:, i, r]  # (n_f, n_r)
                Gii = np.real(Guu[:, i, i] - np.einsum("fr,frs,fs->f", gi_r, Grr_inv, Guu[:, r, i]))
                Giy = Guy[:, i, :] - np.einsum("fr,frs,fsk->fk", gi_r, Grr_inv, Guy[:, r, :])
                Gyy_r = Gyy - np.real(np.einsum("frk,frs,fsk->fk", np.conj(Guy[:, r, :]), Grr_inv, Guy[:, r, :]))
            else:
                Gii, Giy, Gyy_r = np.real(Guu[:, i, i]), Guy[:, i, :], Gyy
            cond_uu[:, i] = Gii
            coh[:, :, i] = np.clip(np.abs(Giy) ** 2 / (Gii[:, None] * Gyy_r), 0.0, 1.0)
        n = np.maximum(n_avg - n_u + 1, 1.0)
        # the noise from the multiple coherence less its bias towards 1 from n averages
        # (E[g^2] ~ gamma^2 + (1 - gamma^2)^2 / n, undone to first order: (n g^2 - 1) / (n - 1))
        nn = n[:, None]
        unbiased = np.where(nn > 1, np.clip((nn * mult - 1) / np.maximum(nn - 1, 1e-12), 0.0, 1.0), 0.0)
        noise = (1 - unbiased) * Gyy  # (n_f, n_y)
        err = np.sqrt(noise[:, :, None] / (2 * n[:, None, None] * cond_uu[:, None, :] * np.abs(H) ** 2))
    return H, np.nan_to_num(coh), err, np.nan_to_num(mult)


def _records(t, u, y) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], float]:
    """(times, inputs, outputs) per record and their common sample interval."""
    many = isinstance(t, (list, tuple))
    ts = [np.asarray(x, dtype=float) for x in t] if many else [np.asarray(t, dtype=float)]
    us = list(u) if many else [u]
    ys = list(y) if many else [y]
    if not (len(ts) == len(us) == len(ys)) or not ts:
        raise ModelDefinitionError(f"frequency_response: {len(ts)} time vectors, {len(us)} inputs, {len(ys)} outputs")
    dts = [uniform_step(x, "frequency_response") for x in ts]
    if max(dts) - min(dts) > 1e-6 * min(dts):
        raise ModelDefinitionError(
            f"frequency_response: the records are sampled at {min(dts):.6g} to {max(dts):.6g} s; resample them alike"
        )
    U = [_as_2d(a, x.size, "u") for a, x in zip(us, ts)]
    Y = [_as_2d(b, x.size, "y") for b, x in zip(ys, ts)]
    if len({a.shape[1] for a in U}) > 1 or len({b.shape[1] for b in Y}) > 1:
        raise ModelDefinitionError("frequency_response: the records have different numbers of inputs or outputs")
    return ts, U, Y, dts[0]


def frequency_response(
    t: np.ndarray | Sequence[np.ndarray],
    u: np.ndarray | Sequence[np.ndarray],
    y: np.ndarray | Sequence[np.ndarray],
    f: np.ndarray | None = None,
    *,
    windows: Sequence[float] | None = None,
    inputs: Sequence[str] | None = None,
    outputs: Sequence[str] | None = None,
) -> FrequencyResponse:
    """Frequency responses of the outputs ``y`` to the inputs ``u`` (module docstring).

    t : (N,) uniformly sampled times (s), or a list of such records (maneuvers, the pieces
        of a log between gaps) whose averages add up.
    u : (N,) or (N, n_u) inputs; y : (N,) or (N, n_y) outputs (lists with a list t).
    f : (n_f,) frequencies (Hz); default N_FREQUENCIES log-spaced from PERIODS_PER_WINDOW
        periods of the longest window to a fifth of the sample rate.
    windows : window lengths (s); default :func:`default_windows` of the longest record (a
        single length: plain Welch averages).
    inputs, outputs : names (default u0.., y0..).
    """
    ts, Us, Ys, dt = _records(t, u, y)
    n_u, n_y = Us[0].shape[1], Ys[0].shape[1]
    longest = max(x.size for x in ts)
    if longest < 8:
        raise ModelDefinitionError("frequency_response needs at least 8 samples")
    duration = longest * dt
    T_w = np.sort(np.asarray(windows if windows is not None else default_windows(duration, dt), dtype=float))
    Ls = np.unique(np.clip(np.round(T_w / dt).astype(int), 8, longest))
    T_w = Ls * dt
    if f is None:
        f_lo = PERIODS_PER_WINDOW / T_w[-1]
        f = np.geomspace(f_lo, max(F_MAX_OF_RATE / dt, 1.01 * f_lo), N_FREQUENCIES)
    f = np.atleast_1d(np.asarray(f, dtype=float))
    n_f, n_c = f.size, n_u + n_y
    num = np.zeros((n_f, n_c, n_c), dtype=complex)
    n_avg = np.zeros(n_f)
    for L in Ls:
        for U, Y in zip(Us, Ys):
            if U.shape[0] < L:
                continue
            fb, G, n_eff = _window_spectra(np.column_stack([U, Y]), dt, int(L))
            ok = (f >= PERIODS_PER_WINDOW / (L * dt)) & (f <= fb[-1])
            if L == Ls[-1]:  # the longest window carries what no other resolves
                ok |= (f < PERIODS_PER_WINDOW / (L * dt)) & (f >= fb[1] * (1 - 1e-9))
            if not np.any(ok):
                continue
            # the windows (and records) that resolve a frequency are averaged in proportion
            # to their numbers of averages (the inverse variance of their spectra for a
            # common coherence: a window's own coherence from few averages is biased towards
            # 1 and would make the longest window look the most accurate)
            num[ok] += n_eff * _interp(fb, G, f[ok])
            n_avg[ok] += n_eff
    if np.any(n_avg == 0):
        raise ModelDefinitionError(
            f"frequency_response: no window resolves {f[n_avg == 0].min():.4g} Hz to "
            f"{f[n_avg == 0].max():.4g} Hz of a {duration:.4g} s record"
        )
    G = num / n_avg[:, None, None]
    H, coh, err, mult = _solve(G, n_u, n_avg)
    return FrequencyResponse(
        f=f,
        H=H,
        coherence=coh,
        random_error=err,
        multiple_coherence=mult,
        inputs=list(inputs) if inputs is not None else [f"u{i}" for i in range(n_u)],
        outputs=list(outputs) if outputs is not None else [f"y{i}" for i in range(n_y)],
        windows=T_w,
        n_averages=n_avg,
        input_spectra=np.real(np.einsum("fii->fi", G[:, :n_u, :n_u])),
    )
