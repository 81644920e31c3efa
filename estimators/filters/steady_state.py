"""Steady-state pieces of the filter-error method: discretisation of a linear system, the
transition matrix and the input integrals of a sample interval, the Riccati equation
(continuous form by Potter's method, the reference software's; the sampled filter's
discrete form by Newton's method) and the gains per pattern of measured outputs.

Shapes: a batch of B linearisations A (B, n, n), C (B, m, n); F F^T (B, n, n) the
continuous process-noise spectral density; R (m, m) the innovation covariance; h the
sample interval (s).
"""

from __future__ import annotations

import numpy as np
from scipy import linalg

try:
    import numba
except ImportError:  # pragma: no cover
    numba = None


def _mm(A, B):
    """A @ B as plain loops (small matrices, compiled)."""
    n, k = A.shape
    m = B.shape[1]
    out = np.zeros((n, m))
    for i in range(n):
        for l in range(k):
            a = A[i, l]
            if a != 0.0:
                for j in range(m):
                    out[i, j] += a * B[l, j]
    return out


if numba is not None:
    _mm = numba.njit(cache=True)(_mm)


def _expm_small(M):
    """e^M by scaling and squaring with a degree-16 Taylor polynomial, written as plain
    loops so that small matrices (n <= ~20) do not go through threaded BLAS/LAPACK (whose
    start-up cost dominates, and which stalls when the cores are busy)."""
    n = M.shape[0]
    norm = 0.0
    for i in range(n):
        r = 0.0
        for j in range(n):
            r += abs(M[i, j])
        norm = max(norm, r)
    s = 0
    while norm > 0.25:
        norm *= 0.5
        s += 1
    A = M / (2.0**s)
    E = np.eye(n)
    T = np.eye(n)
    for k in range(1, 17):
        T = _mm(T, A) / k
        E += T
    for _ in range(s):
        E = _mm(E, E)
    return E


if numba is not None:
    _expm_small = numba.njit(cache=True)(_expm_small)


def expm(M: np.ndarray) -> np.ndarray:
    """Matrix exponential: compiled Taylor scaling-and-squaring for small matrices,
    scipy.linalg.expm otherwise (and for non-finite input)."""
    if M.shape[0] <= 24 and np.all(np.isfinite(M)):
        return _expm_small(np.ascontiguousarray(M, dtype=float))
    return linalg.expm(M)


