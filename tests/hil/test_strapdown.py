"""The flight's attitude estimate against the plant's truth (the oracle) in closed loop.

A rate gyro samples once a tick; the flight integrates the samples with the burns' position in
the tick from its onboard model (``FlightSoftware._rate_increment``). The figures before, with
the rectangle ``h y[n]``: 0.26 deg through S000's slew, 0.28 deg through S004-cart-x's burn,
0.11 deg in REC-stuck. The flight's attitude at tick n is compared with the truth at ``t_n``
(``SimRun.truth[n - 1]``: the plant's state after integrating up to ``t_n``).
"""

from __future__ import annotations

import numpy as np
import pytest

from flight.attitude import error_quaternion
from hil.config import SCENARIO_DIR
from hil.sim import simulate


def _knowledge_error_deg(name: str) -> float:
    r = simulate(SCENARIO_DIR / f"{name}.yaml", keep=True)
    err = [np.linalg.norm(2.0 * error_quaternion(t.q_BO, o.attitude_BO)[1:])
           for o, t in zip(r.outputs[1:], r.truth[:-1], strict=True)]
    return float(np.degrees(max(err)))


@pytest.mark.parametrize(("name", "bound_deg"), [
    ("S000-stuck", 0.02),   # generic: a 22 deg slew at up to the rate limit, a stuck thruster
    ("REC-stuck", 0.02),    # orel: a slew, a stuck thruster, the manifold closed
    ("S004-cart-x", 0.2),   # orel: 100 s of burn with off-times and roll pairs
])
def test_attitude_estimate_follows_the_truth(name: str, bound_deg: float) -> None:
    assert _knowledge_error_deg(name) < bound_deg
