"""The bus package's errors (set-up and programmer errors; junk from the peer is never raised)."""

from __future__ import annotations

from common.errors import HilError


class CatalogError(HilError):
    """The message catalog is inconsistent (duplicate ID, signal overlap...)."""


class EncodeError(HilError):
    """We tried to encode a value that the catalog does not allow (programmer error)."""


class BusError(HilError):
    """The transport could not be opened or used (interface missing, permission denied)."""
