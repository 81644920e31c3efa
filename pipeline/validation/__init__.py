"""pipeline.validation."""
