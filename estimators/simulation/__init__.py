"""estimators.simulation."""
