"""Numeric command-line arguments checked by argparse itself: finite and in range.

``type=number(ge=0)`` makes ``--kill-flight-at nan`` or ``-5`` a usage error (exit 2, one
line naming the argument, what was expected and what was found) before anything boots.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def _bounds_text(ge: float | None, gt: float | None, le: float | None) -> str:
    parts = []
    if ge is not None:
        parts.append(f">= {ge:g}")
    if gt is not None:
        parts.append(f"> {gt:g}")
    if le is not None:
        parts.append(f"<= {le:g}")
    return " and ".join(parts)


def number(*, ge: float | None = None, gt: float | None = None,
           le: float | None = None) -> Callable[[str], float]:
    """An argparse ``type`` for a finite float within the given bounds."""
    want = "a finite number" + (f" {_bounds_text(ge, gt, le)}" if (ge, gt, le) != (None,) * 3
                                else "")

    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {want}, got {text!r}") from None
        if not math.isfinite(x) or (ge is not None and x < ge) or (gt is not None and x <= gt) \
                or (le is not None and x > le):
            raise argparse.ArgumentTypeError(f"expected {want}, got {text!r}")
        return x

    parse.__name__ = "number"
    return parse


def integer(*, ge: int | None = None, le: int | None = None) -> Callable[[str], int]:
    """An argparse ``type`` for an integer within the given bounds."""
    want = "an integer" + (f" {_bounds_text(ge, None, le)}" if (ge, le) != (None, None) else "")

    def parse(text: str) -> int:
        try:
            x = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {want}, got {text!r}") from None
        if (ge is not None and x < ge) or (le is not None and x > le):
            raise argparse.ArgumentTypeError(f"expected {want}, got {text!r}")
        return x

    parse.__name__ = "integer"
    return parse
