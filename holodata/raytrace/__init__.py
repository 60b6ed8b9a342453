"""raytrace stage (in progress)."""
