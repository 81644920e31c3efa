"""Shared helpers of the validation package: array coercion and output names."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd


def _is_segment_list(a) -> bool:
    return (
        isinstance(a, (list, tuple))
        and len(a) > 0
        and all(isinstance(x, (np.ndarray, pd.DataFrame, pd.Series)) and np.ndim(x) >= 1 for x in a)
    )


def as_2d(a, name: str = "array") -> np.ndarray:
    """Return ``a`` as a float array of shape (N, n_out); 1-D input becomes (N, 1).

    pandas objects are accepted (their values are used); a list of per-segment arrays or
    DataFrames is concatenated along time.
    """
    if _is_segment_list(a):
        return np.concatenate([as_2d(x, name) for x in a], axis=0)
    arr = np.asarray(a.to_numpy() if isinstance(a, (pd.DataFrame, pd.Series)) else a, dtype=float)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise ValueError(f"{name} must have shape (N,) or (N, n_out), got {arr.shape}")
    return arr


def output_names(names: Sequence[str] | None, n: int, *arrays) -> list[str]:
    """Names for ``n`` outputs: the given ones, else DataFrame columns, else y0, y1, ..."""
    if names is not None:
        names = list(names)
        if len(names) != n:
            raise ValueError(f"got {len(names)} names for {n} outputs")
        return names
    for a in arrays:
        if _is_segment_list(a):
            a = a[0]
        if isinstance(a, pd.DataFrame):
            return [str(c) for c in a.columns]
        if isinstance(a, pd.Series) and a.name is not None:
            return [str(a.name)]
    return [f"y{i}" for i in range(n)]


def fill_missing(x: np.ndarray) -> np.ndarray:
    """Columns of x (N, n) with NaN samples (multi-rate channels) filled by linear
    interpolation over the present ones (nearest at the ends): for spectral estimates,
    which need a uniform record. All-NaN columns stay NaN."""
    x = np.array(x, dtype=float, copy=True)
    if not np.isnan(x).any():
        return x
    i = np.arange(x.shape[0])
    for k in range(x.shape[1]):
        ok = np.isfinite(x[:, k])
        if ok.any() and not ok.all():
            x[~ok, k] = np.interp(i[~ok], i[ok], x[ok, k])
    return x
