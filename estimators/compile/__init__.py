"""estimators.compile."""
