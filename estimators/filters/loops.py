"""The filters' per-sample loops, written as element loops for numba.

* :func:`kf_loop`: the filter-error method's steady-state Kalman filter over a batch of
  linear systems (compiled here, :data:`kf_loop_jit`).
* :func:`nl_loop`: the filter-error method's constant-gain filter with the integrator's
  prediction (nonlinear form).
* :func:`ekf_segment`, :func:`ukf_segment`: one segment of an EKF / UKF pass with the
  parameters in the state, and their helpers (:data:`SEGMENT_HELPERS`).

The functions taking ``scheme``, ``rhs`` or ``gout`` are not compiled here: their source
is copied into the model's filter kernel module (:func:`estimators.filters.kernels.output_kernel`),
where those callables are the module's compiled integrator, right-hand side and output
function.
"""

from __future__ import annotations

import numpy as np

from estimators.filters.sigma_points import sigma_points

try:
    import numba
except ImportError:  # pragma: no cover
    numba = None


def kf_loop(Phi, K, pat, C, drive, offset, Z, x0):
    """Steady-state Kalman filter over a batch of linear systems.

    Phi (B, n, n), K (B, n_pat, n, m) the gain per pattern of measured outputs (zero
    columns for the missing ones, :func:`estimators.filters.steady_state.pattern_gains`), pat (N,) the pattern of each
    sample, C (B, m, n), drive (B, N, n) = Gamma (B u + f0), offset (B, N, m) = D u + y0,
    Z (N, m) with NaN = missing, x0 (B, n).
    Returns predicted outputs Y (B, N, m) and a-posteriori states X (B, N, n).
    """
    Bn, n, _ = Phi.shape
    N, m = Z.shape
    Y = np.empty((Bn, N, m))
    X = np.empty((Bn, N, n))
    nu = np.empty(m)
    xh = np.empty(n)
    for b in range(Bn):
        x = x0[b].copy()
        for k in range(N):
            for j in range(m):
                y = offset[b, k, j]
                for i in range(n):
                    y += C[b, j, i] * x[i]
                Y[b, k, j] = y
                d = Z[k, j] - y
                nu[j] = d if np.isfinite(d) else 0.0
            pk = pat[k]
            for i in range(n):
                v = x[i]
                for j in range(m):
                    v += K[b, pk, i, j] * nu[j]
                xh[i] = v
                X[b, k, i] = v
            if k + 1 < N:
                for i in range(n):
                    v = drive[b, k, i]
                    for j in range(n):
                        v += Phi[b, i, j] * xh[j]
                    x[i] = v
    return Y, X


if numba is not None:
    kf_loop_jit = numba.njit(cache=True)(kf_loop)
else:  # pragma: no cover
    kf_loop_jit = kf_loop


def nl_loop(scheme, rhs, gout, x0, U, t, P, c, K, pat, Z, rtol, atol, mode):
    """Constant-gain filter with integrator prediction, batched over parameter columns:
    x0 (n, B), P (n_p, B), K (B, n_pat, n, m) per pattern of measured outputs, pat (N,),
    Z (N, m). Returns Y (B, N, m), X (B, N, n)."""
    n, Bc = x0.shape
    N, m = Z.shape
    Y = np.full((Bc, N, m), np.nan)
    X = np.full((Bc, N, n), np.nan)
    x = x0.copy()
    y = np.empty((m, Bc))
    xh = np.empty((n, Bc))
    nu = np.empty(m)
    alive = np.ones(Bc, dtype=np.bool_)
    for i in range(N):
        gout(x, U[i], P, c, y)
        for b in range(Bc):
            for j in range(m):
                d = Z[i, j] - y[j, b]
                nu[j] = d if np.isfinite(d) else 0.0
                Y[b, i, j] = y[j, b]
            for r in range(n):
                v = x[r, b]
                for j in range(m):
                    v += K[b, pat[i], r, j] * nu[j]
                xh[r, b] = v
                X[b, i, r] = v
        if i + 1 < N:
            # the integrators stop a whole batch when any column becomes non-finite; a
            # diverging perturbed or trial column must not take the others with it, so
            # only live columns are stepped and a failed batch step is redone per column
            idx = np.flatnonzero(alive)
            if idx.size == 0:
                break
            Xs = scheme(rhs, xh[:, idx], U[i : i + 2], t[i : i + 2], P[:, idx], c, rtol, atol, mode)
            ok_all = True
            for r in range(n):
                for jj in range(idx.size):
                    if not np.isfinite(Xs[1, r, jj]):
                        ok_all = False
            if ok_all:
                for r in range(n):
                    for jj in range(idx.size):
                        x[r, idx[jj]] = Xs[1, r, jj]
            else:
                for jj in range(idx.size):
                    b = idx[jj]
                    Xb = scheme(
                        rhs,
                        xh[:, b : b + 1].copy(),
                        U[i : i + 2],
                        t[i : i + 2],
                        P[:, b : b + 1].copy(),
                        c,
                        rtol,
                        atol,
                        mode,
                    )
                    fin = True
                    for r in range(n):
                        if not np.isfinite(Xb[1, r, 0]):
                            fin = False
                    if fin:
                        for r in range(n):
                            x[r, b] = Xb[1, r, 0]
                    else:
                        alive[b] = False
                        for r in range(n):
                            x[r, b] = np.nan
    return Y, X


