"""Output error: the model simulated open loop against measurement noise only.

:mod:`.oem` (the :class:`~estimators.OutputError` estimator), :mod:`.likelihood` (the
likelihood of one fit: simulation, residuals, sensitivities, cost), :mod:`.diagnostics`
(runaway simulations, a fit that does not follow the data), :mod:`.stabilized` (the
variants for unstable aircraft) and :mod:`.pseudo_input_noise` (their covariance with
measurements fed back). The submodules are imported on their own so that a plain output
error fit does not load the unstable variants' dependencies.
"""
