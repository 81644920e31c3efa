"""Transfer functions with a time delay fitted in the frequency domain, and the short-period
low-order equivalent system's handling-qualities figures.

H(s) = (b_m s^m + ... + b_0) e^{-tau s} / (s^n + a_(n-1) s^(n-1) + ... + a_0)

From time histories (``fit(t, u, y, w=...)``) the input and output are transformed once
(:func:`estimators.frequency.transform.fourier_transform`) and fitted at the frequencies w:

- equation error ("ee"): A(jw) Y = B(jw) e^{-jw tau} U + v, linear in a and b for a given
  delay; the delay by a one-dimensional search. Fast, biased by output noise.
- output error ("oe"): v = Y - H(jw) U, Gauss-Newton from the equation-error estimate.

Both report Cramér-Rao bounds from M = Re sum_k dv_k^* dv_k / s2 with the residual variance
s2 = sum_k |v_k|^2 / n_f (the reference software's convention), and the result's
"sandwich" covariance view measured from the residuals
(:mod:`estimators.frequency.covariance`).

To a :class:`~estimators.frequency.response.FrequencyResponse` (``fit(fr, f_band=...)``)
the fit minimises CIFER's coherence-weighted magnitude and phase cost (Tischler & Remple,
2012, ch. 11): J = 20/n_f sum_k W_gamma [(|T_c| - |T|)^2 + 0.01745 (angle T_c - angle
T)^2] with magnitudes in dB, phases in degrees and W_gamma = [1.58 (1 - e^{-gamma^2})]^2;
J <= 100 is the usual acceptance. Its bounds treat the weighted residuals as the
measurement noise: cov = s2 (R^T R)^-1 with s2 = sum r^2 / (2 n_f).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd
from scipy.optimize import least_squares, minimize_scalar

from estimators.errors import ModelDefinitionError
from estimators.frequency.covariance import frequency_covariances
from estimators.frequency.response import FrequencyResponse
from estimators.frequency.transform import fourier_transform, uniform_step
from estimators.model import Model, Parameter
from estimators.results import EstimationResult

#: CIFER's weights of the phase (deg^2 against dB^2) and of the coherence
PHASE_WEIGHT = 0.01745
#: the delay search's upper end as a multiple of the longest period fitted
DELAY_MAX_PERIODS = 0.5
DELAY_GRID_MAX = 4000
#: output error's Gauss-Newton: iterations and relative cost change that ends them
MAX_ITER = 100
COST_RTOL = 1e-10


def coherence_weight(gamma2: np.ndarray) -> np.ndarray:
    """CIFER's W_gamma = [1.58 (1 - exp(-gamma^2))]^2 (1 at gamma^2 = 1)."""
    return (1.58 * (1 - np.exp(-np.asarray(gamma2, dtype=float)))) ** 2


