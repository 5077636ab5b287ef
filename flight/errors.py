"""The flight package's errors."""

from __future__ import annotations

from common.errors import HilError


class ThresholdError(HilError):
    """No detector threshold fits the requirements given (``flight.thresholds.propose``)."""
