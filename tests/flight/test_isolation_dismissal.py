"""A stuck-on crossing that the pair fit explains as its opposite's deficit, while that opposite
thruster's own burns show its full thrust, names nothing (``FlightSoftware._isolate_opposite``).

Seen in a real-time run of S002-100 on kalman_cube: a false "degraded Z-" at 115.6 s with a
thrust fraction of 1.05. The detector's own fails-to-fire crossing already had the rule (a
thruster that gives what the admitted errors allow is not failing); the isolation did not.

Oracle: a window of residuals made by hand, a 50 % deficit of Z- on its burns and nothing on
the quiet ticks (a leak of Z+ would push there), so the fit prefers the deficit; whether it is
named depends only on Z-'s measured fraction.
"""

from __future__ import annotations

import numpy as np
import pytest

from flight.detector import DEGRADED, STUCK_ON, Detection
from flight.software import FlightSoftware
from hil.config import load_vehicle


def _set_up(fraction: float) -> tuple[FlightSoftware, Detection]:
    fs = FlightSoftware(load_vehicle("kalman_cube"))
    fs.step(0, np.zeros(3))
    d = fs.detector
    names = list(fs.arrays.names)
    i, j = names.index("Z-"), names.index("Z+")
    assert d.opposite[j, i]
    mu_abs = np.linalg.norm(fs.arrays.mu_B_rad_s2, axis=1)
    window = []
    for t in range(8):
        eff = np.zeros(fs.n)
        if t % 2 == 0:
            eff[i] = 0.2
            dw = -0.5 * mu_abs[i] * 0.2 * d.e_B[i]
        else:
            dw = np.zeros(3)
        window.append((dw, eff, bool(t % 2 == 0), dw, fs.effectiveness.updates))
    fs._window = window
    d.rho_on[i] = -1.1 * d.thresholds_on[i]
    d.rho_off[j] = 1.05 * d.thresholds_off[j]
    # Z-'s burns in the window (stamped with the update they came from)
    fs.effectiveness._recent[i] = [(fs.effectiveness.updates, fraction)] * 3
    det = Detection(tick=10, thruster=j, kind=STUCK_ON, group=(j,), names=("Z+",), rho=1.0)
    return fs, det


def test_deficit_of_a_thruster_at_full_thrust_names_nothing() -> None:
    fs, det = _set_up(1.05)
    avail = np.ones(fs.n, bool)
    assert fs._settle(fs._isolate_opposite(det, avail), det) is None
    assert fs.detector.latched is None
    assert fs._window == []


@pytest.mark.parametrize("fraction", [0.5, 0.3])
def test_deficit_of_a_weak_thruster_is_named_degraded(fraction: float) -> None:
    fs, det = _set_up(fraction)
    avail = np.ones(fs.n, bool)
    got = fs._settle(fs._isolate_opposite(det, avail), det)
    assert got is not None and got.kind == DEGRADED and got.names == ("Z-",)
    assert got.fraction == pytest.approx(fraction)
    assert fs.detector.latched is got