def column_params(S, values, fi, pidx, lo, hi, n, th, Pm):
    """Model parameters Pm (n_p, B) of augmented columns S (L, B): the layout's values with
    the free ones from S's parameter rows, held to their bounds (:meth:`estimators.filters.augmented.AugmentedModel.params`);
    ``th`` a work copy of the values."""
    m = fi.shape[0]
    for b in range(S.shape[1]):
        for j in range(m):
            th[fi[j]] = min(max(S[n + j, b], lo[j]), hi[j])
        for r in range(pidx.shape[0]):
            Pm[r, b] = th[pidx[r]]


def measured_indices(z):
    """Indices of the finite entries of z."""
    k = 0
    for a in range(z.shape[0]):
        if np.isfinite(z[a]):
            k += 1
    idx = np.empty(k, dtype=np.int64)
    k = 0
    for a in range(z.shape[0]):
        if np.isfinite(z[a]):
            idx[k] = a
            k += 1
    return idx


def book_update(K, Sinn, Rk, nu, idx, n, dt, acc, gain, last_ok):
    """The bookkeeping of an update on the outputs ``idx`` (gain K (L, k), innovations nu
    (k,) with covariance Sinn, the filter's Rk on them, step dt s, 0 at a segment start):
    the gain kept in ``gain`` (L, n_out) / ``last_ok``, and added into the flat work array
    acc = [nll, n_obs, r (n_out), r_post (n_out), nr (n_out), q_obs (n), q_exp (n)]: the
    innovations' negative log-likelihood and count
    (:func:`estimators.filters.update.innovation_nll`) and the covariance-matching sums
    (:meth:`estimators.filters.noise.NoiseMatch.add`)."""
    k = idx.shape[0]
    n_out = gain.shape[1]
    sign, logdet = np.linalg.slogdet(Sinn)
    acc[0] += np.inf if sign <= 0 else 0.5 * (nu @ np.linalg.solve(Sinn, nu) + logdet)
    acc[1] += k
    gain[:, :] = 0.0
    last_ok[:] = False
    for a in range(k):
        gain[:, idx[a]] = K[:, a]
        last_ok[idx[a]] = True
    RSi = np.linalg.solve(Sinn, Rk).T
    rp = RSi @ nu
    for a in range(k):
        o = idx[a]
        acc[2 + o] += nu[a] ** 2 - Sinn[a, a] + Rk[a, a]
        v = 0.0
        for b in range(k):
            v += RSi[a, b] * Rk[b, a]
        acc[2 + n_out + o] += rp[a] ** 2 + Rk[a, a] - v
        acc[2 + 2 * n_out + o] += 1.0
    if dt > 0:
        Kx = K[:n]
        kn = Kx @ nu
        KS = Kx @ Sinn
        base = 2 + 3 * n_out
        for r in range(n):
            acc[base + r] += kn[r] ** 2 / dt
            v = 0.0
            for a in range(k):
                v += KS[r, a] * Kx[r, a]
            acc[base + n + r] += v / dt


def project_to_bounds(s, lo, hi, n, hits, i, P, Spost, Pdiag):
    """The end of sample i: the parameter rows of s held to their bounds (projections
    counted in hits), s and diag(P) kept in row i of Spost, Pdiag."""
    for j in range(hits.shape[0]):
        v = min(max(s[n + j], lo[j]), hi[j])
        if v != s[n + j]:
            hits[j] += 1
        s[n + j] = v
    Spost[i] = s
    for j in range(s.shape[0]):
        Pdiag[i, j] = P[j, j]


