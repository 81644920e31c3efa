"""Noise settings of the filters: process noise F (continuous white noise, state unit per
sqrt(s)) and measurement noise R (output variance) from the caller's specification or
the data, and their adaptation between filter passes by covariance matching.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from estimators import statistics as st
from estimators.errors import ModelDefinitionError
from estimators.model import Model, Segment


def named_vector(spec: Any, names: Sequence[str], what: str, default: np.ndarray) -> np.ndarray:
    """A per-name vector from None (default), a scalar, a mapping or a sequence."""
    out = np.array(default, dtype=float)
    if spec is None:
        return out
    if isinstance(spec, Mapping):
        bad = sorted(set(spec) - set(names))
        if bad:
            raise ModelDefinitionError(f"{what}: unknown names {bad}; expected some of {list(names)}")
        for k, v in spec.items():
            out[list(names).index(k)] = float(v)
        return out
    arr = np.asarray(spec, dtype=float)
    if arr.ndim == 0:
        return np.full(len(names), float(arr))
    if arr.shape != (len(names),):
        raise ModelDefinitionError(f"{what}: expected {len(names)} values for {list(names)}, got shape {arr.shape}")
    return arr


def named_process_noise(model: Model, names: Sequence[str], segments: Sequence[Segment]) -> np.ndarray:
    """Process-noise std (n,) for a list of state names: the data default of
    :func:`default_process_noise` on those states, 0 on the others. A named state that is
    not a measured output has no data default: that is an error saying what to give."""
    bad = sorted(set(names) - set(model.states))
    if bad:
        raise ModelDefinitionError(f"process_noise: {bad} are not states {model.states}")
    unmeasured = [s for s in names if s not in model.outputs]
    if unmeasured:
        raise ModelDefinitionError(
            f"process_noise names {unmeasured}, not measured outputs, so their level cannot "
            "come from the data: give it as {state: std} (state unit per sqrt(s))"
        )
    default = default_process_noise(model, segments)
    return np.array([default[i] if s in names else 0.0 for i, s in enumerate(model.states)])


def is_name_list(spec: Any) -> bool:
    """Whether a noise setting is a non-empty list of state names."""
    return isinstance(spec, (list, tuple)) and len(spec) > 0 and all(isinstance(v, str) for v in spec)


def process_noise_matrix(model: Model, spec: Any, segments: Sequence[Segment] = ()) -> np.ndarray:
    """F (n_states, n_states) from None (zeros), {state: std}, a (n,) vector of std, an
    (n, n) matrix, or a list of state names (their data default, :func:`named_process_noise`;
    needs ``segments``). Units: state unit per sqrt(s) (std of the continuous white noise)."""
    n = len(model.states)
    if is_name_list(spec):
        return np.diag(named_process_noise(model, spec, segments))
    if spec is not None and np.ndim(spec) == 2:
        F = np.asarray(spec, dtype=float)
        if F.shape[0] != n:
            raise ModelDefinitionError(f"process_noise matrix needs {n} rows (states {model.states})")
        return F
    return np.diag(named_vector(spec, model.states, "process_noise", np.zeros(n)))


def default_process_noise(model: Model, segments: Sequence[Segment], fraction: float = 0.05) -> np.ndarray:
    """Process-noise std per state (n,) from the data: ``fraction`` sqrt(var(diff z) / h)
    for each state that is a measured output (a twentieth of the bound the sample-to-sample
    variation puts on it), 0 for unmeasured states. Units: state unit per sqrt(s); h is
    the median sample interval (s)."""
    out = np.zeros(len(model.states))
    for i, name in enumerate(model.states):
        if name in model.outputs:
            d, dt = _sample_differences(segments, model.outputs.index(name))
            if d.size >= 2:
                out[i] = fraction * np.sqrt(np.var(d) / np.median(dt))
    return out


def _sample_differences(segments: Sequence[Segment], j: int) -> tuple[np.ndarray, np.ndarray]:
    """Differences of output j between its consecutive measured samples and their time steps,
    pooled over segments ((n_d,), (n_d,)): a slower channel on a faster grid is NaN between
    its samples, so plain np.diff would hold no finite value."""
    d, dt = [], []
    for seg in segments:
        ok = np.isfinite(seg.z[:, j])
        d.append(np.diff(seg.z[ok, j]))
        dt.append(np.diff(seg.t[ok]))
    return np.concatenate(d), np.concatenate(dt)


def default_measurement_noise(model: Model, segments: Sequence[Segment]) -> np.ndarray:
    """Measurement-noise variance per output from the data: the white-noise level of the
    second differences (:func:`estimators.statistics.difference_noise_std`), pooled over
    segments; 1 for an output never measured 4 times (never used for an update). Signal
    curvature and process noise between samples count as noise, so it errs high; with
    ``adapt_noise`` (default "auto") the filter adapts it pass by pass, else pass
    ``measurement_noise`` when the sensor noise is known."""
    sd = st.difference_noise_std([seg.z for seg in segments])
    return np.where(np.isfinite(sd), np.where(sd > 0, sd**2, 1e-12), 1.0)


def measurement_noise_matrix(model: Model, spec: Any, segments: Sequence[Segment]) -> np.ndarray:
    """R (n_out, n_out) from None (data default), {output: std}, (n_out,) std or a matrix."""
    m = len(model.outputs)
    if spec is not None and np.ndim(spec) == 2:
        R = np.asarray(spec, dtype=float)
        if R.shape != (m, m):
            raise ModelDefinitionError(f"measurement_noise matrix must be {m}x{m} (outputs {model.outputs})")
        return R
    var0 = default_measurement_noise(model, segments)
    if spec is None:
        return np.diag(var0)
    sd = named_vector(spec, model.outputs, "measurement_noise", np.sqrt(var0))
    return np.diag(sd**2)


def process_noise_start(model: Model, spec: Any, segments: Sequence[Segment]) -> tuple[list[int], np.ndarray]:
    """The filter-error method's process-noise start: (indices of the states with noise,
    F's diagonal (n,)) from None (:func:`default_process_noise`), a list of state names
    (:func:`named_process_noise`), {state: std} or a (n,) vector (0 = no noise on that
    state). Units: state unit per sqrt(s)."""
    n = len(model.states)
    if spec is None:
        f0 = default_process_noise(model, segments)
    elif is_name_list(spec):
        f0 = named_process_noise(model, spec, segments)
    elif isinstance(spec, Mapping):
        bad = sorted(set(spec) - set(model.states))
        if bad:
            raise ModelDefinitionError(f"process_noise: {bad} are not states {model.states}")
        f0 = np.array([float(spec.get(s, 0.0)) for s in model.states])
    else:
        f0 = np.asarray(spec, dtype=float).ravel()
        if f0.size != n:
            raise ModelDefinitionError(f"process_noise needs {n} entries (states {model.states})")
    noisy = [i for i in range(n) if f0[i] > 0]
    return noisy, f0


# -- noise adaptation (covariance matching) -----------------------------------------------------
#: adapt_noise values: "auto" adapts R when measurement_noise is not given
ADAPT_CHOICES = ("auto", True, False, "R", "Q")


class NoiseMatch:
    """Sums over one filter pass for covariance matching (Myers and Tapley).

    Measurement noise from the innovations nu and the a-priori output covariance
    H P- H^T = S - R: R_ii = mean(nu_i^2 - (S - R)_ii) (Mehra; one pass lands near the
    fixed point), and where that is not positive from the a-posteriori residuals
    r+ = R S^-1 nu and output covariance H P+ H^T = R - R S^-1 R:
    mean(r+_i^2 + (R - R S^-1 R)_ii) (Myers and Tapley; positive, but a small R only grows
    by a fraction of the mismatch per pass). Samples where output i is finite.
    Process noise, per state: the observed spread of the state corrections K_x nu against
    the spread the filter expects, K_x S K_x^T, per second of sample interval.
    """

    def __init__(self, n: int, n_out: int) -> None:
        self.r = np.zeros(n_out)
        self.r_post = np.zeros(n_out)
        self.nr = np.zeros(n_out)
        self.q_obs = np.zeros(n)
        self.q_exp = np.zeros(n)

    def add(self, nu: np.ndarray, S: np.ndarray, Kx: np.ndarray, R: np.ndarray, ok: np.ndarray, h: float) -> None:
        """One update: innovations nu (n_ok,), their covariance S, the state rows of the
        gain Kx (n, n_ok), the filter's R (n_out, n_out), finite mask ok, step h s (0 at
        a segment's first sample: no prediction preceded it)."""
        Rk = R[np.ix_(ok, ok)]
        RSi = np.linalg.solve(S, Rk).T  # R S^-1 (S, R symmetric)
        self.r[ok] += nu**2 - np.diag(S) + np.diag(Rk)
        self.r_post[ok] += (RSi @ nu) ** 2 + np.diag(Rk) - np.einsum("ij,ji->i", RSi, Rk)
        self.nr[ok] += 1.0
        if h > 0:
            self.q_obs += (Kx @ nu) ** 2 / h
            self.q_exp += np.einsum("ij,jk,ik->i", Kx, S, Kx) / h

    def add_sums(self, acc: np.ndarray, n_out: int) -> None:
        """A segment's sums as a compiled segment loop summed them: acc = [r, r_post, nr
        (n_out each), q_obs, q_exp (n each)] (:func:`estimators.filters.loops.book_update`)."""
        r, r_post, nr, rest = np.split(acc, [n_out, 2 * n_out, 3 * n_out])
        q_obs, q_exp = np.split(rest, 2)
        self.r += r
        self.r_post += r_post
        self.nr += nr
        self.q_obs += q_obs
        self.q_exp += q_exp


