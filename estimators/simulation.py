"""Batched simulation of a model over a segment.

Each segment reads its model parameter row ``P`` (n_params, B) and initial state ``X0``
(n_states, B) from a batch of parameter vectors ``Theta`` (B, n_all) laid out by
:class:`estimators.layout.Layout`, so B perturbed parameter sets simulate in one
integration.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from estimators.compile import kernel_for
from estimators.defaults import ATOL, RTOL
from estimators.errors import SimulationDivergedError
from estimators.integrators import DEFAULT_INPUTS
from estimators.layout import Layout, as_values
from estimators.model import Model, Segment


def simulate_batch(
    model: Model,
    seg: Segment,
    Theta: np.ndarray,
    layout: Layout,
    k: int,
    integrator: str = "rk4",
    rtol: float = RTOL,
    atol: float = ATOL,
    return_states: bool = False,
    inputs: str = DEFAULT_INPUTS,
):
    """Outputs Y (N, n_outputs, B) of segment ``k`` for parameter vectors Theta (B, n_all).
    Diverged trajectories carry NaN from the first non-finite sample on."""
    Theta = np.atleast_2d(Theta)
    P = np.ascontiguousarray(Theta[:, layout.pidx[k]].T)
    X0 = np.ascontiguousarray(Theta[:, layout.x0idx[k]].T)
    c = model.constants_for(seg)
    X = kernel_for(model).integrate(integrator, X0, seg.u, seg.t, P, c, rtol=rtol, atol=atol, inputs=inputs)
    with np.errstate(all="ignore"):
        Y = model.eval_g(X.transpose(1, 0, 2), seg.u.T[:, :, None], P, c)
    Y = Y.transpose(1, 0, 2)
    return (Y, X) if return_states else Y


def divergence_error(
    model: Model, seg: Segment, X: np.ndarray, k: int, what: str, hint: str
) -> SimulationDivergedError:
    """Build the message for a trajectory X (N, n) that went non-finite."""
    bad = ~np.isfinite(X)
    i = int(np.argmax(bad.any(axis=1)))
    j = int(np.argmax(bad[i])) if i > 0 else 0
    state = model.states[j]
    label = seg.name or str(k)
    return SimulationDivergedError(
        f"the simulation of segment {label} diverged at t={seg.t[i]:.4g} s (state {state!r} became non-finite) {what}. {hint}",
        segment=k,
        time=float(seg.t[i]),
        state=state,
    )


def simulate_outputs(
    model: Model,
    segment: Segment,
    params: Mapping[str, float] | pd.Series | None = None,
    integrator: str = "rk4",
    *,
    states: bool = False,
    k: int = 0,
    **kw,
) -> pd.DataFrame:
    """Simulate one segment; a DataFrame of outputs (and states when ``states``) on t.

    params : values by name, a mapping or a pandas Series (``res.params``), or None for
        the model's own. Model parameter names (``Cmq``; ``bias_az`` sets the segment's
        bias) and expanded names of segment ``k`` (``bias_az[k]``, ``x0_alpha[k]``) are
        read; an initial state not given comes from the segment (:meth:`Segment.initial_state`).
    k : the index of ``segment`` among the segments of the fit ``params`` come from:
        ``simulate_outputs(model, segs[k], res.params, k=k)`` reproduces
        ``res.predicted[k]`` of an :class:`~estimators.OutputError` fit (same integrator
        and ``inputs``). With the default 0 a multi-segment result's ``[0]`` values are
        used whatever the segment.
    Other keywords go to :func:`simulate_batch` (rtol, atol, inputs="linear"|"hold").
    """
    given = as_values(params)
    suffix = f"[{int(k)}]"
    # expanded names of segment k become those of this one-segment layout ([0])
    vals = {n: v for n, v in given.items() if not n.endswith("]")}
    vals.update({n[: -len(suffix)] + "[0]": v for n, v in given.items() if n.endswith(suffix)})
    for p in model.parameters:
        if p.per_segment and p.name in vals:
            vals[f"{p.name}[0]"] = vals.pop(p.name)
    lay = Layout.build(model, [segment], values=vals)
    Y, X = simulate_batch(model, segment, lay.values[None, :], lay, 0, integrator, return_states=True, **kw)
    df = pd.DataFrame(Y[:, :, 0], index=pd.Index(segment.t, name="t"), columns=model.outputs)
    if states:
        for i, s in enumerate(model.states):
            df[f"state_{s}" if s in df.columns else s] = X[:, i, 0]
    return df