def add_process_noise(P, FFt, qth, dt, n):
    """P (L, L) + the process noise of a step of dt s (FFt dt on the states, qth dt on the
    parameters), made symmetric, in place."""
    for r in range(n):
        for j in range(n):
            P[r, j] += FFt[r, j] * dt
    for j in range(qth.shape[0]):
        P[n + j, n + j] += qth[j] * dt
    for r in range(P.shape[0]):
        for j in range(r + 1, P.shape[0]):
            v = 0.5 * (P[r, j] + P[j, r])
            P[r, j] = v
            P[j, r] = v


def segment_arrays(N, L, n_out, n):
    """The outputs of a segment loop: Ypred (N, n_out) NaN, Spost and Pdiag (N, L), gain
    (L, n_out), last_ok (n_out,), hits (L - n,), acc (see :func:`book_update`)."""
    return (
        np.full((N, n_out), np.nan),
        np.empty((N, L)),
        np.empty((N, L)),
        np.zeros((L, n_out)),
        np.zeros(n_out, dtype=np.bool_),
        np.zeros(L - n, dtype=np.int64),
        np.zeros(2 + 3 * n_out + 2 * n),
    )


def ekf_segment(scheme, gout, s, P, t, U, Z, R, FFt, qth, values, fi, pidx, lo, hi, c, fd_step, rtol, atol, mode, n):
    """The EKF over one segment, compiled with the model's rhs and g (the kernel module of
    :func:`estimators.filters.kernels.output_kernel` binds ``scheme`` and ``gout``; the helpers
    above are compiled into it too): the same equations as :meth:`EKF._predict` /
    :meth:`EKF._update` and the pass loop of :meth:`ParameterFilter._one_pass` (bounds,
    innovations' likelihood, covariance-matching sums), without Python's per-sample
    overhead. s (L,) = [x0; theta], P (L, L); t (N,), U (N, n_in), Z (N, n_out) with NaN =
    not measured; R (n_out, n_out); FFt (n, n) and qth (m,) the process noise per second;
    values, fi, pidx, lo, hi the layout's values, free indices, the segment's parameter
    rows and the free parameters' bounds.
    Returns (s, P, Ypred (N, n_out), Spost (N, L), Pdiag (N, L), gain (L, n_out) of the
    last update (zero columns: not measured), its measured mask, hits (m,), acc (see
    :func:`book_update`), the sample where the prediction became non-finite or -1)."""
    N = t.shape[0]
    L = s.shape[0]
    n_out = Z.shape[1]
    Ypred, Spost, Pdiag, gain, last_ok, hits, acc = segment_arrays(N, L, n_out, n)
    S = np.empty((L, L + 1))
    Pm = np.empty((pidx.shape[0], L + 1))
    th = values.copy()
    Y = np.empty((n_out, L + 1))
    h = np.empty(L)
    eye = np.eye(L)
    for i in range(N):
        dt = 0.0
        for pred in range(2 if i > 0 else 1):
            # the difference columns s + h_j e_j and their model parameters
            for j in range(L):
                h[j] = fd_step * max(abs(s[j]), 1.0)
                for b in range(L + 1):
                    S[j, b] = s[j]
                S[j, j + 1] += h[j]
            column_params(S, values, fi, pidx, lo, hi, n, th, Pm)
            if pred == 0 and i > 0:
                # prediction over [t_(i-1), t_i]
                dt = t[i] - t[i - 1]
                X = scheme(S[:n].copy(), U[i - 1 : i + 1], t[i - 1 : i + 1], Pm, c, rtol, atol, mode)
                Phi = eye.copy()
                for r in range(n):
                    for j in range(L):
                        Phi[r, j] = (X[1, r, j + 1] - X[1, r, 0]) / h[j]
                    s[r] = X[1, r, 0]
                P = Phi @ P @ Phi.T
                add_process_noise(P, FFt, qth, dt, n)
                if not (np.all(np.isfinite(s)) and np.all(np.isfinite(P))):
                    return s, P, Ypred, Spost, Pdiag, gain, last_ok, hits, acc, i
        # measurement update at t_i (the columns set again about the predicted s)
        gout(S[:n].copy(), U[i], Pm, c, Y)
        for a in range(n_out):
            Ypred[i, a] = Y[a, 0]
        idx = measured_indices(Z[i])
        k = idx.shape[0]
        if k > 0:
            H = np.empty((k, L))
            nu = np.empty(k)
            Rk = np.empty((k, k))
            for a in range(k):
                nu[a] = Z[i, idx[a]] - Y[idx[a], 0]
                for j in range(L):
                    H[a, j] = (Y[idx[a], j + 1] - Y[idx[a], 0]) / h[j]
                for b in range(k):
                    Rk[a, b] = R[idx[a], idx[b]]
            Sinn = H @ P @ H.T + Rk
            K = np.linalg.solve(Sinn, H @ P).T
            s = s + K @ nu
            IKH = eye - K @ H
            P = IKH @ P @ IKH.T + K @ Rk @ K.T
            P = 0.5 * (P + P.T)
            book_update(K, Sinn, Rk, nu, idx, n, dt, acc, gain, last_ok)
        project_to_bounds(s, lo, hi, n, hits, i, P, Spost, Pdiag)
    return s, P, Ypred, Spost, Pdiag, gain, last_ok, hits, acc, -1


