"""Output sensitivities of one segment, kept only for the parameters it depends on.

A fit of G maneuvers has the shared parameters plus each maneuver's own initial states
and biases; maneuver k's outputs depend on the shared ones and its own only. Stored dense,
the sensitivities of all maneuvers grow as G^2 (memory) and every product over them as
G^3 (time): with dozens of maneuvers, forming F = sum S^T R^-1 S would cost more than
simulating. :class:`Sensitivity` holds the columns a
segment depends on and where they sit among the free parameters; the sums scatter each
segment's block into place (:func:`add_block`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Sensitivity:
    """dy/dtheta of one segment: ``values`` (N, n_out, m) for the free parameters ``cols``
    (m,) (indices into the n_free free parameters, increasing); every other column is 0.
    ``np.asarray`` gives the dense (N, n_out, n_free) array."""

    values: np.ndarray
    cols: np.ndarray
    n_free: int

    @property
    def shape(self) -> tuple[int, int, int]:
        """(N, n_out, n_free), the shape of the dense array."""
        return (self.values.shape[0], self.values.shape[1], self.n_free)

    def dense(self) -> np.ndarray:
        """The (N, n_out, n_free) array, zeros in the columns the segment does not depend on."""
        out = np.zeros(self.shape)
        out[:, :, self.cols] = self.values
        return out

    @property
    def ndim(self) -> int:
        return 3

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        d = self.dense()
        return d if dtype is None else d.astype(dtype)

    def __getitem__(self, key: Any) -> np.ndarray:
        """Indexing as the dense array (``S[:, :, i]``, ``S[n]``): code written for the
        (N, n_out, n_free) arrays reads the same values (the dense array is formed)."""
        return self.dense()[key]

    def take(self, idx: np.ndarray) -> Sensitivity:
        """The sensitivities to the free parameters ``idx`` (increasing), numbered 0..len(idx)-1."""
        idx = np.asarray(idx, dtype=int)
        keep = np.isin(self.cols, idx)
        return Sensitivity(self.values[:, :, keep], np.searchsorted(idx, self.cols[keep]), int(idx.size))


def as_sensitivity(S: Any) -> Sensitivity:
    """A :class:`Sensitivity` as it is, or a dense (N, n_out, n_p) array (all columns;
    (N, n_p) is one output) as one."""
    if isinstance(S, Sensitivity):
        return S
    S = np.asarray(S, dtype=float)
    if S.ndim == 2:
        S = S[:, None, :]
    if S.ndim != 3:
        raise ValueError(f"sensitivities must be (N, n_out, n_p); got shape {S.shape}")
    return Sensitivity(S, np.arange(S.shape[2]), int(S.shape[2]))


def add_block(M: np.ndarray, cols: np.ndarray, block: np.ndarray) -> None:
    """M[cols, cols] += block (M (n_p, n_p) in place; block (m, m)), or M[cols] += block
    for a vector."""
    if M.ndim == 1:
        M[cols] += block
    else:
        M[np.ix_(cols, cols)] += block
