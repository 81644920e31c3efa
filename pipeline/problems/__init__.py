"""pipeline.problems."""
