"""The root of the project's exception tree, and the error every package's configuration shares.

Two families are kept apart (house style, habit 5):

* ``HilError`` subclasses raised at set-up time or on programmer error ("we misused it"):
  bad configuration, bad CLI argument, bad fault command, encoding a value out of range.
  Each package owns its own: ``bus.errors`` (catalog, encode, transport), ``plant.errors``
  (fault commands), ``flight.errors`` (threshold proposal), ``hil.errors`` (command line).
* ``PeerError`` subclasses describe junk that came from the other side of the bus. The
  receive loops never let them escape: they become counters and events.

Messages follow one form: ``<where>: <what was expected>, got <what was found>``.
"""

from __future__ import annotations

SHOWN_MAX_CHARS = 120


def one_line(text: str) -> str:
    """``text`` with every non-printable character escaped (a key holding a newline or a
    carriage return must not break the one-line error)."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class HilError(Exception):
    """Root of every exception the project raises on purpose."""


class Raw(str):
    """A ``found`` value printed as is (not quoted), e.g. ``nothing`` for a missing field."""


class ConfigError(HilError):
    """A configuration (vehicle, scenario, bus) is invalid.

    ``str(err)`` is one line: ``file: field.path: expected ..., got ...``.
    """

    def __init__(self, where: str, field: str, expected: str, found: object) -> None:
        self.where = where
        self.field = field
        self.expected = expected
        self.found = found
        loc = one_line(f"{where}: {field}" if field else where)
        shown = one_line(str(found)) if isinstance(found, Raw) else repr(found)
        if len(shown) > SHOWN_MAX_CHARS:  # one line, whatever the input held
            shown = f"{shown[:SHOWN_MAX_CHARS]}... ({len(shown)} characters)"
        super().__init__(f"{loc}: expected {expected}, got {shown}")


class PeerError(Exception):
    """Junk from the other side of the bus. Never escapes a receive loop; counted instead."""