def ukf_segment(
    scheme, gout, s, P, t, U, Z, R, FFt, qth, values, fi, pidx, lo, hi, c, Wm, Wc, cfac, rtol, atol, mode, n
):
    """The UKF (sigma points not noise-augmented) over one segment, compiled as
    :func:`ekf_segment` is, with the equations of :meth:`UKF._predict` /
    :meth:`UKF._update`; Wm, Wc (2L + 1,) the weights and cfac = L + lambda. Returns what
    :func:`ekf_segment` returns."""
    N = t.shape[0]
    L = s.shape[0]
    n_out = Z.shape[1]
    B = 2 * L + 1
    Ypred, Spost, Pdiag, gain, last_ok, hits, acc = segment_arrays(N, L, n_out, n)
    Pm = np.empty((pidx.shape[0], B))
    th = values.copy()
    Y = np.empty((n_out, B))
    for i in range(N):
        dt = 0.0
        if i > 0:
            dt = t[i] - t[i - 1]
            S = sigma_points(s, P, cfac)
            column_params(S, values, fi, pidx, lo, hi, n, th, Pm)
            X = scheme(S[:n].copy(), U[i - 1 : i + 1], t[i - 1 : i + 1], Pm, c, rtol, atol, mode)
            S[:n] = X[1]
            mean = S @ Wm
            D = S - mean.reshape(L, 1)
            P = (D * Wc) @ D.T
            add_process_noise(P, FFt, qth, dt, n)
            s = mean
            if not (np.all(np.isfinite(s)) and np.all(np.isfinite(P))):
                return s, P, Ypred, Spost, Pdiag, gain, last_ok, hits, acc, i
        S = sigma_points(s, P, cfac)
        column_params(S, values, fi, pidx, lo, hi, n, th, Pm)
        gout(S[:n].copy(), U[i], Pm, c, Y)
        y = Y @ Wm
        for a in range(n_out):
            Ypred[i, a] = y[a]
        idx = measured_indices(Z[i])
        k = idx.shape[0]
        if k > 0:
            Dy = Y - y.reshape(n_out, 1)
            Ds = S - s.reshape(L, 1)
            Syy_all = (Dy * Wc) @ Dy.T + R
            Ssy_all = (Ds * Wc) @ Dy.T
            Syy = np.empty((k, k))
            Ssy = np.empty((L, k))
            Rk = np.empty((k, k))
            nu = np.empty(k)
            for a in range(k):
                nu[a] = Z[i, idx[a]] - y[idx[a]]
                for b in range(k):
                    Syy[a, b] = Syy_all[idx[a], idx[b]]
                    Rk[a, b] = R[idx[a], idx[b]]
                for j in range(L):
                    Ssy[j, a] = Ssy_all[j, idx[a]]
            K = np.linalg.solve(Syy, Ssy.T).T
            s = s + K @ nu
            P = P - K @ Syy @ K.T
            P = 0.5 * (P + P.T)
            book_update(K, Syy, Rk, nu, idx, n, dt, acc, gain, last_ok)
        project_to_bounds(s, lo, hi, n, hits, i, P, Spost, Pdiag)
    return s, P, Ypred, Spost, Pdiag, gain, last_ok, hits, acc, -1


#: the compiled helpers of the segment loops (source copied into the kernel module)
SEGMENT_HELPERS = (
    column_params,
    measured_indices,
    book_update,
    project_to_bounds,
    segment_arrays,
    add_process_noise,
    sigma_points,
)
