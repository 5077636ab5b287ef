"""generic's ellipsoidal dead zone (``detector.relative_dead_zone_across``): a thruster's deficit
is not hidden by the firings of thrusters on the other axes.

Oracles: the dead zone written out here from the vehicle's own figures (a sphere of 10 % of
every commanded effect against the ellipsoid ``dz^2 I + sum_j m_j^2 (a^2 e e^T + b^2 (I -
e e^T))``); the closed loop against what the plant was given (a degraded thruster named with
its fraction, where the same run with the sphere names nothing).
"""

from __future__ import annotations

import numpy as np
import pytest

from flight.software import FlightSoftware
from hil.config import load_vehicle
from tests.flight.campaign_run import campaign_run


def _fs(across) -> FlightSoftware:
    return FlightSoftware(load_vehicle("generic", {"detector": {
        "relative_dead_zone_across": across}}))


def test_a_deficit_behind_other_axes_firings() -> None:
    """Y+ at 60 ms with X+ and Z+ at 150 ms (generic-faults run 44, 10.4 s): 44 % of Y+'s
    effect missing along y is outside the ellipsoid and inside the sphere."""
    sph, ell = _fs(None), _fs(0.05)
    names = list(ell.arrays.names)
    mu = ell.arrays.mu_B_rad_s2
    on = {"Y+": 0.06, "X+": 0.15, "Z+": 0.15}
    m = np.zeros(ell.n)
    for n, s in on.items():
        m[names.index(n)] = np.linalg.norm(mu[names.index(n)]) * s
    dw = -0.44 * mu[names.index("Y+")] * on["Y+"]
    dz, a, b = 1e-4, 0.1, 0.05
    # written out: the sphere, and the ellipsoid
    assert np.linalg.norm(dw) < dz + a * m.sum()
    e = mu / np.linalg.norm(mu, axis=1)[:, None]
    S = dz**2 * np.eye(3) + sum(m[j] ** 2 * (a**2 * np.outer(e[j], e[j])
                                              + b**2 * (np.eye(3) - np.outer(e[j], e[j])))
                                for j in range(ell.n))
    assert float(dw @ np.linalg.solve(S, dw)) > 1.0
    assert sph.detector.project(dw, m.sum())[2]
    assert not ell.detector.in_ellipsoid(dw, m)
    # a healthy tick (3 % off along each, 2 deg of direction error) stays inside both
    healthy = sum(0.03 * mu[names.index(n)] * s for n, s in on.items())
    assert ell.detector.in_ellipsoid(healthy, m) and sph.detector.project(healthy, m.sum())[2]


def _campaign_run(tmp_path, run: int, across=None):
    return campaign_run(tmp_path, "generic-faults", run,
                        None if across is None else {"relative_dead_zone_across": across})


@pytest.mark.parametrize("run", [17, 44])
def test_a_weak_thruster_that_fires_with_others_is_named(tmp_path, run: int) -> None:
    """generic-faults runs 17 (Z- at 45 %) and 44 (Y+ at 56 %): named degraded, the right
    thruster, the fraction within 0.1; with the sphere (``relative_dead_zone_across: null``)
    the same runs name nothing (the oracle: the test can fail)."""
    spec, r = _campaign_run(tmp_path, run)
    assert spec.fault["kind"] == "degraded"
    d = r.summary["detections"]
    assert len(d) == 1 and d[0]["correct"] and d[0]["type"] == "degraded", d
    assert abs(d[0]["fraction"] - spec.fault["fraction"]) <= 0.1, (d, spec.fault)
    _, r0 = _campaign_run(tmp_path / "sphere", run, "null")
    assert r0.summary["detections"] == [], r0.summary["detections"]
