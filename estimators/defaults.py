"""The estimators' tuning constants in one place: tolerances, step sizes, iteration limits, thresholds.

Each module reads its constants from here (a keyword argument, where there is one,
takes its default from here). Values are in SI units unless the name says otherwise.
Changing one here changes the default of every estimator that uses it.
"""

from __future__ import annotations

# -- data segments -------------------------------------------------------------------------
#: a sample interval longer than GAP_FACTOR times the segment's median interval is a gap:
#: the estimators step the model from sample to sample and would cross it in one step, as
#: if the aircraft had flown on unobserved with the inputs interpolated across. Logger
#: jitter and a few dropped samples stay below it
GAP_FACTOR = 5.0

# -- integration and compiled kernels ---------------------------------------------------------
#: relative and absolute tolerance of the adaptive integrator (rkf45)
RTOL, ATOL = 1e-8, 1e-10
#: a compiled kernel is used only when its state derivatives at a probe point agree with
#: the numpy evaluation to these relative and absolute tolerances
JIT_CHECK_RTOL, JIT_CHECK_ATOL = 1e-9, 1e-12
#: days a kernel module kept on disk may go unused, and the cache folder's size in MB,
#: before pruning removes it (``FSID_CACHE_DAYS``, ``FSID_CACHE_MB`` override them)
CACHE_DAYS, CACHE_MB = 30.0, 500.0

# -- information matrix and result ---------------------------------------------------------
#: eigenvalue of the scaled information matrix (relative to its largest) below which a
#: direction in parameter space counts as unidentifiable
SINGULAR_RTOL = 1e-11
#: a diagonal element of the information matrix below this fraction of the largest means
#: the parameter has no effect on the outputs (round-off of the largest)
UNINFORMED_RTOL = 1e-30
#: correlation magnitude above which a pair of estimates is flagged
CORR_FLAG = 0.9

# -- output error: Gauss-Newton -------------------------------------------------------------
#: relative finite-difference step: parameter j moves by FD_STEP * max(|theta_j|, 1)
FD_STEP = 1e-6
#: most Gauss-Newton iterations of a fit
MAX_ITER = 50
#: convergence when the relative change of det(R) (or J for a fixed R) between iterations is below it
TOL = 1e-6
#: most halvings of a Gauss-Newton step that does not lower the cost
STEP_HALVINGS = 10
#: Levenberg-Marquardt damping: its start, its floor, and the factor it shrinks by after
#: an accepted step and grows by after a rejected one
LM_LAMBDA_START, LM_LAMBDA_MIN, LM_LAMBDA_FACTOR = 1e-3, 1e-10, 10.0
#: a free parameter within BOUND_RTOL * max(1, |theta|) of a bound counts as on it for the
#: active set of bounded-variable Gauss-Newton
BOUND_RTOL = 1e-12
#: a final estimate within this relative distance of a bound is reported at the bound (no
#: Cramér-Rao bound: the likelihood is not stationary there)
AT_BOUND_RTOL = 1e-9
#: a rejected step whose predicted decrease 1/2 G^T delta is below DESCENT_RTOL * max(J, 1)
#: means no descent is left: converged to round-off
DESCENT_RTOL = 1e-10

# -- output error: Nelder-Mead start ---------------------------------------------------------
#: initial simplex: each vertex moves one parameter by this fraction of its start value
SIMPLEX_STEP = 0.2
#: a start value smaller than this in magnitude is scaled by 1 instead of by itself
SIMPLEX_SCALE_MIN = 1e-8
#: most cost evaluations: max(SIMPLEX_MIN_EVALS, SIMPLEX_EVALS_PER_PARAMETER * n_free)
SIMPLEX_MIN_EVALS, SIMPLEX_EVALS_PER_PARAMETER = 600, 200
#: Nelder-Mead stopping tolerances on the scaled parameters and on the cost
SIMPLEX_XATOL, SIMPLEX_FATOL = 1e-6, 1e-8

# -- output error: divergence and fit diagnostics ------------------------------------------
#: a simulated output further from the data's median than this many times the data's own
#: largest deviation from it counts as a diverged (runaway) simulation: an unstable model
#: integrated open loop grows exponentially long before it overflows to Inf
RUNAWAY_FACTOR = 1e3
#: an output is not followed when its residuals' lag-1 autocorrelation exceeds FOLLOW_LAG1
#: and their variance FOLLOW_SHARE times the measured output's: a slow misfit that is a
#: large part of the signal, not noise (coloured residuals alone are common in a good fit)
FOLLOW_LAG1 = 0.8
FOLLOW_SHARE = 0.1

# -- validation: modes -----------------------------------------------------------------------
#: an eigenvalue smaller than this in magnitude (1/s) counts as a zero root (height, heading)
MODE_ZERO_TOL = 1e-6
#: relative and absolute central-difference step of the numerical linearisation:
#: max(LINEARIZE_STEP, LINEARIZE_STEP |value|)
LINEARIZE_STEP = 1e-5

# -- equation error ---------------------------------------------------------------------------
#: recursive least squares: the initial covariance P = RLS_P0 * I (large: a diffuse start)
RLS_P0 = 1e6

# -- unstable aircraft: stabilised output error, eigenvalue transformation, fed-back noise --
#: process-noise scales (times the largest measurement variance) tried in turn for the
#: default stabilisation gain: the smallest for which the Riccati equation solves
STABILIZER_Q_SCALES = (1e-9, 1e-7, 1e-5, 1e-3)
#: the default eigenvalue shift: this much (1/s) above the largest real part of the
#: linearised start model's eigenvalues
SIGMA_MARGIN = 0.5
#: a fed-back model that grows more than this factor over a segment is not propagated
FED_GROWTH_LIMIT = 1e3
#: relative central-difference step of a pseudo-input function's derivative by each measurement
PSEUDO_FD_STEP = 1e-6

# -- validation: maneuver scatter ----------------------------------------------------------
#: robust std / Cramér-Rao bound above which a parameter is flagged
CLUSTER_FLAG_RATIO = 3.0
#: fewest maneuvers for which the covariance is reported: with 2 it has one degree of
#: freedom, but still tells an honest bound from a several times optimistic one
CLUSTER_MIN_SEGMENTS = 2
#: a parameter whose information one maneuver carries more than this share of has no
#: maneuver scatter to measure
CLUSTER_SHARE_LIMIT = 0.95

# -- validation: proof of match, residuals, plausibility ------------------------------------
#: default tolerance bands: body rates (deg/s), specific forces (g), angles (deg)
POM_RATE_DEG_S, POM_ACCEL_G, POM_ANGLE_DEG = 1.5, 0.1, 1.5
#: the chance that white measurement noise alone fails a channel of the proof of match
#: when its level is given (``proof_of_match(noise_std=...)``)
NOISE_ALPHA = 0.05
#: a miss counts as within the prediction's own uncertainty up to this many of its std
#: (``proof_of_match(prediction_std=...)``; pointwise, about 95 % per sample)
PREDICTION_K = 2.0
#: significance level of the residual whiteness test
WHITENESS_ALPHA = 0.05
#: an estimate further than this many (combined) std from an a-priori value, or from
#: another method's estimate, is flagged
PLAUSIBILITY_K = 3.0
