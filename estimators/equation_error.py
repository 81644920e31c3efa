"""Equation-error (regression) methods: OLS, TLS, recursive LS, Fourier-transform regression.

Equation error fits a linear-in-the-parameters relation y = X theta + e, e.g. the pitching
moment coefficient computed from measured pitch acceleration regressed on alpha, q c/2V and
the elevator. The API follows statsmodels / scikit-learn::

    ls = LeastSquares(["alpha", "qhat", "de"], intercept=True)         # method="ols"|"tls"
    res = ls.fit(X, y)                    # X (N, n) array or DataFrame, y (N,)
    res.params, res.std, res.summary()

    rls = RecursiveLeastSquares(["alpha", "qhat", "de"], forgetting=0.995)
    res = rls.fit(X, y)                   # or rls.update(x_k, y_k) sample by sample
    ftr = FourierRegression(["alpha", "qhat", "de"], band=(0.1, 1.5), df=0.02)
    res = ftr.fit(X, y, dt=0.02)          # or ftr.update(x_k, y_k, t_k) in real time

Every fit returns :class:`~estimators.EstimationResult`; its ``model`` is the regression
as a :class:`~estimators.Model` with no states (inputs = regressors, one output = the
response, g = X theta), so summaries, tables and reports work as for the dynamic methods.
``predicted``/``residuals`` are X theta and y - X theta on the sample index (or the time
stamps given to ``fit``); ``R`` is the 1x1 residual variance s^2.

Covariances:

* OLS: s^2 (X^T X)^-1 with s^2 = e^T e / (N - n_p).
* TLS (errors in the regressors and the response, equal variance per column after the
  optional column scaling): the first-order asymptotic covariance (Gleser 1981)
  s^2 (1 + |theta|^2) (X^T X - N s^2 I)^-1 with s^2 = sigma_min^2 / (N - n_p) from the
  smallest singular value of [X y].
* RLS: s^2 P with P the recursive inverse information; with forgetting factor 1 and a
  diffuse start this is the OLS covariance.
* FTR: the complex regression Y(w) = X(w) theta on the Fourier transforms at the chosen
  frequencies: theta = Re(X^H X)^-1 Re(X^H Y), cov = s^2 Re(X^H X)^-1 with
  s^2 = |Y - X theta|^2 / (n_f - n_p) (Morelli's frequency-domain equation error). The
  transforms come from a recursive (sliding-sum) DFT, X_k(w) = X_{k-1}(w) + x_k e^{-jwt_k} dt,
  so the estimate is available at every sample.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from estimators import statistics as st
from estimators.defaults import RLS_P0
from estimators.errors import IdentifiabilityError, ModelDefinitionError
from estimators.frequency.stream import StreamingFourierTransform, derivative_transform, linear_fourier_transform
from estimators.frequency.transform import DETRENDS, detrended, fourier_transform, uniform_step
from estimators.model import Model, Parameter
from estimators.results import EstimationResult


# -- the regression as a Model --------------------------------------------------------------
def regression_model(
    regressors: Sequence[str], response: str = "y", intercept: bool = False, name: str = "regression"
) -> Model:
    """A static Model y = sum theta_i x_i (+ theta_0): no states, inputs = regressors.
    Parameter names are the regressor names (``bias`` for the intercept)."""
    regs = list(regressors)
    pnames = (["bias"] if intercept else []) + regs
    for n in pnames:
        if not n.isidentifier():
            raise ModelDefinitionError(f"regressor name {n!r} is not a Python identifier: rename it")
    nreg = len(regs)

    def f(x, u, p, c):  # no states
        return ()

    def g(x, u, p, c):
        vals = [getattr(p, n) for n in regs]
        y = sum(v * u[i] for i, v in enumerate(vals)) if nreg else 0.0
        if intercept:
            y = y + p.bias
        return (y,)

    return Model(
        states=[], inputs=regs, outputs=[response], parameters=[Parameter(n, 0.0) for n in pnames], f=f, g=g, name=name
    )


def _as_xy(X: Any, y: Any, names: Sequence[str] | None) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray | None]:
    index = None
    if isinstance(X, pd.DataFrame):
        cols = list(names) if names else list(X.columns)
        missing = [c for c in cols if c not in X.columns]
        if missing:
            raise ModelDefinitionError(f"regressors {missing} are not columns of X {list(X.columns)}")
        index = X.index.to_numpy()
        Xa = X[cols].to_numpy(dtype=float)
        names = cols
    else:
        Xa = np.asarray(X, dtype=float)
        if Xa.ndim == 1:
            Xa = Xa[:, None]
    ya = np.asarray(y, dtype=float).ravel()
    if Xa.shape[0] != ya.size:
        raise ModelDefinitionError(f"X has {Xa.shape[0]} rows but y has {ya.size} samples")
    if names is None:
        names = [f"x{i}" for i in range(Xa.shape[1])]
    if len(names) != Xa.shape[1]:
        raise ModelDefinitionError(f"{len(names)} regressor names for {Xa.shape[1]} columns of X")
    ok = np.all(np.isfinite(Xa), axis=1) & np.isfinite(ya)
    if not np.all(ok):
        Xa, ya = Xa[ok], ya[ok]
        index = None if index is None else index[ok]
    return Xa, ya, list(names), index


def _check_rank(XtX: np.ndarray, names: Sequence[str]) -> None:
    st.check_identifiable(XtX, list(names), " of the regressors")


class _RegressionBase:
    method = "ols"

    def __init__(
        self, regressors: Sequence[str] | None = None, *, intercept: bool = False, response: str = "y"
    ) -> None:
        self.regressors = None if regressors is None else list(regressors)
        self.intercept = intercept
        self.response = response

    def _design(self, X: Any, y: Any) -> tuple[np.ndarray, np.ndarray, list[str], Model, np.ndarray | None]:
        Xa, ya, names, index = _as_xy(X, y, self.regressors)
        model = regression_model(names, self.response, self.intercept, name=f"{self.method} regression")
        if self.intercept:
            Xa = np.column_stack([np.ones(Xa.shape[0]), Xa])
        if Xa.shape[0] <= Xa.shape[1]:
            raise ModelDefinitionError(
                f"{Xa.shape[0]} samples for {Xa.shape[1]} parameters: a regression needs more samples than parameters"
            )
        return Xa, ya, names, model, index

    def _result(
        self,
        model: Model,
        theta: np.ndarray,
        cov: np.ndarray,
        s2: float,
        Xa: np.ndarray,
        ya: np.ndarray,
        index: np.ndarray | None,
        history: pd.DataFrame | None = None,
        extra: dict | None = None,
        information: np.ndarray | None = None,
        message: str = "",
    ) -> EstimationResult:
        t = np.arange(ya.size, dtype=float) if index is None else np.asarray(index, dtype=float)
        yhat = Xa @ theta
        pred = pd.DataFrame({self.response: yhat}, index=pd.Index(t, name="t"))
        res = pd.DataFrame({self.response: ya - yhat}, index=pd.Index(t, name="t"))
        return EstimationResult(
            method=self.method,
            model=model,
            names=model.parameter_names,
            values=np.asarray(theta, float),
            free=np.ones(theta.size, dtype=bool),
            cov=cov,
            R=np.array([[s2]]),
            converged=True,
            iterations=1,
            history=history if history is not None else pd.DataFrame(),
            predicted=[pred],
            residuals=[res],
            message=message,
            information=information,
            settings={"intercept": self.intercept},
            extra=extra or {},
        )


class LeastSquares(_RegressionBase):
    """Ordinary (``method="ols"``) or total (``method="tls"``) least squares.

    regressors : names of the columns of X (taken from a DataFrame's columns when None).
    intercept : add a constant regressor ``bias``.
    response : name of y in the result.
    scale : TLS only - divide each column of [X y] by this (n_regressors + 1,) vector of
        noise std before the SVD (TLS assumes equal error variance in every column); the
        estimates are returned in the original units.
    """

    def __init__(
        self,
        regressors: Sequence[str] | None = None,
        *,
        method: str = "ols",
        intercept: bool = False,
        response: str = "y",
        scale: Sequence[float] | None = None,
    ) -> None:
        super().__init__(regressors, intercept=intercept, response=response)
        if method not in ("ols", "tls"):
            raise ModelDefinitionError(f"method must be 'ols' or 'tls', not {method!r}")
        self.method = method
        self.scale = None if scale is None else np.asarray(scale, dtype=float)

    def fit(self, X: Any, y: Any) -> EstimationResult:
        Xa, ya, names, model, index = self._design(X, y)
        N, n = Xa.shape
        if self.method == "ols":
            XtX = Xa.T @ Xa
            _check_rank(XtX, model.parameter_names)
            theta = st.solve_step(XtX, Xa.T @ ya)
            e = ya - Xa @ theta
            s2 = float(e @ e) / (N - n)
            cov = s2 * st.covariance(XtX)
            return self._result(model, theta, cov, s2, Xa, ya, index, information=XtX / s2)
        # total least squares
        if self.intercept:
            # the constant column is exact: project it out (mixed LS-TLS), then TLS on the rest
            mx, my = Xa[:, 1:].mean(axis=0), ya.mean()
            Xc, yc = Xa[:, 1:] - mx, ya - my
        else:
            Xc, yc = Xa, ya
        m = Xc.shape[1]
        w = np.ones(m + 1) if self.scale is None else self.scale
        if w.size != m + 1:
            raise ModelDefinitionError(f"scale needs {m + 1} entries (regressors and y), got {w.size}")
        Cm = np.column_stack([Xc, yc]) / w
        _, sv, Vt = np.linalg.svd(Cm, full_matrices=False)
        v = Vt[-1]
        if abs(v[-1]) < 1e-12:
            raise IdentifiabilityError(
                "TLS has no solution: the smallest singular vector has no response component (y is unrelated to X)",
                parameters=model.parameter_names,
            )
        ts = -v[:-1] / v[-1]  # in scaled units
        dof = Cm.shape[0] - m - (1 if self.intercept else 0)
        s2s = float(sv[-1] ** 2) / dof
        Xs = Cm[:, :-1]
        A = Xs.T @ Xs - Cm.shape[0] * s2s * np.eye(m)
        covs = s2s * (1.0 + ts @ ts) * np.linalg.inv(A)
        theta_r = ts * w[-1] / w[:-1]
        J = np.diag(w[-1] / w[:-1])
        cov_r = J @ covs @ J
        if self.intercept:
            b = my - mx @ theta_r
            theta = np.concatenate([[b], theta_r])
            cov = np.zeros((m + 1, m + 1))
            cov[1:, 1:] = cov_r
            cov[0, 1:] = cov[1:, 0] = -(cov_r @ mx)
            cov[0, 0] = mx @ cov_r @ mx + s2s * w[-1] ** 2 * (1 + ts @ ts) / N
        else:
            theta = theta_r
            cov = cov_r
        e = ya - Xa @ theta
        s2 = float(e @ e) / (N - n)
        return self._result(
            model, theta, cov, s2, Xa, ya, index, extra={"singular_values": sv, "noise_var_scaled": s2s}
        )


class RecursiveLeastSquares(_RegressionBase):
    """Recursive least squares with exponential forgetting.

    theta_k = theta_{k-1} + k_k (y_k - x_k^T theta_{k-1}),
    k_k = P_{k-1} x_k / (lambda + x_k^T P_{k-1} x_k),  P_k = (P_{k-1} - k_k x_k^T P_{k-1}) / lambda.

    forgetting : lambda in (0, 1]; 1 = no forgetting (the final estimate equals OLS up to
        the diffuse start), 0.95-0.999 tracks slowly varying parameters (memory ~ 1/(1-lambda)
        samples).
    p0 : initial P = p0 * I (large = diffuse, default RLS_P0 = 1e6).
    theta0 : start estimate (zeros by default).

    ``update(x, y)`` processes one sample (usable in real time) and returns the current
    estimate; ``fit(X, y)`` runs over a batch and returns the result with the parameter
    trajectories ``extra["trajectory"]`` and their std ``extra["trajectory_std"]``
    (DataFrames on the sample index), with s^2 from the a-posteriori residuals weighted
    by the forgetting window.
    """

    method = "rls"

    def __init__(
        self,
        regressors: Sequence[str] | None = None,
        *,
        forgetting: float = 1.0,
        intercept: bool = False,
        response: str = "y",
        p0: float = RLS_P0,
        theta0: Sequence[float] | None = None,
    ) -> None:
        super().__init__(regressors, intercept=intercept, response=response)
        if not 0.0 < forgetting <= 1.0:
            raise ModelDefinitionError(f"forgetting factor must lie in (0, 1], got {forgetting}")
        self.forgetting = float(forgetting)
        self.p0 = float(p0)
        self.theta0 = theta0
        self.theta: np.ndarray | None = None
        self.P: np.ndarray | None = None

    def reset(self, n: int) -> None:
        self.theta = np.zeros(n) if self.theta0 is None else np.asarray(self.theta0, float).copy()
        self.P = self.p0 * np.eye(n)

    def update(self, x: Sequence[float], y: float) -> np.ndarray:
        """One RLS step with regressor row x (without the intercept's 1) and response y."""
        x = np.asarray(x, dtype=float).ravel()
        if self.intercept:
            x = np.concatenate([[1.0], x])
        if self.theta is None:
            self.reset(x.size)
        self.theta, self.P = _rls_step(self.theta, self.P, x, float(y), self.forgetting)
        return self.theta

    def fit(self, X: Any, y: Any) -> EstimationResult:
        Xa, ya, names, model, index = self._design(X, y)
        N, n = Xa.shape
        self.reset(n)
        lam = self.forgetting
        traj = np.empty((N, n))
        pdiag = np.empty((N, n))
        sw = 0.0  # forgetting-weighted sum of squared a-posteriori residuals
        wsum = 0.0  # forgetting-weighted sample count
        s2_t = np.empty(N)
        theta, P = self.theta, self.P
        for k in range(N):
            x = Xa[k]
            theta, P = _rls_step(theta, P, x, ya[k], lam)
            e = ya[k] - x @ theta
            sw = lam * sw + e * e
            wsum = lam * wsum + 1.0
            traj[k] = theta
            pdiag[k] = np.diag(P)
            s2_t[k] = sw / max(wsum - n, 1.0)
        self.theta, self.P = theta, 0.5 * (P + P.T)
        s2 = float(s2_t[-1])
        cov = s2 * self.P
        t = np.arange(N, dtype=float) if index is None else np.asarray(index, dtype=float)
        tr = pd.DataFrame(traj, index=pd.Index(t, name="t"), columns=model.parameter_names)
        trs = pd.DataFrame(
            np.sqrt(np.maximum(pdiag, 0) * s2_t[:, None]), index=pd.Index(t, name="t"), columns=model.parameter_names
        )
        res = self._result(
            model, theta, cov, s2, Xa, ya, index, extra={"trajectory": tr, "trajectory_std": trs, "P": self.P}
        )
        return res.replace(settings={**res.settings, "forgetting": lam})


def _rls_step(theta: np.ndarray, P: np.ndarray, x: np.ndarray, y: float, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """One recursive-least-squares update with forgetting factor lam."""
    Px = P @ x
    gain = Px / (lam + x @ Px)
    theta = theta + gain * (y - x @ theta)
    P = (P - np.outer(gain, Px)) / lam
    return theta, 0.5 * (P + P.T)


class RecursiveDFT:
    """Recursive discrete Fourier transform at fixed frequencies (usable in real time).

    X_k(w) = X_{k-1}(w) + (x_k - x_0) e^{-j w t_k} dt, with the rotation e^{-j w dt}
    carried recursively (one complex multiply per frequency and sample). Each channel's
    first sample is subtracted (Morelli's real-time method: the trim drops out without a
    record to detrend). ``frequencies`` in Hz.
    """

    def __init__(self, frequencies: Sequence[float], dt: float, n_channels: int) -> None:
        self.f = np.asarray(frequencies, dtype=float)
        self.w = 2.0 * np.pi * self.f
        self.dt = float(dt)
        self.rot = np.exp(-1j * self.w * self.dt)
        self.X = np.zeros((self.f.size, n_channels), dtype=complex)
        self.phase = np.ones(self.f.size, dtype=complex)  # e^{-j w t_k}, t_0 = 0
        self.first: np.ndarray | None = None
        self.count = 0

    def update(self, x: Sequence[float]) -> np.ndarray:
        x = np.asarray(x, dtype=float).ravel()
        if self.first is None:
            self.first = x.copy()
        self.X += np.outer(self.phase, x - self.first) * self.dt
        self.phase = self.phase * self.rot
        self.count += 1
        if self.count % 1000 == 0:  # re-normalise the carried rotation (round-off)
            self.phase /= np.abs(self.phase)
        return self.X


class FourierRegression(_RegressionBase):
    """Fourier-transform (frequency-domain equation-error) regression over a band.

    frequencies : the frequencies in Hz; or band : (f_low, f_high) in Hz with frequencies
        ``np.arange(f_low, f_high + df/2, df)``, df : their spacing in Hz (default: 1 /
        record length at fit time).
    detrend : of the whole-record transform (:func:`estimators.frequency.fourier_transform`:
        "ends", the default, removes the line through the first and last samples).
    The intercept (a constant, i.e. zero frequency) drops out at w > 0 and is not
    estimated; biases and trim values need no removal.

    response_derivative : regress the time derivative of y (a rate whose derivative the
        equation needs: q for the pitching moment) through its transform jw Y + the record's
        end terms, exact for the samples' interpolant, instead of a differentiated signal.

    ``fit(X, y, dt)`` transforms the whole record (:func:`~estimators.frequency.fourier_transform`,
    exact for the samples' cubic interpolant; samples at irregular times, a DataFrame's
    index: :func:`~estimators.frequency.stream.linear_fourier_transform`, exact for their
    piecewise-linear interpolant) and solves. The real-time form: ``update(x, y)`` (after
    ``start(dt, n_regressors)``) adds one sample to a recursive DFT that subtracts each
    channel's first sample; ``update(x, y, t)`` (after ``start(None, n_regressors)``, with
    ``detrend="none"``) adds a sample at its own time to the irregular transform, which
    then equals ``fit`` on the same samples; ``estimate()`` solves with what has been seen.
    """

    method = "ftr"

    def __init__(
        self,
        regressors: Sequence[str] | None = None,
        *,
        band: tuple[float, float] | None = None,
        df: float | None = None,
        frequencies: Sequence[float] | None = None,
        detrend: str = "ends",
        response: str = "y",
        response_derivative: bool = False,
    ) -> None:
        super().__init__(regressors, intercept=False, response=response)
        self.response_derivative = bool(response_derivative)
        self._stream: StreamingFourierTransform | None = None
        if detrend not in DETRENDS:
            raise ModelDefinitionError(f"detrend={detrend!r}: use one of {', '.join(DETRENDS)}")
        self.detrend = detrend
        if frequencies is None and band is None:
            raise ModelDefinitionError("FourierRegression needs band=(f_low, f_high) or frequencies")
        if band is not None and not 0.0 <= band[0] < band[1]:
            raise ModelDefinitionError(f"band must satisfy 0 <= f_low < f_high, got {band}")
        self.band = band
        self.df = df
        self.frequencies = None if frequencies is None else np.asarray(frequencies, float)
        self._dft: RecursiveDFT | None = None

    def _freqs(self, T: float | None) -> np.ndarray:
        if self.frequencies is not None:
            return self.frequencies
        df = self.df if self.df is not None else (1.0 / T if T else None)
        if df is None:
            raise ModelDefinitionError("give df (Hz) for real-time use, or fit a whole record")
        lo, hi = self.band
        f = np.arange(np.ceil(lo / df - 1e-9) * df, hi + 0.5 * df, df)
        f = f[(f > 0) & (f <= hi + 1e-12)]
        if f.size == 0:
            raise ModelDefinitionError(f"no frequencies in band {self.band} at spacing {df} Hz")
        return f

    # real-time form
    def start(self, dt: float | None, n_regressors: int) -> None:
        """Start the real-time form: samples every ``dt`` s (a recursive DFT), or at their
        own times (``dt`` None: the irregular transform; needs ``detrend="none"``)."""
        if dt is None:
            if self.detrend != "none":
                raise ModelDefinitionError(
                    "samples at their own times are transformed as they are: use FourierRegression(detrend='none') "
                    "and give the constants their own regressors"
                )
            if self.frequencies is None:
                raise ModelDefinitionError("give the frequencies for real-time use at the samples' own times")
            self._stream, self._dft = StreamingFourierTransform(2 * np.pi * self.frequencies, n_regressors + 1), None
        else:
            self._dft, self._stream = RecursiveDFT(self._freqs(None), dt, n_regressors + 1), None

    def update(self, x: Sequence[float], y: float, t: float | None = None) -> None:
        """Add one sample: regressors ``x``, response ``y`` (at time ``t`` s in the
        irregular form)."""
        row = np.concatenate([np.asarray(x, float).ravel(), [float(y)]])
        if self._stream is not None:
            if t is None:
                raise ModelDefinitionError("started for samples at their own times: give update(x, y, t)")
            self._stream.update(t, row)
        elif self._dft is not None:
            self._dft.update(row)
        else:
            raise ModelDefinitionError("call start(dt, n_regressors) before update()")

    def update_many(self, X: np.ndarray, y: np.ndarray, t: np.ndarray) -> None:
        """Add samples (rows of ``X``, ``y``) at their own times ``t`` at once (the same as
        one :meth:`update` each, vectorised; after ``start(None, n_regressors)``)."""
        if self._stream is None:
            raise ModelDefinitionError("update_many adds samples at their own times: start(None, n_regressors) first")
        self._stream.update_many(t, np.column_stack([np.asarray(X, float), np.asarray(y, float)]))

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """(theta, cov) from the transforms accumulated so far."""
        if self._stream is not None:
            Xf = self._stream.X[:, :-1]
            Yf = self._stream.derivative()[:, -1] if self.response_derivative else self._stream.X[:, -1]
            return self._solve(Xf, Yf)[:2]
        Xf = self._dft.X[:, :-1]
        Yf = self._dft.X[:, -1]
        if self.response_derivative:
            raise ModelDefinitionError("response_derivative needs the samples' own times: start(None, n_regressors)")
        return self._solve(Xf, Yf)[:2]

    def _transform(self, t: np.ndarray, Xa: np.ndarray, ya: np.ndarray, w: np.ndarray) -> np.ndarray:
        """The regressors' and the response's (or its derivative's) transforms (n_f, n + 1)
        of one record: cubic on a uniform grid, piecewise-linear at irregular times."""
        data = np.column_stack([Xa, ya])
        try:
            uniform_step(t)
            F = fourier_transform(t, data, w, self.detrend)
        except ModelDefinitionError:  # irregular times (or too few for the cubic weights)
            F = linear_fourier_transform(t, detrended(t, data, self.detrend), w)
        if self.response_derivative:
            F[:, -1] = derivative_transform(t, detrended(t, ya, self.detrend), w, F[:, -1])
        return F

    def _solve(self, Xf: np.ndarray, Yf: np.ndarray, names: Sequence[str] | None = None):
        n = Xf.shape[1]
        A = np.real(Xf.conj().T @ Xf)
        b = np.real(Xf.conj().T @ Yf)
        if names is not None:
            _check_rank(A, names)
        theta = st.solve_step(A, b)
        E = Yf - Xf @ theta
        nf = Xf.shape[0]
        s2 = float(np.real(E.conj() @ E)) / max(nf - n, 1)
        cov = s2 * st.covariance(A)
        return theta, cov, s2, A

    def fit(self, X: Any, y: Any, dt: float | None = None) -> EstimationResult:
        Xa, ya, names, model, index = self._design(X, y)
        if dt is None:
            if index is None:
                raise ModelDefinitionError("give dt (s) or a DataFrame indexed by time")
            dt = float(np.median(np.diff(index)))
        N, n = Xa.shape
        t = np.arange(N) * dt if index is None else np.asarray(index, dtype=float)
        freqs = self._freqs(t[-1] - t[0] + dt)
        F = self._transform(t, Xa, ya, 2 * np.pi * freqs)
        Xf, Yf = F[:, :-1], F[:, -1]
        theta, cov, s2, A = self._solve(Xf, Yf, model.parameter_names)
        res = self._result(
            model, theta, cov, s2, Xa, ya, index, information=A / s2, extra={"frequencies": freqs, "X_f": Xf, "Y_f": Yf}
        )
        settings = {
            **res.settings,
            "band": self.band,
            "n_frequencies": int(freqs.size),
            "dt": dt,
            "detrend": self.detrend,
        }
        return res.replace(R=np.array([[s2]]), settings=settings)

    def fit_records(self, records: Sequence[tuple[np.ndarray, Any, Any]]) -> EstimationResult:
        """The regression over several records (maneuvers) at once: each (t, X, y) with t
        (N_k,) uniformly sampled in s, X (N_k, n) (or a DataFrame) and y (N_k,), transformed
        on its own at the frequencies (from ``band`` at the shortest record's 1/T unless
        given), their equations stacked and solved together. The result's covariances:
        "crb", s^2 (Re X^H X)^-1 (the reference's, the stated std), and "sandwich", measured
        from the residuals frequency by frequency
        (:func:`estimators.frequency.covariance.frequency_covariances`), which holds where the
        equation error's level changes across the band."""
        from estimators.frequency.covariance import frequency_covariances

        if not records:
            raise ModelDefinitionError("fit_records needs at least one (t, X, y) record")
        designed = [(np.asarray(t, dtype=float), *self._design(X, y)) for t, X, y in records]
        names, model = designed[0][3], designed[0][4]
        T = min(t[-1] - t[0] + float(np.median(np.diff(t))) for t, *_ in designed)
        freqs = self._freqs(T)
        w = 2 * np.pi * freqs
        F = [self._transform(t, Xa, ya, w) for t, Xa, ya, *_ in designed]
        Xf = np.concatenate([f[:, :-1] for f in F])
        Yf = np.concatenate([f[:, -1] for f in F])
        theta, cov, s2, A = self._solve(Xf, Yf, names)
        covs = frequency_covariances(-Xf[:, None, :], (Yf - Xf @ theta)[:, None], np.array([[1.0 / s2]]))
        Xa = np.vstack([d[1] for d in designed])
        ya = np.concatenate([d[2] for d in designed])
        res = self._result(
            model,
            theta,
            cov,
            s2,
            Xa,
            ya,
            np.concatenate([t for t, *_ in designed]),
            information=A / s2,
            extra={"frequencies": freqs, "X_f": Xf, "Y_f": Yf, "n_records": len(records)},
        )
        settings = {**res.settings, "band": self.band, "n_frequencies": int(freqs.size), "detrend": self.detrend}
        return res.replace(covariances={"crb": cov, "sandwich": covs["sandwich"]}, settings=settings)
