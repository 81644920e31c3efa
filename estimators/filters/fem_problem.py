"""One filter-error fit's problem: the data, the parameter vector phi = [free model
parameters, process-noise std F_i] and the steady-state filter run over every segment for
a batch of phi columns, with its costs (det R of the innovations, and the weighted
innovations for a fixed R).

Per segment and column the model is linearised about the segment's start
(:func:`~estimators.filters.linearize.linearize_batch`), the steady-state gain solved
from the continuous Riccati equation (:func:`~estimators.filters.steady_state.continuous_gain`,
the reference software's; ``gain="discrete"``: the sampled filter's,
:func:`~estimators.filters.steady_state.discrete_gain`) and the filter run: with the integrator's prediction and the
model's g (``form="nonlinear"``, the default for linear and nonlinear models alike,
compiled in the model's filter kernel module or with numpy) or with the transition matrix
and the input integrals (``form="linear"``, :func:`~estimators.filters.loops.kf_loop`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from estimators import statistics as st
from estimators.compile import kernel_for
from estimators.errors import DependentOutputsError, ModelDefinitionError, SimulationDivergedError
from estimators.filters.kernels import output_kernel
from estimators.filters.linearize import linearize_batch
from estimators.filters.loops import kf_loop_jit
from estimators.filters.steady_state import continuous_gain, discrete_gain, input_integrals, pattern_gains
from estimators.integrators import INPUT_MODES
from estimators.layout import Layout
from estimators.model import Model, Segment

#: largest deviation of a sample interval from the segment's median interval (relative)
#: that the filter-error method accepts: the steady-state gain, and in the linear form the
#: transition matrices, are those of the median interval
JITTER_TOL = 0.05


def sample_interval(seg: Segment, k: int = 0) -> float:
    """The segment's sample interval h (s): the median of its intervals, which may deviate
    from it by up to JITTER_TOL (timestamp jitter of a logger); larger deviations (gaps,
    rate changes, time going backwards) raise ModelDefinitionError saying where."""
    dt = np.diff(seg.t)
    h = float(np.median(dt))
    dev = np.abs(dt - h) / h if h > 0 else np.full(dt.shape, np.inf)
    if dt.size and dev.max() > JITTER_TOL:
        i = int(np.argmax(dev))
        raise ModelDefinitionError(
            f"segment {seg.name or k}: the filter-error method needs a constant sample interval; "
            f"at t={seg.t[i]:.6g} s the step is {dt[i]:.6g} s against a median of {h:.6g} s "
            f"({dev[i]:.0%} off, {JITTER_TOL:.0%} accepted): resample the data to a constant "
            f"rate, or split the segment there (Segment.split_at_gaps(factor={1 + JITTER_TOL:g})) "
            "and fit the pieces as a list of segments"
        )
    return h


#: fraction of an output's variance left by its least-squares fit on the other outputs and
#: the inputs under which it counts as their exact function (measurement noise leaves far
#: more; outputs computed from others, as angular accelerations often are, leave rounding)
DEPENDENT_OUTPUT_TOL = 1e-6


def dependent_outputs(model: Model, segments: Sequence[Segment]) -> list[str]:
    """The measured outputs that are, to :data:`DEPENDENT_OUTPUT_TOL` of their variance,
    affine functions of the other outputs and the inputs over the samples where every
    output is measured (all segments, each with its own offset)."""
    names = list(model.outputs)
    m = len(names)
    Z, X = [], []
    for k, seg in enumerate(segments):
        ok = np.all(np.isfinite(seg.z), axis=1) & np.all(np.isfinite(seg.u), axis=1)
        Z.append(seg.z[ok])
        ones = np.zeros((int(ok.sum()), len(segments)))
        ones[:, k] = 1.0
        X.append(np.hstack([seg.u[ok], ones]))
    Z, X = np.vstack(Z), np.vstack(X)
    if Z.shape[0] <= Z.shape[1] + X.shape[1]:
        return []
    out = []
    for i in range(m):
        zi = Z[:, i] - Z[:, i].mean()
        var = float(zi @ zi)
        if var <= 0.0:
            continue
        A = np.hstack([np.delete(Z, i, axis=1), X])
        A = A / np.maximum(np.abs(A).max(axis=0), 1e-300)
        coef = np.linalg.lstsq(A, Z[:, i], rcond=None)[0]
        r = Z[:, i] - A @ coef
        if float(r @ r) < DEPENDENT_OUTPUT_TOL * var:
            out.append(names[i])
    return out


def check_full_R(model: Model, segments: Sequence[Segment]) -> None:
    """Refuse a full innovation covariance when an output is an exact function of the
    others (:func:`dependent_outputs`): its determinant then goes to zero at the cost of
    every other term of the likelihood."""
    dep = dependent_outputs(model, segments)
    if dep:
        raise DependentOutputsError(
            f"full_R: the measured outputs {', '.join(dep)} are exact functions of the other outputs "
            f"and the inputs (less than {DEPENDENT_OUTPUT_TOL:g} of their variance left by a linear fit), "
            "so the determinant of a full innovation covariance can be driven to zero: use the "
            "diagonal one (full_R=False, the default) or leave those outputs out",
            outputs=dep,
        )


@dataclass
class SegmentFilter:
    """The filter run of one segment for a batch of Bc phi columns (column 0 the base):
    predicted outputs Y (Bc, N, m), steady-state gain K (Bc, n, m) and covariance
    P (Bc, n, n), filtered states X (Bc, N, n), the constrained diagonal CK (diag(K C),
    (Bc, n); with a full R diag(C K), (Bc, m)), the output matrix C
    (Bc, m, n) and the linearisation (A, B, C, D) of column 0."""

    Y: np.ndarray
    K: np.ndarray
    P: np.ndarray
    X: np.ndarray
    CK: np.ndarray
    C: np.ndarray
    lin: tuple


@dataclass
class FemProblem:
    """The data and settings of one filter-error fit.

    ``noisy``: the states with process noise; ``f_fixed`` (n,) the std of F where it is not
    estimated (and the start where it is); ``names``, ``lo``, ``hi`` the names and bounds of
    phi; ``floor`` (n_phi,) the finite-difference floor (1 for model parameters, the start
    for F); ``h`` the sample interval and ``patterns`` the patterns of measured outputs
    (:func:`~estimators.filters.steady_state.output_patterns`) per segment.
    """

    model: Model
    segments: list[Segment]
    lay: Layout
    form: str
    integrator: str
    inputs: str
    compiled: bool
    full_R: bool
    gain: str
    estimate_F: bool
    fd_step: float
    h: list[float]
    patterns: list[tuple[np.ndarray, np.ndarray]]
    noisy: list[int]
    f_fixed: np.ndarray
    names: list[str]
    lo: np.ndarray
    hi: np.ndarray
    floor: np.ndarray

    @property
    def n_samples(self) -> int:
        """Samples over every segment."""
        return int(sum(seg.n for seg in self.segments))

    def unpack(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """theta (n_all,) and F (n, n) from phi (free vector)."""
        theta = self.lay.values.copy()
        nf = self.lay.free_idx.size
        theta[self.lay.free_idx] = phi[:nf]
        fvec = self.f_fixed.copy()
        if self.estimate_F:
            fvec[self.noisy] = np.maximum(phi[nf : nf + len(self.noisy)], 0.0)
        return theta, np.diag(fvec)

    def filter(
        self, Phis: np.ndarray, R: np.ndarray, rows: Sequence[np.ndarray] | None = None, gain: bool = True
    ) -> list[SegmentFilter]:
        """For parameter columns Phis (Bc, n_phi) and innovation covariance R (m, m): per
        segment the predicted outputs Y (Bc_k, N, m), gain K (Bc_k, n, m), P, diag(K C)
        (Bc_k, n), filtered states and the linearisation of column 0. ``rows``: per segment
        the columns of Phis to run (column 0 first; default all): a sensitivity batch needs
        only the parameters the segment depends on (:meth:`segment_rows`). ``gain`` False
        runs without a gain (K = 0: the output-error simulation)."""
        model = self.model
        n, m = len(model.states), len(model.outputs)
        unpacked = [self.unpack(p) for p in Phis]
        Theta_all = np.stack([u[0] for u in unpacked])
        FF_all = np.stack([u[1] @ u[1].T for u in unpacked])
        if not gain:
            FF_all[:] = 0.0
        out = []
        for k, seg in enumerate(self.segments):
            idx = np.arange(Phis.shape[0]) if rows is None else rows[k]
            Bc = idx.size
            Theta = Theta_all[idx]
            lay = self.lay
            P = np.ascontiguousarray(Theta[:, lay.pidx[k]].T)
            X0 = np.ascontiguousarray(Theta[:, lay.x0idx[k]].T)
            c = model.constants_for(seg)
            A, Bu, C, D, f0, y0 = linearize_batch(model, P, X0, seg.u[0], c)
            h = self.h[k]
            with np.errstate(all="ignore"):
                Pp, Kg = (discrete_gain if self.gain == "discrete" else continuous_gain)(A, C, FF_all[idx], R, h)
            ok = np.all(np.isfinite(Kg.reshape(Bc, -1)), axis=1)
            Z = np.ascontiguousarray(seg.z)
            masks, pat = self.patterns[k]
            Kp = pattern_gains(Pp, C, np.repeat(R[None], Bc, axis=0), Kg, masks)
            if self.form == "linear":
                Y = np.full((Bc, seg.n, m), np.nan)
                Xf = np.full((Bc, seg.n, n), np.nan)
                drive = np.empty((Bc, seg.n, n))
                Phi = np.empty((Bc, n, n))
                du = np.vstack([np.diff(seg.u, axis=0), np.zeros((1, seg.u.shape[1]))])
                for b in range(Bc):
                    Phi[b], G0, G1 = input_integrals(A[b], h)
                    drive[b] = (Bu[b] @ seg.u.T + f0[b][:, None]).T @ G0.T
                    if self.inputs == "linear":
                        drive[b] += (Bu[b] @ du.T).T @ G1.T
                offset = np.einsum("bij,nj->bni", D, seg.u) + y0[:, None, :]
                if np.any(ok):
                    Y[ok], Xf[ok] = kf_loop_jit(
                        np.ascontiguousarray(Phi[ok]),
                        np.ascontiguousarray(Kp[ok]),
                        pat,
                        np.ascontiguousarray(C[ok]),
                        np.ascontiguousarray(drive[ok]),
                        np.ascontiguousarray(offset[ok]),
                        Z,
                        np.ascontiguousarray(X0.T[ok]),
                    )
            else:
                Y, Xf = self._nonlinear_loop(seg, P, X0, Kg, Kp, pat, c)
            # the constraint: diag(K C) <= 1 on the states (the reference's), or with the
            # full R of the likelihood diag(C K) <= 1 on the outputs (the implied
            # measurement noise R - C P C^T non-negative)
            CK = np.einsum("bij,bji->bi", C, Kg) if self.full_R else np.einsum("bij,bji->bi", Kg, C)
            out.append(SegmentFilter(Y=Y, K=Kg, P=Pp, X=Xf, CK=CK, C=C, lin=(A[0], Bu[0], C[0], D[0])))
        return out

    def _nonlinear_loop(
        self,
        seg: Segment,
        P: np.ndarray,
        X0: np.ndarray,
        Kg: np.ndarray,
        Kp: np.ndarray,
        pat: np.ndarray,
        c: Mapping[str, float],
    ):
        """Integrator prediction and nonlinear outputs, constant gain per pattern of measured
        outputs (Kp (Bc, n_pat, n, m), pat (N,); Kg the full gain, NaN where the Riccati
        equation failed), batched over columns."""
        model = self.model
        kern = kernel_for(model)
        Bc = X0.shape[1]
        kmod = output_kernel(model) if self.compiled else None
        if kmod is None:
            return self._nonlinear_loop_numpy(seg, P, X0, Kg, Kp, pat, c)
        Y, Xf = getattr(kmod, f"nl_loop_{self.integrator}")(
            np.ascontiguousarray(X0, dtype=float),
            np.ascontiguousarray(seg.u),
            seg.t,
            np.ascontiguousarray(P, dtype=float),
            kern._c_jit(c),
            np.ascontiguousarray(Kp),
            pat,
            np.ascontiguousarray(seg.z),
            1e-8,
            1e-10,
            INPUT_MODES[self.inputs],
        )
        # a diverging column is not an error here: its non-finite predictions make the
        # cost infinite, so a trial step that causes it is rejected
        bad = ~np.all(np.isfinite(Kg.reshape(Bc, -1)), axis=1)
        Y[bad] = np.nan
        return Y, Xf

    def _nonlinear_loop_numpy(
        self,
        seg: Segment,
        P: np.ndarray,
        X0: np.ndarray,
        Kg: np.ndarray,
        Kp: np.ndarray,
        pat: np.ndarray,
        c: Mapping[str, float],
    ):
        """:meth:`_nonlinear_loop` with numpy, sample by sample (the model's g or f does
        not compile, or ``compiled`` is off)."""
        model = self.model
        kern = kernel_for(model)
        N, m = seg.n, len(model.outputs)
        n, Bc = X0.shape
        Y = np.full((Bc, N, m), np.nan)
        Xf = np.full((Bc, N, n), np.nan)
        x = X0.copy()
        alive = np.ones(Bc, dtype=bool)
        for i in range(N):
            with np.errstate(all="ignore"):
                y = model.eval_g(x[:, None, :], seg.u[i][:, None, None], P, c)[:, 0, :]  # (m, Bc)
            nu = seg.z[i][:, None] - y
            nu = np.where(np.isfinite(nu), nu, 0.0)
            xh = x + np.einsum("bij,jb->ib", Kp[:, pat[i]], nu)
            Y[:, i, :] = y.T
            Xf[:, i, :] = xh.T
            if i + 1 < N:
                # the integrators stop a whole batch when any column becomes non-finite; a
                # diverging perturbed or trial column must not take the others with it
                idx = np.flatnonzero(alive)
                if idx.size == 0:
                    break  # every column diverged: the rest stays NaN
                x = np.full_like(xh, np.nan)
                with np.errstate(all="ignore"):
                    xs = kern.integrate(
                        self.integrator,
                        xh[:, idx],
                        seg.u[i : i + 2],
                        seg.t[i : i + 2],
                        P[:, idx],
                        c,
                        inputs=self.inputs,
                    )[1]
                    if np.all(np.isfinite(xs)):
                        x[:, idx] = xs
                    else:
                        for b in idx:
                            xb = kern.integrate(
                                self.integrator,
                                xh[:, b : b + 1],
                                seg.u[i : i + 2],
                                seg.t[i : i + 2],
                                P[:, b : b + 1],
                                c,
                                inputs=self.inputs,
                            )[1]
                            if np.all(np.isfinite(xb)):
                                x[:, b] = xb[:, 0]
                            else:
                                alive[b] = False
        bad = ~np.all(np.isfinite(Kg.reshape(Bc, -1)), axis=1)
        Y[bad] = np.nan
        return Y, Xf

    def innovations(self, res) -> list[np.ndarray]:
        return [seg.z - r.Y[0] for seg, r in zip(self.segments, res)]

    def cost(self, res) -> tuple[float, np.ndarray]:
        """(det R^, R^): the innovations' diagonal covariance R^ over every segment and its
        determinant, the cost with R concentrated out; inf when a measured output's
        prediction is not finite (a diverged filter must not shorten the sums)."""
        E = self.innovations(res)
        for seg, e in zip(self.segments, E):
            if np.any(np.isfinite(seg.z) & ~np.isfinite(e)):
                return np.inf, np.full((e.shape[1], e.shape[1]), np.nan)
        Rh = st.residual_covariance(E, full=self.full_R)
        if not np.all(np.isfinite(Rh)):
            return np.inf, Rh
        sign, logdet = np.linalg.slogdet(Rh)
        if sign <= 0:
            return np.inf, Rh
        return float(np.exp(logdet)), Rh

    def weighted(self, res, R: np.ndarray) -> float:
        """J = 1/2 sum nu^T R^-1 nu over every sample on its measured outputs: the cost the
        Gauss-Newton step lowers for a fixed R; inf when a measured output's prediction is
        not finite."""
        J = 0.0
        for k, (seg, r) in enumerate(zip(self.segments, res)):
            E = seg.z - r.Y[0]
            masks, pat = self.patterns[k]
            for p, o in enumerate(masks):
                if not o.any():
                    continue
                Eo = E[pat == p][:, o]
                if not np.all(np.isfinite(Eo)):
                    return np.inf
                J += 0.5 * float(np.sum(Eo.T * np.linalg.solve(R[np.ix_(o, o)], Eo.T)))
        return J if np.isfinite(J) else np.inf

    def constraint_ok(self, res) -> bool:
        """CK <= 1 on every segment: no state corrected by more than its predicted deviation
        (diag(K C), the reference software's constraint), or with a full R no negative
        implied measurement noise (diag(C K))."""
        return all(np.all(r.CK[0] <= 1.0 + 1e-9) for r in res)

    def segment_rows(self, nphi: int) -> list[np.ndarray]:
        """Per segment the columns of a sensitivity batch (:meth:`difference_columns`) it needs: 0 (the
        base) and 1 + the phi it depends on - the model parameters of ``Layout.relevant``
        (shared ones and its own initial states) and every process-noise parameter."""
        fi = self.lay.free_idx
        noise = np.arange(fi.size, nphi)
        return [np.r_[0, 1 + np.searchsorted(fi, rel), 1 + noise] for rel in self.lay.relevant]

    def sensitivity_batch(self, phi: np.ndarray, R: np.ndarray, rows: Sequence[np.ndarray]):
        """The perturbed filter runs of :meth:`difference_columns` for phi (column 0 the base) and their
        steps; a column whose forward step makes the gain over-correct (diag(K C) > 1) or
        the prediction run away is run again with the step reversed."""
        Phis, hsteps = self.difference_columns(phi)
        batch = self.filter(Phis, R, rows=rows)
        flip = np.zeros(phi.size, dtype=bool)
        for k, r in enumerate(batch):
            Y = r.Y
            big = 1e6 * (1.0 + np.nanmax(np.abs(Y[0])))
            with np.errstate(invalid="ignore"):
                bad = (
                    np.any(r.CK[1:] > 1.0 + 1e-9, axis=1)
                    | ~np.all(
                        np.isfinite(Y[1:]).reshape(Y.shape[0] - 1, -1) | ~np.isfinite(Y[:1]).reshape(1, -1), axis=1
                    )
                    | (np.nanmax(np.abs(Y[1:] - Y[:1]).reshape(Y.shape[0] - 1, -1), axis=1, initial=0.0) > big)
                )
            flip[rows[k][1:][bad] - 1] = True
        if np.any(flip):
            hsteps = np.where(flip, -hsteps, hsteps)
            Phis = np.repeat(phi[None, :], phi.size + 1, axis=0)
            Phis[1 + np.arange(phi.size), np.arange(phi.size)] += hsteps
            batch = self.filter(Phis, R, rows=rows)
        return batch, hsteps

    def difference_columns(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        hsteps = self.fd_step * np.maximum(np.abs(phi), self.floor)
        up_ok = phi + hsteps <= self.hi
        hsteps = np.where(up_ok, hsteps, -hsteps)
        Phis = np.repeat(phi[None, :], phi.size + 1, axis=0)
        Phis[1 + np.arange(phi.size), np.arange(phi.size)] += hsteps
        return Phis, hsteps

    def raise_diverged(self, res) -> None:
        for k, (seg, r) in enumerate(zip(self.segments, res)):
            bad = np.isfinite(seg.z) & ~np.isfinite(r.Y[0])
            if np.any(bad):
                i = int(np.argmax(np.any(bad, axis=1)))
                raise SimulationDivergedError(
                    f"the {'nonlinear ' if self.form == 'nonlinear' else ''}filter prediction of "
                    f"segment {seg.name or k} became non-finite at t={seg.t[i]:.4g} s (start "
                    "closer, e.g. from output-error or equation-error estimates, or give a "
                    "smaller process-noise start)",
                    segment=k,
                    time=float(seg.t[i]),
                )
        raise SimulationDivergedError(
            "the filter-error Riccati equation has no stabilising solution at the current "
            "parameters (a state not detectable from the outputs?)"
        )

    def fslice(self) -> slice:
        nf = self.lay.free_idx.size
        return slice(nf, nf + (len(self.noisy) if self.estimate_F else 0))
