"""The parameters' covariance beyond the plain Cramér-Rao bound: coloured-residual
correction (Morelli-Klein), maneuver scatter (each maneuver a cluster), correlation.
Below every estimator and :mod:`estimators.validation`, which all read it."""
