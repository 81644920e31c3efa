"""pipeline.uncertainty."""
