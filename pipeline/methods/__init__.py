"""pipeline.methods."""
