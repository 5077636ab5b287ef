"""Sub-commands of `hil` owned by this module (placeholder until built)."""


def register(sub) -> None:  # noqa: ARG001
    """Add this module's sub-parsers to ``sub``."""
