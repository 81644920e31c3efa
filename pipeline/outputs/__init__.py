"""pipeline.outputs."""
