"""Unit conversions shared by the cores and the shells (names carry the unit elsewhere)."""

from __future__ import annotations

import math

# Standard gravity, m/s^2: Isp in seconds to exhaust velocity (mdot = F / (Isp g0)).
G0_M_S2 = 9.80665
# Degrees per radian.
DEG = 180.0 / math.pi