class TransferFunction:
    """A transfer function of ``num_order`` zeros and ``den_order`` poles (monic
    denominator), with a pure time delay when ``delay`` is True (module docstring).

    Parameters are named b<m>..b0, a<n-1>..a0 and tau (s), in that order.
    """

    def __init__(self, num_order: int, den_order: int, delay: bool = False) -> None:
        if not (0 <= num_order <= den_order and den_order >= 1):
            raise ModelDefinitionError(
                f"a transfer function needs 0 <= num_order <= den_order and den_order >= 1, got {num_order}/{den_order}"
            )
        self.num_order, self.den_order, self.delay = int(num_order), int(den_order), bool(delay)

    # -- names and evaluation -------------------------------------------------------------
    @property
    def names(self) -> list[str]:
        m, n = self.num_order, self.den_order
        return (
            [f"b{k}" for k in range(m, -1, -1)]
            + [f"a{k}" for k in range(n - 1, -1, -1)]
            + (["tau"] if self.delay else [])
        )

    def split(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(num (m+1,) descending, den (n+1,) descending and monic, tau) of a parameter vector."""
        m = self.num_order + 1
        num = np.asarray(theta[:m], dtype=float)
        den = np.concatenate([[1.0], theta[m : m + self.den_order]])
        tau = float(theta[-1]) if self.delay else 0.0
        return num, den, tau

    def response(self, theta: np.ndarray, w: np.ndarray) -> np.ndarray:
        """H(jw) (n_f,) complex."""
        num, den, tau = self.split(theta)
        s = 1j * np.asarray(w, dtype=float)
        return np.polyval(num, s) / np.polyval(den, s) * np.exp(-s * tau)

    def _dH(self, theta: np.ndarray, w: np.ndarray) -> np.ndarray:
        """dH/dtheta (n_f, n_p), analytic."""
        num, den, tau = self.split(theta)
        s = 1j * w
        B, A, E = np.polyval(num, s), np.polyval(den, s), np.exp(-s * tau)
        cols = [s**k * E / A for k in range(self.num_order, -1, -1)]
        cols += [-(s**k) * B * E / A**2 for k in range(self.den_order - 1, -1, -1)]
        if self.delay:
            cols.append(-s * B / A * E)
        return np.column_stack(cols)

    # -- fits ------------------------------------------------------------------------------
    def fit(
        self,
        t: Any,
        u: np.ndarray | None = None,
        y: np.ndarray | None = None,
        *,
        w: np.ndarray | None = None,
        method: str = "oe",
        detrend: str = "ends",
        start: Mapping[str, float] | None = None,
        f_band: tuple[float, float] | None = None,
    ) -> EstimationResult:
        """Fit to time histories ``t`` (N,), ``u`` (N,), ``y`` (N,) at the frequencies ``w``
        (rad/s; default 100 log-spaced from two periods of the record to a tenth of the
        sample rate) by ``method`` "ee" or "oe"; or, when ``t`` is a FrequencyResponse, to
        that response over ``f_band`` (Hz; default all of it) by CIFER's cost."""
        if isinstance(t, FrequencyResponse):
            return self._fit_response(t, f_band, start)
        if u is None or y is None:
            raise ModelDefinitionError("TransferFunction.fit needs t, u and y (or a FrequencyResponse)")
        if method not in ("ee", "oe"):
            raise ModelDefinitionError(f"method={method!r}: use 'ee' (equation error) or 'oe' (output error)")
        t = np.asarray(t, dtype=float)
        dt = uniform_step(t, "TransferFunction.fit")
        if w is None:
            T = t[-1] - t[0]
            w = 2 * np.pi * np.geomspace(2.0 / T, 0.1 / dt, 100)
        w = np.asarray(w, dtype=float)
        if w.size <= len(self.names):
            raise ModelDefinitionError(f"{w.size} frequencies cannot determine {len(self.names)} parameters")
        U = fourier_transform(t, np.asarray(u, dtype=float).ravel(), w, detrend)
        Y = fourier_transform(t, np.asarray(y, dtype=float).ravel(), w, detrend)
        theta, it, hist = self._equation_error(w, U, Y, start)
        if method == "oe":
            theta, it, hist = self._output_error(w, U, Y, theta)
        v = Y - self.response(theta, w) * U if method == "oe" else self._ee_residual(theta, w, U, Y)
        J = -self._dH(theta, w) * U[:, None] if method == "oe" else self._ee_jacobian(theta, w, U, Y)
        s2 = float(np.real(np.vdot(v, v))) / w.size
        covs = frequency_covariances(J[:, None, :], v[:, None], np.array([[1.0 / s2]]))
        extra = {"w": w, "U": U, "Y": Y, "residuals_f": v}
        return self._result(f"tf-{method}", theta, covs, s2, it, hist, w, extra)

    def _ee_residual(self, theta: np.ndarray, w: np.ndarray, U: np.ndarray, Y: np.ndarray) -> np.ndarray:
        num, den, tau = self.split(theta)
        s = 1j * w
        return np.polyval(den, s) * Y - np.polyval(num, s) * np.exp(-s * tau) * U

    def _ee_jacobian(self, theta: np.ndarray, w: np.ndarray, U: np.ndarray, Y: np.ndarray) -> np.ndarray:
        num, _, tau = self.split(theta)
        s = 1j * w
        E = np.exp(-s * tau)
        cols = [-(s**k) * E * U for k in range(self.num_order, -1, -1)]
        cols += [s**k * Y for k in range(self.den_order - 1, -1, -1)]
        if self.delay:
            cols.append(s * np.polyval(num, s) * E * U)
        return np.column_stack(cols)

    def _ee_solve(self, w: np.ndarray, U: np.ndarray, Y: np.ndarray, tau: float) -> tuple[np.ndarray, float]:
        """(a and b for the delay tau, residual sum of squares): linear least squares."""
        s = 1j * w
        E = np.exp(-s * tau)
        X = np.column_stack(
            [s**k * E * U for k in range(self.num_order, -1, -1)]
            + [-(s**k) * Y for k in range(self.den_order - 1, -1, -1)]
        )
        z = s**self.den_order * Y
        Xr, zr = np.vstack([X.real, X.imag]), np.concatenate([z.real, z.imag])
        coef, *_ = np.linalg.lstsq(Xr, zr, rcond=None)
        r = zr - Xr @ coef
        return coef, float(r @ r)

    def _equation_error(
        self, w: np.ndarray, U: np.ndarray, Y: np.ndarray, start: Mapping[str, float] | None
    ) -> tuple[np.ndarray, int, list[dict]]:
        """The equation-error estimate; the delay by a grid then a bounded scalar search (or
        the start's delay when given)."""
        if not self.delay:
            coef, sse = self._ee_solve(w, U, Y, 0.0)
            return coef, 1, [{"cost": sse}]
        if start and "tau" in start:
            tau = float(start["tau"])
        else:
            # the cost repeats in tau with period 2 pi / w_max: a grid four times finer, up
            # to half the longest period fitted
            hi = DELAY_MAX_PERIODS * 2 * np.pi / max(w.min(), 1e-9)
            n_grid = int(min(np.ceil(hi / (0.25 * np.pi / w.max())), DELAY_GRID_MAX)) + 1
            grid = np.linspace(0.0, hi, n_grid)
            sse = np.array([self._ee_solve(w, U, Y, g)[1] for g in grid])
            k = int(np.argmin(sse))
            lo_g, hi_g = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
            tau = float(
                minimize_scalar(
                    lambda x: self._ee_solve(w, U, Y, x)[1],
                    bounds=(lo_g, hi_g),
                    method="bounded",
                    options={"xatol": 1e-7},
                ).x
            )
        coef, sse = self._ee_solve(w, U, Y, tau)
        return np.concatenate([coef, [tau]]), 1, [{"cost": sse}]

    def _output_error(
        self, w: np.ndarray, U: np.ndarray, Y: np.ndarray, theta: np.ndarray
    ) -> tuple[np.ndarray, int, list[dict]]:
        """Gauss-Newton on sum |Y - H U|^2 with step halving."""

        def cost(th: np.ndarray) -> float:
            v = Y - self.response(th, w) * U
            return float(np.real(np.vdot(v, v)))

        c = cost(theta)
        hist = [{"cost": c}]
        it = 0
        for it in range(1, MAX_ITER + 1):
            v = Y - self.response(theta, w) * U
            J = -self._dH(theta, w) * U[:, None]
            A = np.real(J.conj().T @ J)
            g = np.real(J.conj().T @ v)
            step = -np.linalg.lstsq(A, g, rcond=None)[0]
            alpha, new = 1.0, np.inf
            while alpha > 1e-6:
                trial = theta + alpha * step
                new = cost(trial)
                if np.isfinite(new) and new <= c:
                    break
                alpha /= 2
            if not (np.isfinite(new) and new <= c):
                break
            theta, done = trial, abs(c - new) <= COST_RTOL * max(c, 1e-300)
            c = new
            hist.append({"iteration": it, "cost": c, "step": alpha})
            if done:
                break
        return theta, it, hist

    def _fit_response(
        self, fr: FrequencyResponse, f_band: tuple[float, float] | None, start: Mapping[str, float] | None
    ) -> EstimationResult:
        if fr.H.shape[1:] != (1, 1):
            raise ModelDefinitionError(
                f"TransferFunction.fit takes one input-output pair; use fr.select(output, input) (this one has "
                f"{fr.H.shape[1]} outputs, {fr.H.shape[2]} inputs)"
            )
        keep = np.ones(fr.f.size, dtype=bool) if f_band is None else (fr.f >= f_band[0]) & (fr.f <= f_band[1])
        keep &= np.isfinite(fr.H[:, 0, 0]) & (np.abs(fr.H[:, 0, 0]) > 0)
        if keep.sum() <= len(self.names):
            raise ModelDefinitionError(
                f"{keep.sum()} frequencies in {f_band} Hz cannot determine {len(self.names)} parameters"
            )
        w, T, g2 = fr.w[keep], fr.H[keep, 0, 0], fr.coherence[keep, 0, 0]
        Wg = coherence_weight(g2)
        n = w.size
        ones = np.ones_like(T)
        # a start from equation error on the response itself (U = 1, Y = T), coherence-weighted
        theta0, _, _ = self._equation_error(w, ones * np.sqrt(Wg), T * np.sqrt(Wg), start)
        if start:
            theta0 = np.array([start.get(k, v) for k, v in zip(self.names, theta0)])
        mag_d, ph_d = 20 * np.log10(np.abs(T)), np.degrees(np.angle(T))
        scale = np.sqrt(20.0 / n * Wg)

        def resid(th: np.ndarray) -> np.ndarray:
            Hc = self.response(th, w)
            dm = 20 * np.log10(np.abs(Hc)) - mag_d
            dp = (np.degrees(np.angle(Hc)) - ph_d + 180.0) % 360.0 - 180.0
            return np.concatenate([scale * dm, scale * np.sqrt(PHASE_WEIGHT) * dp])

        sol = least_squares(resid, theta0, method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=4000)
        r = sol.fun
        J = float(r @ r)
        s2 = J / (2 * n)
        covs = {"crb": s2 * np.linalg.pinv(sol.jac.T @ sol.jac)}
        extra = {"J": J, "f_band": f_band, "w": w, "coherence": g2}
        return self._result("tf-fr", sol.x, covs, s2, int(sol.nfev), [{"cost": J}], w, extra, converged=sol.success)

    def _result(
        self,
        method: str,
        theta: np.ndarray,
        covs: dict[str, np.ndarray],
        s2: float,
        iterations: int,
        hist: list[dict],
        w: np.ndarray,
        extra: dict[str, Any],
        converged: bool = True,
    ) -> EstimationResult:
        num, den, tau = self.split(theta)
        H = self.response(theta, w)
        f = pd.Index(w / (2 * np.pi), name="f_hz")
        pred = [pd.DataFrame({"H": H}, index=f)]
        resid = [pd.DataFrame({"v": extra["residuals_f"]}, index=f)] if "residuals_f" in extra else []
        return EstimationResult(
            method=method,
            model=self.state_space_model(theta),
            names=self.names,
            values=np.asarray(theta, dtype=float),
            free=np.ones(len(self.names), dtype=bool),
            cov=covs["crb"],
            covariances=covs,
            R=np.array([[s2]]),
            converged=converged,
            iterations=iterations,
            history=pd.DataFrame(hist),
            predicted=pred,
            residuals=resid,
            settings={"num_order": self.num_order, "den_order": self.den_order, "delay": self.delay},
            extra={**extra, "num": num, "den": den, "tau": tau},
        )

    def state_space_model(self, theta: np.ndarray | None = None) -> Model:
        """The transfer function (without its delay) as an estimators Model in
        controllable canonical form: states x1..xn, input u, output y; its parameters are
        the transfer function's (tau kept as a parameter the equations do not use: delay
        the input by it to simulate)."""
        m, n = self.num_order, self.den_order
        theta = np.zeros(len(self.names)) if theta is None else np.asarray(theta, dtype=float)
        names = self.names
        bnames = names[: m + 1][::-1]  # b0..bm
        anames = names[m + 1 : m + 1 + n][::-1]  # a0..a(n-1)

        def f(x, u, p, c):
            rows = [x[k + 1] for k in range(n - 1)]
            rows.append(-sum(p[anames[k]] * x[k] for k in range(n)) + u[0])
            return tuple(rows)

        def g(x, u, p, c):
            # y = sum_k (b_k - b_n a_k) x_(k+1) + b_n u with b_n the s^n coefficient (0 unless m == n)
            bn = p[bnames[n]] if m == n else 0.0
            y = sum((p[bnames[k]] if k <= m else 0.0) * x[k] - bn * p[anames[k]] * x[k] for k in range(n))
            return (y + bn * u[0],)

        return Model(
            states=[f"x{k + 1}" for k in range(n)],
            inputs=["u"],
            outputs=["y"],
            parameters=[Parameter(nm, float(v)) for nm, v in zip(names, theta)],
            f=f,
            g=g,
            name=f"tf {m}/{n}" + (" delay" if self.delay else ""),
        )


def loes_parameters(res: EstimationResult) -> dict[str, float]:
    """The short-period low-order equivalent system's figures from a fitted pitch-rate
    transfer function q/de = (b1 s + b0) e^{-tau s} / (s^2 + a1 s + a0):
    omega_sp = sqrt(a0) (rad/s), zeta_sp = a1 / (2 omega_sp), 1/T_theta2 = b0 / b1 (1/s),
    tau (s; 0 without a delay), and the gain b1."""
    p = res.params
    need = ("b1", "b0", "a1", "a0")
    if any(k not in p.index for k in need) or "b2" in p.index or "a2" in p.index:
        raise ModelDefinitionError("loes_parameters needs the fit of TransferFunction(num_order=1, den_order=2)")
    a0, a1, b0, b1 = (float(p[k]) for k in ("a0", "a1", "b0", "b1"))
    if a0 <= 0:
        raise ModelDefinitionError(f"a0 = {a0:.4g}: the fitted denominator has no oscillatory short period")
    omega = float(np.sqrt(a0))
    return {
        "omega_sp": omega,
        "zeta_sp": a1 / (2 * omega),
        "one_over_T_theta2": b0 / b1,
        "tau": float(p["tau"]) if "tau" in p.index else 0.0,
        "gain": b1,
    }