def matched_noise(
    F: np.ndarray, R: np.ndarray, match: NoiseMatch, adapt_r: bool, adapt_q: bool
) -> tuple[np.ndarray, np.ndarray, float]:
    """The noise for the next pass from one pass's sums: (F, R, largest relative change
    of a noise std). R's diagonal set to the matched variances (outputs never finite
    keep theirs); F's non-zero diagonal scaled by sqrt(observed / expected correction
    spread), the ratio held to [0.1, 10] per pass."""
    moves = [0.0]
    if adapt_r:
        d = np.diag(R).copy()
        seen = match.nr > 0
        cnt = np.maximum(match.nr, 1.0)
        new = np.where(match.r > 0, match.r, match.r_post) / cnt
        new = np.where(seen, np.maximum(new, 1e-12 * np.maximum(d, 1e-30)), d)
        moves += list(np.abs(np.sqrt(new[seen] / d[seen]) - 1.0))
        R = np.diag(new)
    if adapt_q:
        f = np.diag(F).copy()
        on = (f != 0) & (match.q_exp > 0)
        ratio = np.clip(match.q_obs[on] / match.q_exp[on], 0.1, 10.0)
        f[on] = f[on] * np.sqrt(ratio)
        moves += list(np.abs(np.sqrt(ratio) - 1.0))
        F = np.diag(f)
    return F, R, float(max(moves))