def discretize(A: np.ndarray, FFt: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Phi = e^{A h}, Gamma = int_0^h e^{As} ds, Qd = int_0^h e^{As} F F^T e^{A^T s} ds (van
    Loan) for one system: A (n, n), FFt (n, n), h (s)."""
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = A
    M[:n, n:] = np.eye(n)
    E = expm(M * h)
    Phi, Gam = E[:n, :n], E[:n, n:]
    if not np.any(FFt):
        return Phi, Gam, np.zeros((n, n))
    V = np.zeros((2 * n, 2 * n))
    V[:n, :n] = -A
    V[:n, n:] = FFt
    V[n:, n:] = A.T
    W = expm(V * h)
    Qd = Phi @ W[:n, n:]
    return Phi, Gam, 0.5 * (Qd + Qd.T)


def input_integrals(A: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Phi = e^{A h}, Gamma0 = int_0^h e^{As} ds and Gamma1 = int_0^h e^{A(h-s)} s ds / h for
    one system A (n, n): over a sample interval the input enters as Gamma0 B u_k for a held
    input plus Gamma1 B (u_k+1 - u_k) for one interpolated linearly (first-order hold, the
    exact counterpart of the integrators' stage-time interpolation)."""
    n = A.shape[0]
    M = np.zeros((3 * n, 3 * n))
    M[:n, :n] = A * h
    M[:n, n : 2 * n] = np.eye(n) * h
    M[n : 2 * n, 2 * n :] = np.eye(n)
    E = expm(M)
    return E[:n, :n], E[:n, n : 2 * n], E[:n, 2 * n :]


def continuous_gain(
    A: np.ndarray, C: np.ndarray, FFt: np.ndarray, R: np.ndarray, h: float
) -> tuple[np.ndarray, np.ndarray]:
    """Steady-state P (B, n, n) and gain K = P C^T R^-1 (B, n, m) of the filter-error method
    for a batch of linearisations A (B, n, n), C (B, m, n) and process noise FFt (B, n, n),
    with R (m, m) the innovation covariance and h the sample interval (s).

    P solves A P + P A^T - P C^T (R h)^-1 C P + F F^T = 0 (the reference software's
    continuous form of the Riccati equation with the innovation covariance in place of the
    measurement noise), by Potter's method: the eigenvectors of the Hamiltonian
    [[A, -F F^T], [-C^T R^-1 C / h, -A^T]] for its eigenvalues of positive real part give
    P = -E11 E21^-1, all columns in one batched eigen-decomposition. A column where that
    fails (an eigenvalue on the imaginary axis) is solved by scipy's Schur method; NaN
    where neither has a stabilising solution. Columns without process noise get P = 0."""
    Bc, n, _ = A.shape
    Ri = np.linalg.inv(R)
    P = np.zeros((Bc, n, n))
    noisy = np.any(FFt.reshape(Bc, -1) != 0.0, axis=1)
    if np.any(noisy):
        a, c, q = A[noisy], C[noisy], FFt[noisy]
        H = np.block([[a, -q], [-np.einsum("bji,jk,bkl->bil", c, Ri, c) / h, -a.transpose(0, 2, 1)]])
        with np.errstate(all="ignore"):
            ok = np.all(np.isfinite(H.reshape(H.shape[0], -1)), axis=1)
            Pn = np.full((H.shape[0], n, n), np.nan)
            if np.any(ok):
                w, V = np.linalg.eig(H[ok])
                order = np.argsort(w.real, axis=1)[:, n:]
                E = np.take_along_axis(V, order[:, None, :], axis=2)
                wr = np.take_along_axis(w.real, order, axis=1)
                sol = -E[:, :n] @ np.linalg.pinv(E[:, n:])
                good = (np.min(wr, axis=1) > 1e-9 * np.max(np.abs(w), axis=1, initial=1.0)) & np.all(
                    np.abs(sol.imag) <= 1e-8 * (1.0 + np.abs(sol.real)), axis=(1, 2)
                )
                Pn[ok] = np.where(good[:, None, None], sol.real, np.nan)
        for b in np.flatnonzero(~np.all(np.isfinite(Pn.reshape(Pn.shape[0], -1)), axis=1)):
            try:
                Pn[b] = linalg.solve_continuous_are(a[b].T, c[b].T, q[b], R * h)
            except (np.linalg.LinAlgError, ValueError):
                Pn[b] = np.nan
        P[noisy] = 0.5 * (Pn + Pn.transpose(0, 2, 1))
    K = np.einsum("bij,bkj,kl->bil", P, C, Ri)
    return P, K


def discrete_gain(
    A: np.ndarray, C: np.ndarray, FFt: np.ndarray, R: np.ndarray, h: float, max_iter: int = 12
) -> tuple[np.ndarray, np.ndarray]:
    """Steady-state a-priori P (B, n, n) and gain K = P C^T R^-1 (B, n, m) of the sampled
    filter for a batch of linearisations A (B, n, n), C (B, m, n), process noise FFt
    (B, n, n), the innovation covariance R (m, m) and the sample interval h (s).

    P solves P = Phi (P - P C^T R^-1 C P) Phi^T + Qd (Phi, Qd of :func:`discretize`): the
    Kalman filter's prediction of its own a-posteriori covariance when R is the innovation
    covariance. Newton's method from the continuous form's solution
    (:func:`continuous_gain`, the reference software's, which it approaches as h -> 0),
    batched over columns; the continuous solution is kept for a column where Newton does
    not settle. NaN where neither exists."""
    Bc, n, _ = A.shape
    P, K = continuous_gain(A, C, FFt, R, h)
    noisy = np.any(FFt.reshape(Bc, -1) != 0.0, axis=1) & np.all(np.isfinite(P.reshape(Bc, -1)), axis=1)
    if not np.any(noisy):
        return P, K
    idx = np.flatnonzero(noisy)
    Ri = np.linalg.inv(R)
    Phi = np.empty((idx.size, n, n))
    Q = np.empty((idx.size, n, n))
    for j, b in enumerate(idx):
        Phi[j], _, Q[j] = discretize(A[b], FFt[b], h)
    Mm = np.einsum("bji,jk,bkl->bil", C[idx], Ri, C[idx])
    X = P[idx].copy()
    eye = np.eye(n * n)
    q_scale = np.abs(Q).reshape(idx.size, -1).max(axis=1)
    done = np.zeros(idx.size, dtype=bool)
    with np.errstate(all="ignore"):
        for _ in range(max_iter):
            XM = X @ Mm
            f = Phi @ (X - XM @ X) @ Phi.transpose(0, 2, 1) + Q - X
            # relative to the larger of Qd and P: with little process noise on an unstable
            # mode P stays finite while Qd -> 0, and a residual relative to Qd alone would
            # never settle (the column then keeping the continuous solution, a jump between
            # the columns of one sensitivity batch)
            scale = np.maximum(q_scale, np.abs(X).reshape(idx.size, -1).max(axis=1)) + 1e-300
            err = np.abs(f).reshape(idx.size, -1).max(axis=1) / scale
            done = np.isfinite(err) & (err < 1e-12)
            if np.all(done | ~np.isfinite(err)):
                break
            PXM = Phi @ XM
            J = (
                np.einsum("bij,bkl->bikjl", Phi, Phi)
                - np.einsum("bij,bkl->bikjl", Phi, PXM)
                - np.einsum("bij,bkl->bikjl", PXM, Phi)
            ).reshape(idx.size, n * n, n * n) - eye
            try:
                dX = np.linalg.solve(J, -f.reshape(idx.size, n * n, 1)).reshape(idx.size, n, n)
            except np.linalg.LinAlgError:
                break
            X = X + np.where(done[:, None, None], 0.0, dX)
            X = 0.5 * (X + X.transpose(0, 2, 1))
    good = done & np.all(np.isfinite(X.reshape(idx.size, -1)), axis=1)
    P[idx[good]] = X[good]
    K = np.einsum("bij,bkj,kl->bil", P, C, Ri)
    return P, K


def output_patterns(Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The patterns of measured (finite) outputs in Z (N, m): (masks (n_pat, m) bool, the
    pattern index of each sample (N,)). One pattern when every output is measured at
    every sample; multi-rate data (a 10 Hz airspeed on a 50 Hz grid) have several."""
    masks, pat = np.unique(np.isfinite(Z), axis=0, return_inverse=True)
    return masks, np.ascontiguousarray(pat.reshape(-1), dtype=np.int64)


def pattern_gains(Pp: np.ndarray, C: np.ndarray, B: np.ndarray, K: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """Steady-state gains per pattern of measured outputs, (Bc, n_pat, n, m): for the
    outputs o measured, K_o = P C_o^T B_oo^-1 (P the a-priori covariance, B = C P C^T + R)
    in their columns, zero in the others; the full gain K where every output is measured.
    (The full K's columns are not the subset's gain: B^-1 couples the outputs.)"""
    Bc, n, m = K.shape
    out = np.zeros((Bc, masks.shape[0], n, m))
    for p, o in enumerate(masks):
        if o.all():
            out[:, p] = K
        elif o.any():
            PCt = np.einsum("bij,bkj->bik", Pp, C[:, o, :])  # (Bc, n, m_o)
            with np.errstate(all="ignore"):
                out[:, p][:, :, o] = np.linalg.solve(B[:, o][:, :, o], PCt.transpose(0, 2, 1)).transpose(0, 2, 1)
    return np.nan_to_num(out)
