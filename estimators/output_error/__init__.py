"""estimators.output_error."""
