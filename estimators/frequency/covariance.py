"""Parameter covariances of frequency-domain fits.

The reference software states M^-1 with M = Re sum_k dv_k^H S^-1 dv_k ("crb"). For residuals
that are circular complex and alike at every frequency that covariance is twice the scatter
of the estimates (the positive frequencies carry the information of the whole real record,
which the complex-Gaussian likelihood counts twice), and for residuals whose level changes
across the band (coloured noise, gusts, equation error's A(jw)-weighted residuals) it can
be too small. The "sandwich" covariance M^-1 (sum_k s_k s_k^T) M^-1 with the scores
s_k = Re(dv_k^H S^-1 v_k) measures the scatter from the residuals themselves and holds in
both cases (White's heteroscedasticity-consistent estimator, frequency by frequency, whose
residuals are nearly independent at a spacing of at least 1/T).
"""

from __future__ import annotations

import numpy as np


def frequency_covariances(J: np.ndarray, v: np.ndarray, S_inv: np.ndarray) -> dict[str, np.ndarray]:
    """{"crb": M^-1, "sandwich": M^-1 B M^-1} (n_p, n_p) from the residual sensitivities J
    (n_f, n_y, n_p) complex, the residuals v (n_f, n_y) complex and the inverse residual
    spectral covariance S_inv (n_y, n_y) (module docstring)."""
    M = np.real(np.einsum("fyp,yz,fzq->pq", np.conj(J), S_inv, J))
    s = np.real(np.einsum("fyp,yz,fz->fp", np.conj(J), S_inv, v))
    Minv = np.linalg.pinv(0.5 * (M + M.T))
    sw = Minv @ (s.T @ s) @ Minv
    return {"crb": Minv, "sandwich": 0.5 * (sw + sw.T)}
