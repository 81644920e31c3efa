"""Extended Kalman filter with the parameters in the state::

    ekf = EKF(model, process_noise={"alpha": 0.01, "q": 0.02},
              measurement_noise={"alpha": 1.7e-3, "q": 3.5e-3, ...})
    res = ekf.fit([seg1, seg2])
    res.params, res.std                    # final estimate and sqrt(diag P_theta)
    res.extra["trajectory"][0]             # parameter estimates over time (segment 0)

Jacobians of the integrator step Phi_h and of g with respect to s = [x; theta] by forward
differences, all perturbed columns in one vectorised model call; covariance update in
Joseph form P = (I - K H) P (I - K H)^T + K R K^T. The passes, noise settings and result
are :class:`~estimators.filters.parameter_filter.ParameterFilter`'s.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.filters.filter_pass import SegmentRun, SegmentStart, run_compiled
from estimators.filters.parameter_filter import ParameterFilter
from estimators.filters.update import joseph_update
from estimators.model import Model


class EKF(ParameterFilter):
    """Extended Kalman filter with the parameters in the state (Joseph-form update).

    Parameters
    ----------
    model : the :class:`~estimators.Model` (free parameters are estimated).
    integrator : one-step predictor, "euler" ... "rk4" (default) or "rkf45".
    process_noise : F: {state: std}, (n,) std or an (n, n) matrix; continuous white noise
        in state units per sqrt(s), Qd = F F^T dt. Default 0 (calm air).
    measurement_noise : {output: std}, (n_out,) std or an (n_out, n_out) covariance.
        Default: the white-noise level of each output's second differences (errs high:
        signal curvature and process noise count as noise), adapted pass by pass.
    adapt_noise : covariance matching between passes (Mehra; Myers and Tapley): "auto"
        (default) adapts R when ``measurement_noise`` is not given, True adapts R and the
        process noise of the states that have some (diagonal ``process_noise``), "R" or
        "Q" one of them, False none. R's diagonal is set to the innovations' spread less
        the filter's predicted output spread; F is scaled by sqrt(observed / expected
        spread of the state corrections K nu). The next pass runs with them;
        ``extra["measurement_noise"]``/``["process_noise"]`` are those of the last pass,
        ``extra["noise_moves"]`` the largest relative change of a noise std per pass. R
        held at the second-difference default errs high and biases the estimates; adapted,
        it approaches the true R. Adapting F suits process noise that is white; where it
        stands in for coloured gusts it finds too little.
    param_std : initial std of the parameters: {name: std}, a fraction of |start| (float),
        default 0.5 |start| (1.0 where the start is 0 - give biases explicitly).
    state_std : initial std of the states, {state: std} or (n,); default the measurement
        std of states that are outputs; for a state that is not an output but has process
        noise (a gust state) the stationary spread of its own dynamics at each segment
        start (F sqrt(tau/2) for a first-order gust: the gust at a segment start is
        unknown, not 0); 1e-3 max(|x0|, 1) otherwise.
    param_noise : random-walk std of the parameters per sqrt(s) (default 0: constant).
    inputs : input variation over a sample interval in the prediction step, as
        OutputError: "linear" (default) or "hold".
    passes : "auto" (default: repeat the pass from the last estimates until no free
        parameter moves by more than ``pass_tol`` (0.2) of its std, at most ``max_passes``
        (8)) or a fixed number of passes (see :meth:`fit`). A pass whose innovations'
        negative log-likelihood (``extra["innovation_nll"]``) is more than 3 std of it,
        sqrt(n_obs / 2), above the best pass's ends the passes: the best pass's result is
        kept and ``converged`` is False (``extra["not_settled"]`` says so). Not checked
        while the noise is adapted or in a pass that projected a parameter onto a bound.
    fd_step : relative forward-difference step of the Jacobians,
        h_j = fd_step * max(|s_j|, 1).
    callback : called as callback(pass, innovations' negative log-likelihood, params
        Series) after each pass (pass counts from 0), as OutputError's after each iteration.
    gain_sensitivity : Ljung's modification (default False): the state correction K_x nu
        depends on the parameters through the gain, which the plain filter neglects; with
        True, state-only filters at each parameter perturbation (relative step
        ``gain_step``, 1e-5) carry dK_x/dtheta, and after each update the covariance gets
        the term (dK_x/dtheta) nu in its state-parameter coupling (see
        :class:`~estimators.filters.gain_sensitivity.GainSensitivity`). With the noise known
        it makes the filter a recursive prediction-error estimator whose std is honest where
        the plain filter's is too small (a gust acting through a derivative); with the noise
        wrong it is biased as any prediction-error method. It runs the Python loop only
        (``compiled`` is ignored; several times slower).

    Parameter bounds (``Parameter(bounds=...)``) hold: every update is projected onto
    them, and a sigma point or difference step beyond a bound evaluates the model at the
    bound. A parameter projected in the last pass and ending within 3 std of its bound is
    reported in ``at_bounds`` with its std NaN (``extra["bound_hits"]``: projections per
    parameter in the last pass).
    """

    method = "ekf"

    def __init__(self, model: Model, *, fd_step: float = 1e-6, **kw) -> None:
        super().__init__(model, **kw)
        self.fd_step = fd_step

    def _compiled_segment(self, start: SegmentStart) -> SegmentRun | None:
        return run_compiled("ekf", start, float(self.fd_step))

    def _columns(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = self.fd_step * np.maximum(np.abs(s), 1.0)
        S = np.repeat(s[:, None], s.size + 1, axis=1)
        S[np.arange(s.size), 1 + np.arange(s.size)] += h
        return S, h

    def _predict(self, aug, s, P, Q, i):
        n = aug.n
        S, h = self._columns(s)
        Xn = aug.step(S, i)
        Phi = np.eye(s.size)
        Phi[:n, :] = (Xn[:, 1:] - Xn[:, :1]) / h
        s_new = s.copy()
        s_new[:n] = Xn[:, 0]
        P = Phi @ P @ Phi.T + Q
        return s_new, 0.5 * (P + P.T)

    def _update(self, aug, s, P, z, ok, R, i):
        S, h = self._columns(s)
        Y = aug.outputs(S, i)
        y = Y[:, 0]
        if not np.any(ok):
            return s, P, y, None, None
        H = ((Y[:, 1:] - Y[:, :1]) / h)[ok]
        P, K, Sinn = joseph_update(P, H, R[np.ix_(ok, ok)])
        return s + K @ (z[ok] - y[ok]), P, y, K, Sinn

    def _settings(self) -> dict[str, Any]:
        return {**super()._settings(), "fd_step": self.fd_step}
