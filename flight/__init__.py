"""flight package."""
