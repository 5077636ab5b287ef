"""The shell's errors, and the whole exception tree gathered for the shell's ``except`` clauses.

Each package owns its errors (``common.errors`` the root and ``ConfigError``, ``bus.errors``,
``plant.errors``, ``flight.errors``); this module adds the command line's ``UsageError`` and
re-exports the others so that a shell module (or a test) names any of them from one place.
``hil.cli`` prints every ``HilError`` as one ``error: ...`` line and exits 2.
"""

from __future__ import annotations

from bus.errors import BusError, CatalogError, EncodeError
from common.errors import ConfigError, HilError, PeerError, Raw
from flight.errors import ThresholdError
from plant.errors import FaultCommandError

__all__ = [
    "BusError", "CatalogError", "ConfigError", "EncodeError", "FaultCommandError", "HilError",
    "PeerError", "Raw", "ThresholdError", "UsageError",
]


class UsageError(HilError):
    """A command-line argument is invalid (exit code 2)."""
