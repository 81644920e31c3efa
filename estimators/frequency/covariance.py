"""Parameter covariances of frequency-domain fits.

The reference software states M^-1 with M = Re sum_k dv_k^H S^-1 dv_k ("crb"). For residuals
that are circular complex and alike at every frequency that covariance is twice the scatter
of the estimates (the positive frequencies carry the information of the whole real record,
which the complex-Gaussian likelihood counts twice), and for residuals whose level changes
across the band (coloured noise, gusts, equation error's A(jw)-weighted residuals) it can
be too small. The "sandwich" covariance M^-1 (sum_k s_k s_k^T) M^-1 with the scores
s_k = Re(dv_k^H S^-1 v_k) measures the scatter from the residuals themselves and holds in
both cases (White's heteroscedasticity-consistent estimator, frequency by frequency, whose
residuals are nearly independent at a spacing of at least 1/T). Each score is divided by
sqrt(1 - h_k), h_k = tr(M^-1 M_k) the leverage of the frequency's real and imaginary
equations together - for small leverage the per-equation 1/(1 - h) of MacKinnon and White's
HC3, the small-sample form: where a few frequencies carry the information (gusts at the low
end of a short band) the fitted residuals are smaller than the errors there, and the plain
sandwich is too small with them.
"""

from __future__ import annotations

import numpy as np

#: the largest leverage used in the HC2 correction (a frequency that alone sets a parameter
#: would otherwise divide by nearly zero)
MAX_LEVERAGE = 0.9


def frequency_covariances(J: np.ndarray, v: np.ndarray, S_inv: np.ndarray) -> dict[str, np.ndarray]:
    """{"crb": M^-1, "sandwich": M^-1 B M^-1} (n_p, n_p) (B from the leverage-corrected
    scores) from the residual sensitivities J
    (n_f, n_y, n_p) complex, the residuals v (n_f, n_y) complex and the inverse residual
    spectral covariance S_inv (n_y, n_y) (module docstring)."""
    M_k = np.real(np.einsum("fyp,yz,fzq->fpq", np.conj(J), S_inv, J))
    M = M_k.sum(axis=0)
    Minv = np.linalg.pinv(0.5 * (M + M.T))
    leverage = np.clip(np.einsum("pq,fqp->f", Minv, M_k), 0.0, MAX_LEVERAGE)
    s = np.real(np.einsum("fyp,yz,fz->fp", np.conj(J), S_inv, v)) / np.sqrt(1.0 - leverage)[:, None]
    sw = Minv @ (s.T @ s) @ Minv
    return {"crb": Minv, "sandwich": 0.5 * (sw + sw.T)}
