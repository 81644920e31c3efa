"""estimators.filters."""
