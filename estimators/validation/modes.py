"""Modes of a linear(ised) model: eigenvalues named short period / phugoid / Dutch roll /
roll / spiral, with damping, natural frequency, period and time to half or double
amplitude; eigenvectors; and a numerical linearisation of a vectorised model.

Naming uses the state names (canonical channels of DESIGN.md section 3): longitudinal
states {V, u, w, alpha, q, theta, h, vn, vd, x, z}, lateral-directional states
{v, beta, p, r, phi, psi, ve, y}. Each eigenvector's content (squared magnitudes, after
optional per-state scaling) decides its axis; within an axis:

* longitudinal oscillatory pairs: the highest natural frequency is the short period, the
  lowest the phugoid (one pair only: short period when no speed state is present or the
  angle-of-attack content is comparable to the pitch-attitude content, else phugoid);
  longitudinal real roots: near-zero with height content -> "height"; the others are
  the real form of whichever of short period / phugoid is not oscillatory (with neither
  oscillatory: the two fastest are "short period (real)", the rest "phugoid (real)"),
  e.g. the divergent root of a statically unstable aircraft is "short period (real)";
* lateral oscillatory pair: Dutch roll; lateral real roots: near-zero with heading content
  -> "heading", the fastest remaining -> roll, the slowest -> spiral.
Anything else is called "longitudinal"/"lateral"/"other" with its index.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from estimators.defaults import LINEARIZE_STEP, MODE_ZERO_TOL

__all__ = ["LONGITUDINAL", "LATERAL", "ModeAnalysis", "mode_properties", "modes", "linearize"]

LONGITUDINAL = frozenset({"V", "u", "w", "alpha", "q", "theta", "h", "vn", "vd", "x", "z"})
LATERAL = frozenset({"v", "beta", "p", "r", "phi", "psi", "ve", "y"})
_SPEED = {"V", "u", "vn", "vd"}


def mode_properties(eigenvalues) -> pd.DataFrame:
    """Characteristics of eigenvalues lambda = sigma + j omega (1/s), one row each.

    Columns: ``real`` sigma (1/s), ``imag`` omega (rad/s), ``wn`` natural frequency
    |lambda| (rad/s), ``zeta`` damping -sigma/|lambda| (for real roots +1 stable, -1
    unstable), ``period`` 2 pi/|omega| (s, inf for real roots), ``t_half`` ln2/(-sigma)
    (s, NaN unless stable), ``t_double`` ln2/sigma (s, NaN unless unstable),
    ``time_constant`` 1/|sigma| (s), ``stable`` (sigma < 0).
    """
    lam = np.atleast_1d(np.asarray(eigenvalues, dtype=complex))
    s, w = lam.real, lam.imag
    wn = np.abs(lam)
    with np.errstate(invalid="ignore", divide="ignore"):
        zeta = np.where(wn > 0, -s / wn, np.nan)
        period = np.where(w != 0, 2 * np.pi / np.abs(w), np.inf)
        t_half = np.where(s < 0, np.log(2) / -s, np.nan)
        t_double = np.where(s > 0, np.log(2) / s, np.nan)
        tc = np.where(s != 0, 1.0 / np.abs(s), np.inf)
    return pd.DataFrame(
        {
            "real": s,
            "imag": w,
            "wn": wn,
            "zeta": zeta,
            "period": period,
            "t_half": t_half,
            "t_double": t_double,
            "time_constant": tc,
            "stable": s < 0,
        }
    )


@dataclass(frozen=True)
class ModeAnalysis:
    """Result of :func:`modes`.

    ``table``: one row per mode (a complex pair is one row, the eigenvalue with positive
    imaginary part), index the mode name, columns ``eigenvalue`` plus those of
    :func:`mode_properties` and ``axis``. ``eigenvalues``: all n eigenvalues (complex,
    (n,)); ``eigenvectors``: DataFrame (states x mode name) of the complex eigenvectors
    normalised to unit length with the largest component real positive;
    ``eigenvector_magnitude``: its absolute values.
    """

    table: pd.DataFrame
    eigenvalues: np.ndarray
    eigenvectors: pd.DataFrame

    @property
    def eigenvector_magnitude(self) -> pd.DataFrame:
        return self.eigenvectors.abs()


@dataclass(frozen=True)
class _Roots:
    """The eigen-decomposition :func:`modes` names: eigenvalues ``lam`` (n,), each
    eigenvector's content per state ``content`` (n_states, n) (columns sum to 1), the
    state index ``ix``, the representative roots ``reps`` (real ones, and of each complex
    pair the one with positive imaginary part), their ``axis`` and the oscillatory ones
    ``osc``; |lambda| below ``zero_tol`` counts as zero."""

    lam: np.ndarray
    content: np.ndarray
    ix: dict[str, int]
    reps: list[int]
    axis: dict[int, str]
    osc: set[int]
    zero_tol: float

    def share(self, j: int, names) -> float:
        """The content of root j in the states ``names`` (those present)."""
        return float(sum(self.content[self.ix[s], j] for s in names if s in self.ix))

    def of_axis(self, axis: str, oscillatory: bool) -> list[int]:
        return [j for j in self.reps if self.axis[j] == axis and (j in self.osc) == oscillatory]


def _roots(A: np.ndarray, states: list[str], scales: Mapping[str, float] | None, zero_tol: float):
    """(:class:`_Roots`, eigenvectors (n, n)) of A with each root's axis decided by its
    eigenvector content (scaled per state by ``scales``)."""
    lam, vec = np.linalg.eig(A)
    lam, vec = lam.astype(complex), vec.astype(complex)
    scale = np.array([float((scales or {}).get(s, 1.0)) for s in states])
    content = np.abs(vec / scale[:, None]) ** 2
    content /= content.sum(axis=0, keepdims=True)
    ix = {s: i for i, s in enumerate(states)}
    tol_im = 1e-9 * max(1.0, float(np.abs(lam).max(initial=0.0)))
    reps = [j for j in range(len(lam)) if lam[j].imag > tol_im or abs(lam[j].imag) <= tol_im]
    axis = {}
    for j in reps:
        lon = float(sum(content[ix[s], j] for s in LONGITUDINAL if s in ix))
        lat = float(sum(content[ix[s], j] for s in LATERAL if s in ix))
        axis[j] = "other" if lon + lat < 0.5 else ("longitudinal" if lon >= lat else "lateral")
    osc = {j for j in reps if abs(lam[j].imag) > tol_im}
    return _Roots(lam, content, ix, reps, axis, osc, zero_tol), vec


def _longitudinal_names(r: _Roots) -> dict[int, str]:
    """Names of the longitudinal roots (see the module docstring)."""
    lam, content, ix = r.lam, r.content, r.ix
    name: dict[int, str] = {}
    lon_osc = sorted(r.of_axis("longitudinal", True), key=lambda j: abs(lam[j]))
    has_speed = any(s in ix for s in _SPEED)
    if len(lon_osc) >= 2:
        name[lon_osc[-1]], name[lon_osc[0]] = "short period", "phugoid"
    elif len(lon_osc) == 1:
        j = lon_osc[0]
        if not has_speed:
            name[j] = "short period"
        elif "alpha" in ix and "theta" in ix:
            name[j] = "short period" if content[ix["alpha"], j] > 0.25 * content[ix["theta"], j] else "phugoid"
        else:
            name[j] = "short period" if abs(lam[j]) > 1.0 else "phugoid"
    lon_real = r.of_axis("longitudinal", False)
    for j in list(lon_real):
        if abs(lam[j]) < r.zero_tol and r.share(j, {"h", "z"}) > 0.5:
            name[j] = "height"
            lon_real.remove(j)
    lon_real.sort(key=lambda j: -abs(lam[j]))
    named = set(name.values())
    if "short period" in named and "phugoid" not in named:
        kinds = ["phugoid (real)"] * len(lon_real)
    elif "phugoid" in named and "short period" not in named:
        kinds = ["short period (real)"] * len(lon_real)
    elif not named & {"short period", "phugoid"}:
        n_sp = 2 if has_speed else len(lon_real)  # the two fastest real roots
        kinds = ["short period (real)" if i < n_sp else "phugoid (real)" for i in range(len(lon_real))]
    else:
        kinds = ["longitudinal"] * len(lon_real)
    name.update(zip(lon_real, kinds))
    return name


def _lateral_names(r: _Roots) -> dict[int, str]:
    """Names of the lateral-directional roots (see the module docstring)."""
    lam = r.lam
    name: dict[int, str] = {}
    lat_osc = sorted(r.of_axis("lateral", True), key=lambda j: -abs(lam[j]))
    if lat_osc:
        name[lat_osc[0]] = "Dutch roll"
    lat_real = r.of_axis("lateral", False)
    for j in list(lat_real):
        if abs(lam[j]) < r.zero_tol and r.share(j, {"psi", "y"}) > 0.5:
            name[j] = "heading"
            lat_real.remove(j)
    lat_real.sort(key=lambda j: -abs(lam[j]))
    if len(lat_real) >= 2:
        name[lat_real[0]], name[lat_real[-1]] = "roll", "spiral"
    elif len(lat_real) == 1:
        j = lat_real[0]
        name[j] = "roll" if r.share(j, {"p"}) >= r.share(j, {"phi"}) else "spiral"
    return name


def _numbered(r: _Roots, name: dict[int, str]) -> dict[int, str]:
    """``name`` with unnamed roots named after their axis and repeated names numbered
    (fastest first)."""
    for j in r.reps:
        name.setdefault(j, r.axis[j])
    counts = pd.Series([name[j] for j in r.reps]).value_counts()
    k_of: dict[str, int] = {}
    for j in sorted(r.reps, key=lambda j: -abs(r.lam[j])):
        if counts[name[j]] > 1:
            k_of[name[j]] = k_of.get(name[j], 0) + 1
            name[j] = f"{name[j]} {k_of[name[j]]}"
    return name


def modes(
    A, states: Sequence[str], *, scales: Mapping[str, float] | None = None, zero_tol: float = MODE_ZERO_TOL
) -> ModeAnalysis:
    """Eigen-analysis of a state matrix A (n, n) (1/s) with named states, modes named.

    scales: optional divisor per state for the eigenvector content used in naming (e.g.
    {"V": 50.0} to compare a speed in m/s with angles in rad); states absent count as 1.
    zero_tol: |lambda| below which a root counts as zero (1/s).
    """
    A = np.asarray(A, dtype=float)
    states = list(states)
    n = A.shape[0]
    if A.shape != (n, n) or len(states) != n:
        raise ValueError(f"A must be square with one name per state; got {A.shape}, {len(states)} names")
    r, vec = _roots(A, states, scales, zero_tol)
    name = _longitudinal_names(r)
    name.update(_lateral_names(r))
    name = _numbered(r, name)

    order = sorted(r.reps, key=lambda j: (r.axis[j] != "longitudinal", -abs(r.lam[j])))
    props = mode_properties(r.lam[order])
    props.insert(0, "eigenvalue", r.lam[order])
    props["axis"] = [r.axis[j] for j in order]
    props.index = pd.Index([name[j] for j in order], name="mode")

    v = vec[:, order]
    big = np.argmax(np.abs(v), axis=0)
    v = v * np.exp(-1j * np.angle(v[big, np.arange(v.shape[1])]))
    v /= np.linalg.norm(v, axis=0)
    ev = pd.DataFrame(v, index=pd.Index(states, name="state"), columns=props.index)
    return ModeAnalysis(table=props, eigenvalues=r.lam, eigenvectors=ev)


def _stack(out, trailing: tuple[int, ...]) -> np.ndarray:
    if isinstance(out, np.ndarray) and out.ndim == 1 + len(trailing) and out.shape[1:] == trailing:
        return out.astype(float)
    return np.stack([np.broadcast_to(np.asarray(o, dtype=float), trailing) for o in out])


def linearize(
    f: Callable[..., Any], x0, u0, p, c, *, rel_step: float = LINEARIZE_STEP, abs_step: float = LINEARIZE_STEP
) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of a vectorised f(x, u, p, c) at (x0, u0) by central differences.

    f follows the estimators model convention: x (n_x, ...), u (n_u, ...), returns a tuple
    or an array stacked on axis 0; all 2 (n_x + n_u) perturbed points go in ONE call with
    trailing dimension 2 (n_x + n_u). p, c are passed through unchanged (they must
    broadcast against the trailing dimension, as scalars do).
    Step per variable: max(abs_step, rel_step |value|).
    Returns (A, B) = (df/dx (n_f, n_x), df/du (n_f, n_u)). Applied to the observation
    function g it returns (C, D).
    """
    x0 = np.asarray(x0, dtype=float).ravel()
    u0 = np.asarray(u0, dtype=float).ravel()
    nx, nu = x0.size, u0.size
    z0 = np.concatenate([x0, u0])
    h = np.maximum(abs_step, rel_step * np.abs(z0))
    m = nx + nu
    Z = np.repeat(z0[:, None], 2 * m, axis=1)
    idx = np.arange(m)
    Z[idx, idx] += h
    Z[idx, m + idx] -= h
    F = _stack(f(Z[:nx], Z[nx:], p, c), (2 * m,))
    J = (F[:, :m] - F[:, m:]) / (2 * h)
    return J[:, :nx], J[:, nx:]
