"""The parameter-augmented system of one segment, s = [x; theta_free], evaluated in
batches of columns: the EKF's difference columns, the UKF's sigma points."""

from __future__ import annotations

import numpy as np

from estimators.compile import kernel_for
from estimators.filters.kernels import output_kernel
from estimators.integrators import DEFAULT_INPUTS
from estimators.layout import Layout
from estimators.model import Model, Segment


class AugmentedModel:
    """Batched evaluation of the parameter-augmented system for one segment.

    Columns of S (n + m, B) are augmented states [x; theta_free]; ``step`` advances the
    x part over one sample interval with the package integrator, ``outputs`` evaluates g.
    ``gout`` and ``c_compiled`` are g and the constants of the model's filter kernel module
    (None when g does not compile), ``u`` the segment's inputs (N, n_in), contiguous.
    """

    def __init__(
        self,
        model: Model,
        layout: Layout,
        seg: Segment,
        k: int,
        integrator: str,
        rtol: float = 1e-8,
        atol: float = 1e-10,
        inputs: str = DEFAULT_INPUTS,
    ) -> None:
        self.model, self.lay, self.seg, self.k = model, layout, seg, k
        self.integrator = integrator
        self.n = len(model.states)
        self.fi = layout.free_idx
        self.lo, self.hi = layout.lower[self.fi][:, None], layout.upper[self.fi][:, None]
        self.c = model.constants_for(seg)
        self.kernel = kernel_for(model)
        self.rtol, self.atol = rtol, atol
        self.inputs = inputs
        # g compiled when the model allows (the filter kernel module's gout), else numpy
        gk = output_kernel(model) if self.kernel.prepare() else None
        self.gout = None if gk is None else gk.gout
        self.c_compiled = None if gk is None else self.kernel._c_jit(self.c)
        self.u = np.ascontiguousarray(seg.u, dtype=float)

    def params(self, S: np.ndarray) -> np.ndarray:
        """Model parameter matrix P (n_params, B) for augmented columns S, the free
        parameters held to their bounds (a sigma point or a difference step beyond a bound
        sees the model at the bound)."""
        B = S.shape[1]
        Theta = np.repeat(self.lay.values[:, None], B, axis=1)
        Theta[self.fi] = np.clip(S[self.n :], self.lo, self.hi)
        return Theta[self.lay.pidx[self.k]]

    def step(self, S: np.ndarray, i: int) -> np.ndarray:
        """x part of S advanced from sample i to i+1 (n, B); theta unchanged."""
        seg = self.seg
        X = self.kernel.integrate(
            self.integrator,
            S[: self.n],
            seg.u[i : i + 2],
            seg.t[i : i + 2],
            self.params(S),
            self.c,
            rtol=self.rtol,
            atol=self.atol,
            inputs=self.inputs,
        )
        return X[1]

    def outputs(self, S: np.ndarray, i: int) -> np.ndarray:
        """g at sample i for the augmented columns S: (n_out, B)."""
        if self.gout is not None:
            Y = np.empty((len(self.model.outputs), S.shape[1]))
            self.gout(np.ascontiguousarray(S[: self.n]), self.u[i], self.params(S), self.c_compiled, Y)
            return Y
        u = self.seg.u[i][:, None, None]
        with np.errstate(all="ignore"):
            Y = self.model.eval_g(S[: self.n, None, :], u, self.params(S), self.c)
        return Y[:, 0, :]

    def outputs_along(self, S: np.ndarray) -> np.ndarray:
        """g along a trajectory of augmented states S (N, n+m): (N, n_out)."""
        P = self.params(S.T)  # (n_p, N)
        X = S[:, : self.n].T[:, None, :]  # (n, 1, N)
        U = self.seg.u.T[:, None, :]  # (n_in, 1, N)
        with np.errstate(all="ignore"):
            return self.model.eval_g(X, U, P, self.c)[:, 0, :].T
