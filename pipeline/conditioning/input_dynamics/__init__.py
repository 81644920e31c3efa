"""The dynamics between a logged control input and the surface it moves: a pure delay and
a first-order lag per surface, estimated from the maneuvers and applied before estimation.

A log's surface position is often the servo *command* (ArduPilot RCOU/AETR, PX4 actuator
outputs, MAVLink SERVO_OUTPUT_RAW): the surface follows it through the servo's transport
delay and lag, tens of milliseconds on small-UAV servos. A measured position can instead
lag the surface (a filtered potentiometer: a negative delay). Output error and filter
error take the inputs as exact; at a 2 Hz short period a 40 ms delay is 29 deg of phase,
which a fit books on the damping and the control derivative. A pure delay does not stand
in for a lag, so both are estimated.

Model of surface s (:mod:`.model`): delta_s(t) = L_tau_s[u_s](t - d_s), L_tau the
first-order lag 1 / (tau s + 1) (tau = 0: none), d the delay (> 0: the surface acts after
the logged value).

Estimate (:mod:`.estimate`, :mod:`.regression`; equation error, no aircraft data needed):
the angular acceleration of each surface's axis (de -> pitch, da -> roll, dr -> yaw) is
regressed on the measured variables,

    omega_dot(t) = a_k + sum_i c_i x_i(t) + sum_s b_s delta_s(t)          (k: the maneuver)

over the maneuvers on that surface, with x = p, q, r, the air-data angles (alpha, else
az; the sideslip is needed for the aileron and rudder), V and the throttle; the rates
scaled by V / V_ref, the angles, the surfaces and a constant by (V / V_ref)^2 (the dynamic
pressure's share of each moment term). Every surface's (d, tau) is found over all the
equations at once (variable projection: the linear coefficients solved for inside a
bounded least squares in the delays and lags, each equation weighted by its residual
rms), from a start where each equation's surfaces share one (d, tau) found on a grid
(aileron and rudder flown together: one surface at a time stayed at the other's start).
omega_dot is the central difference of the gyro rate, and the response and every
regressor are low-passed by the same zero-phase filter: it commutes with the linear
relation and with the lag, so the regression stays consistent while the differentiated
gyro noise above the maneuvers' band goes. The surfaces are read between samples by
cubic convolution (smooth in the delay).

std: the Cramér-Rao bound of the joint least squares, corrected for coloured residuals
(Morelli-Klein, :func:`estimators.covariance.uncertainty.morelli_klein`), widened to the
delete-a-group jackknife over the maneuvers where that is larger (the maneuvers disagree
by more than one fit's residuals say). A surface's dynamics are applied
(:func:`with_input_dynamics`) when its equivalent delay d + tau (the phase at low
frequency) is at least SIGNIFICANT std from zero and at least MIN_APPLIED_S (positive: a
log lagging its surface by 10 ms or more would need a position sensor filtered that
slowly), and neither estimate sits at an end of its range (DELAY_RANGE_S, LAG_RANGE_S:
equation error is biased in turbulence).

Refined by output error (:mod:`.refinement`, run by the pipeline when output error is
among the methods): the applied delays and lags are moved to where the output-error fits
match the data best (Gauss-Newton with the derivatives profiled out). Output error sees a
lag in every output, where equation error sees one differentiated rate. The refined std
is at least REFINE_MIN_STD_S, and widened to the difference from equation error where the
two disagree.

Known limit: with the commands or the gyros logged slowly (25 Hz and below) a delay and a
lag of a few samples trade against each other and equation error can put dynamics on a
surface that has none; the run withdraws them when output error converges with the inputs
as logged (:func:`logged_inputs_fit_better`), and steps between slow samples are timed
from the gyros instead (:mod:`pipeline.conditioning.input_sampling`).
"""

from pipeline.conditioning.input_dynamics.estimate import covariance, estimate_input_dynamics, summary
from pipeline.conditioning.input_dynamics.model import cubic_at, lagged, with_input_dynamics
from pipeline.conditioning.input_dynamics.refinement import logged_inputs_fit_better, refine_by_output_error

__all__ = [
    "covariance",
    "cubic_at",
    "estimate_input_dynamics",
    "lagged",
    "logged_inputs_fit_better",
    "refine_by_output_error",
    "summary",
    "with_input_dynamics",
]
