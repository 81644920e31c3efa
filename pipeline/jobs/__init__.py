"""pipeline.jobs."""
