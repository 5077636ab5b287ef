"""plant package."""
