"""estimators.filters: the estimators with process noise.

Filter error (:class:`~estimators.filters.filter_error.FilterError`): ``filter_error``
(the iterations and the result), ``fem_problem`` (the data, the parameter vector and the
batched steady-state filter run), ``fem_information`` (information and covariances),
``fem_relaxation`` (the innovation covariance R and the process noise F),
``steady_state`` (discretisation, Riccati equations, gains), ``linearize``.

Kalman filters with the parameters in the state (:class:`~estimators.filters.ekf.EKF`,
:class:`~estimators.filters.ukf.UKF`): ``parameter_filter`` (the pass driver),
``filter_pass`` (a pass's pieces), ``augmented`` (the parameter-augmented model),
``update``, ``sigma_points``, ``gain_sensitivity`` (Ljung's modification).

Shared: ``noise`` (noise settings, covariance matching), ``loops`` (the per-sample loops
written for numba) and ``kernels`` (the model's compiled filter kernel module built from
them).

Nothing is imported here: the ``estimators`` package imports each estimator's module on
first use.
"""
