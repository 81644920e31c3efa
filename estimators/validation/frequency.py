"""Frequency-domain validation: the model's frequency response G(jw) = C (jwI - A)^-1 B + D,
spectral estimates H(jw) of the same from input/output data with coherence, and their
mismatch (magnitude in dB, phase in deg) against configurable bounds.

Array convention for responses: complex arrays of shape (n_w, n_out, n_in).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import signal

from ._util import as_2d, fill_missing

__all__ = ["freq_response", "bode", "SpectralEstimate", "spectral_estimate", "MismatchResult", "mismatch"]


def freq_response(A, B, C, D, w) -> np.ndarray:
    """G(jw) = C (jw I - A)^-1 B + D at angular frequencies w (rad/s), vectorised over w.

    A (n, n), B (n, n_in), C (n_out, n), D (n_out, n_in) or None (zero); w (n_w,) rad/s
    (for Hz multiply by 2 pi). Returns complex (n_w, n_out, n_in) in output units per
    input unit. A pole on jw gives inf/NaN at that frequency (numpy's singular solve raises).
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    B = np.asarray(B, dtype=float).reshape(A.shape[0], -1)
    C = np.asarray(C, dtype=float).reshape(-1, A.shape[0])
    D = np.zeros((C.shape[0], B.shape[1])) if D is None else np.asarray(D, dtype=float).reshape(C.shape[0], B.shape[1])
    w = np.atleast_1d(np.asarray(w, dtype=float))
    n = A.shape[0]
    M = 1j * w[:, None, None] * np.eye(n) - A  # (n_w, n, n)
    X = np.linalg.solve(M, np.broadcast_to(B.astype(complex), (w.size, *B.shape)))
    return C @ X + D


def bode(H, *, unwrap: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude (dB, 20 log10 |H|) and phase (deg) of a response H (n_w, ...), the phase
    unwrapped along axis 0 (frequency) unless unwrap=False (then in (-180, 180])."""
    H = np.asarray(H)
    with np.errstate(divide="ignore"):
        mag = 20.0 * np.log10(np.abs(H))
    ph = np.angle(H)
    if unwrap:
        ph = np.unwrap(ph, axis=0)
    return mag, np.degrees(ph)


@dataclass(frozen=True)
class SpectralEstimate:
    """Frequency response estimated from data (Welch cross/auto spectra).

    ``f`` (n_f,) Hz and ``w`` = 2 pi f rad/s; ``H`` complex (n_f, n_out, n_in) =
    S_yu S_uu^-1 (the H1 estimator; with one input S_yu / S_uu); ``coherence``
    (n_f, n_out, n_in) ordinary coherence |S_yu|^2 / (S_uu S_yy) in [0, 1];
    ``Suu`` (n_f, n_in, n_in), ``Syu`` (n_f, n_out, n_in), ``Syy`` (n_f, n_out) spectra
    (units^2/Hz).
    """

    f: np.ndarray
    H: np.ndarray
    coherence: np.ndarray
    Suu: np.ndarray
    Syu: np.ndarray
    Syy: np.ndarray

    @property
    def w(self) -> np.ndarray:
        return 2 * np.pi * self.f


def spectral_estimate(
    u,
    y,
    fs: float,
    nperseg: int | None = None,
    noverlap: int | None = None,
    window: str = "hann",
    detrend: str | bool = "constant",
) -> SpectralEstimate:
    """Frequency response and coherence from uniformly sampled input/output data.

    u: inputs (N, n_in) or (N,); y: outputs (N, n_out) or (N,); fs: sample rate (Hz).
    nperseg default min(N, max(256, N // 4)); 50 % overlap by default. With several
    inputs they must not be fully correlated (S_uu invertible at each frequency).
    Returns a :class:`SpectralEstimate`.
    """
    u, y = fill_missing(as_2d(u, "u")), fill_missing(as_2d(y, "y"))
    if u.shape[0] != y.shape[0]:
        raise ValueError(f"u has {u.shape[0]} samples, y {y.shape[0]}")
    n = u.shape[0]
    nper = min(n, max(256, n // 4)) if nperseg is None else int(nperseg)
    kw = dict(fs=fs, window=window, nperseg=nper, noverlap=noverlap, detrend=detrend, axis=-1)
    uT, yT = u.T, y.T
    # scipy: csd(x, y) = E[conj(X) Y]
    f, Suu = signal.csd(uT[None, :, :], uT[:, None, :], **kw)  # [i, j] = E[U_i conj(U_j)]
    _, Syu = signal.csd(uT[None, :, :], yT[:, None, :], **kw)  # [k, i] = E[Y_k conj(U_i)]
    _, Syy = signal.welch(yT, **kw)
    Suu = np.moveaxis(Suu, -1, 0)
    Syu = np.moveaxis(Syu, -1, 0)
    Syy = np.moveaxis(Syy, -1, 0).real
    with np.errstate(invalid="ignore", divide="ignore"):
        if u.shape[1] == 1:
            H = Syu / Suu
        else:
            H = np.linalg.solve(np.swapaxes(Suu, 1, 2), np.swapaxes(Syu, 1, 2)).swapaxes(1, 2)
        diag_u = np.real(np.diagonal(Suu, axis1=1, axis2=2))  # (n_f, n_in)
        coh = np.abs(Syu) ** 2 / (diag_u[:, None, :] * Syy[:, :, None])
    return SpectralEstimate(f=f, H=H, coherence=np.clip(coh.real, 0.0, 1.0), Suu=Suu, Syu=Syu, Syy=Syy)


def _bound_array(b) -> np.ndarray:
    """A bound as an array broadcastable to (n_w, n_out, n_in): a scalar, an envelope
    (n_w,) or a full array."""
    a = np.asarray(b, dtype=float)
    return a.reshape(-1, 1, 1) if a.ndim == 1 else a


@dataclass(frozen=True)
class MismatchResult:
    """Model-vs-data mismatch per frequency, arrays (n_w, n_out, n_in):
    ``mag_db`` = 20 log10 |H_model / H_data|, ``phase_deg`` = angle(H_model / H_data) in
    (-180, 180], ``used`` where the coherence reached min_coherence (and inside the band);
    ``table``: per (output, input) max |mag_db| and |phase_deg| over used frequencies, the
    bounds, the count of used points and ``pass``.
    """

    w: np.ndarray
    mag_db: np.ndarray
    phase_deg: np.ndarray
    used: np.ndarray
    table: pd.DataFrame


def mismatch(
    H_model,
    H_data,
    w,
    coherence=None,
    *,
    mag_bound_db=3.0,
    phase_bound_deg=20.0,
    min_coherence: float = 0.6,
    band: tuple[float, float] | None = None,
    outputs: Sequence[str] | None = None,
    inputs: Sequence[str] | None = None,
) -> MismatchResult:
    """Compare a model response with a spectral estimate at the same frequencies.

    H_model, H_data: complex (n_w, n_out, n_in) (or (n_w,) for SISO); w: (n_w,) rad/s;
    coherence: same shape as H_data, points below min_coherence are ignored (None: all
    used); band: optional (w_min, w_max) rad/s. Bounds: scalars, arrays (n_w,) (an
    envelope) or (n_w, n_out, n_in) (per pair, e.g. widened by the random error) in dB and
    deg. A channel passes when every used point is within both bounds
    (and at least one point is used).
    """
    Hm = np.asarray(H_model, dtype=complex)
    Hd = np.asarray(H_data, dtype=complex)
    if Hm.ndim == 1:
        Hm, Hd = Hm[:, None, None], Hd[:, None, None]
        coherence = None if coherence is None else np.asarray(coherence)[:, None, None]
    if Hm.shape != Hd.shape:
        raise ValueError(f"H_model {Hm.shape} and H_data {Hd.shape} differ")
    w = np.asarray(w, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = Hm / Hd
        mag = 20.0 * np.log10(np.abs(ratio))
    ph = np.degrees(np.angle(ratio))
    used = np.isfinite(mag) & np.isfinite(ph)
    if coherence is not None:
        used &= np.asarray(coherence) >= min_coherence
    if band is not None:
        used &= ((w >= band[0]) & (w <= band[1]))[:, None, None]
    mb, pb = (np.broadcast_to(_bound_array(b), Hm.shape) for b in (mag_bound_db, phase_bound_deg))
    ok = (np.abs(mag) <= mb) & (np.abs(ph) <= pb)
    n_out, n_in = Hm.shape[1:]
    outputs = list(outputs) if outputs is not None else [f"y{i}" for i in range(n_out)]
    inputs = list(inputs) if inputs is not None else [f"u{i}" for i in range(n_in)]
    absmag = np.where(used, np.abs(mag), np.nan)
    absph = np.where(used, np.abs(ph), np.nan)
    n_used = used.sum(axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN channels -> NaN
        max_mag = np.nanmax(absmag, axis=0)
        max_ph = np.nanmax(absph, axis=0)
    passed = np.all(ok | ~used, axis=0) & (n_used > 0)
    idx = pd.MultiIndex.from_product([outputs, inputs], names=["output", "input"])
    table = pd.DataFrame(
        {
            "max_mag_db": max_mag.ravel(),
            "max_phase_deg": max_ph.ravel(),
            "n_used": n_used.ravel(),
            "pass": passed.ravel(),
        },
        index=idx,
    )
    table.attrs.update(
        mag_bound_db=mag_bound_db if np.ndim(mag_bound_db) == 0 else "per point",
        phase_bound_deg=phase_bound_deg if np.ndim(phase_bound_deg) == 0 else "per point",
        min_coherence=min_coherence,
    )
    return MismatchResult(w=w, mag_db=mag, phase_deg=ph, used=used, table=table)
