"""dataset stage (in progress)."""
