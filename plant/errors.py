"""The plant package's errors."""

from __future__ import annotations

from common.errors import HilError


class FaultCommandError(HilError):
    """A fault to inject is invalid (unknown thruster, fraction out of [0, 1], negative time...)."""
