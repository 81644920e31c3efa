"""The parameter vector of a model over several segments.

The *layout* expands a model's parameters for a list of segments into one vector:
shared system parameters (``Cmq``), per-segment parameters (``bias_az[k]``) and, when
requested, per-segment initial states (``x0_alpha[k]``). Every estimator works on this
vector; segment k reads its model parameters and initial state from it by index
(``pidx[k]``, ``x0idx[k]``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from estimators.errors import ModelDefinitionError
from estimators.model import Model, Segment, check_in_bounds


def as_values(values: Mapping[str, float] | pd.Series | None) -> dict[str, float]:
    """Parameter values by name as a dict from a mapping, a pandas Series or None (a
    Series has no single truth value, so ``if values:`` cannot test it)."""
    if values is None:
        return {}
    if not hasattr(values, "items"):
        raise ModelDefinitionError(
            f"parameter values must map names to numbers (a dict or a pandas Series), not {type(values).__name__}"
        )
    return dict(values.items())


@dataclass
class Layout:
    """Expanded parameter vector for a model over segments.

    names (n_all,), values (n_all,), free (n_all,) bool, lower/upper (n_all,),
    pidx[k] (n_params,) and x0idx[k] (n_states,) index into the vector for segment k,
    relevant[k] the free indices segment k depends on.
    """

    names: list[str]
    values: np.ndarray
    free: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    kind: list[str]
    pidx: list[np.ndarray]
    x0idx: list[np.ndarray]
    relevant: list[np.ndarray]

    @classmethod
    def build(
        cls,
        model: Model,
        segments: Sequence[Segment],
        estimate_x0: bool | str | Sequence[str] = False,
        values: Mapping[str, float] | None = None,
    ) -> Layout:
        """``estimate_x0``: False, True, state names, or "auto" (the measured states of
        the segments that have no ``x0`` of their own; see OutputError.fit). ``values``:
        start values by expanded name, a mapping or a pandas Series (a result's
        ``params``), or None. Every estimator builds its layout here, so a segment with a
        gap in its time (:meth:`Segment.check_no_gaps`) is refused here for all of them."""
        nseg = len(segments)
        auto = isinstance(estimate_x0, str) and estimate_x0 == "auto"
        if auto:
            est = {s for s in model.states if s in model.outputs}
        elif isinstance(estimate_x0, str):
            raise ModelDefinitionError(f"estimate_x0={estimate_x0!r}: use True, False, 'auto' or a list of states")
        elif estimate_x0 is True:
            est = set(model.states)
        elif not estimate_x0:
            est = set()
        else:
            est = set(estimate_x0)
            bad = est - set(model.states)
            if bad:
                raise ModelDefinitionError(f"estimate_x0 names {sorted(bad)} are not states {model.states}")
        names, vals, free, lo, hi, kind = [], [], [], [], [], []

        def add(name, v, fr, b, k):
            names.append(name)
            vals.append(v)
            free.append(fr)
            lo.append(b[0])
            hi.append(b[1])
            kind.append(k)
            return len(names) - 1

        shared: dict[str, int] = {}
        for p in model.parameters:
            if not p.per_segment:
                shared[p.name] = add(p.name, p.value, p.free, p.bounds, "system")
        pidx, x0idx = [], []
        for k, seg in enumerate(segments):
            seg.check_against(model)
            seg.check_no_gaps(k)
            row = []
            for p in model.parameters:
                if p.per_segment:
                    row.append(add(f"{p.name}[{k}]", p.value, p.free, p.bounds, "segment"))
                else:
                    row.append(shared[p.name])
            pidx.append(np.array(row, dtype=int))
            x0 = seg.initial_state(model)
            est_k = est if not auto or seg.x0 is None else set()
            x0idx.append(
                np.array(
                    [
                        add(f"x0_{s}[{k}]", x0[i], s in est_k, (-np.inf, np.inf), "x0")
                        for i, s in enumerate(model.states)
                    ],
                    dtype=int,
                )
            )
        values_arr = np.array(vals, dtype=float)
        given = as_values(values)
        for i, n in enumerate(names):
            if n in given:
                values_arr[i] = float(given[n])
        free_arr = np.array(free, dtype=bool)
        relevant = []
        for k in range(nseg):
            used = np.zeros(len(names), dtype=bool)
            used[pidx[k]] = True
            used[x0idx[k]] = True
            relevant.append(np.flatnonzero(used & free_arr))
        lay = cls(names, values_arr, free_arr, np.array(lo), np.array(hi), kind, pidx, x0idx, relevant)
        for i in np.flatnonzero(free_arr):
            check_in_bounds(names[i], values_arr[i], lo[i], hi[i])
        return lay

    @property
    def free_idx(self) -> np.ndarray:
        return np.flatnonzero(self.free)

    @property
    def free_names(self) -> list[str]:
        return [self.names[i] for i in self.free_idx]
