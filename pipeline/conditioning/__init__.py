"""pipeline.conditioning."""
