"""readers stage (in progress)."""
