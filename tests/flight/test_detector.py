"""Detector against seed 000 tables 1-2, the progressions, and group reporting."""

from __future__ import annotations

import numpy as np
import pytest

from flight.detector import FAIL_TO_FIRE, STUCK_ON, Detector
from hil.config import DetectorCfg

# Two opposing thrusters on one channel, unequal strength (seed 000 fig. 1 and fig. 4).
MU = np.array([[0.010, 0.0, 0.0], [-0.008, 0.0, 0.0]])
P, M = 0, 1
CFG = DetectorCfg(dead_zone_rad_s=1e-4, forgetting_on=0.9, forgetting_off=0.9,
                  threshold_on=1e9, threshold_off=1e9)


def _one_tick(dw: np.ndarray, cmd_p: bool, cmd_m: bool) -> tuple[np.ndarray, np.ndarray]:
    d = Detector(MU, CFG, ("X+", "X-"))
    out = d.step(0, dw, np.array([cmd_p, cmd_m]))
    return out.rho_on, out.rho_off


# Seed 000 table 1: X+ stuck on, dw = +tau eps+ e+ on ticks X+ was not commanded.
@pytest.mark.parametrize(
    ("cmd_p", "cmd_m", "on_p", "off_p", "on_m", "off_m"),
    [
        (False, False, 0, +1, 0, -1),   # column 1: neither commanded
        (False, True, 0, +1, -1, 0),    # column 2: only X- commanded
    ],
)
def test_table1_stuck_on(cmd_p, cmd_m, on_p, off_p, on_m, off_m) -> None:
    rho_on, rho_off = _one_tick(np.array([3e-4, 0, 0]), cmd_p, cmd_m)
    assert np.sign(rho_on).tolist() == [on_p, on_m]
    assert np.sign(rho_off).tolist() == [off_p, off_m]


def test_table1_column3_commanded_stuck_thruster_gives_no_residual() -> None:
    rho_on, rho_off = _one_tick(np.zeros(3), True, False)
    assert not rho_on.any() and not rho_off.any()


# Seed 000 table 2: X- fails to fire, dw = -tau eps- e- (along +x) on ticks X- was commanded.
@pytest.mark.parametrize(
    ("cmd_p", "cmd_m", "on_p", "off_p", "on_m", "off_m"),
    [
        (False, True, 0, +1, -1, 0),    # column 1: only X- commanded
        (True, True, 0, 0, 0, 0),       # column 2: both commanded -> skipped for the pair
    ],
)
def test_table2_fail_to_fire(cmd_p, cmd_m, on_p, off_p, on_m, off_m) -> None:
    rho_on, rho_off = _one_tick(np.array([2e-4, 0, 0]), cmd_p, cmd_m)
    assert np.sign(rho_on).tolist() == [on_p, on_m]
    assert np.sign(rho_off).tolist() == [off_p, off_m]


def test_dead_zone_and_normalisation() -> None:
    d = Detector(MU, CFG)
    assert not d.step(0, np.array([9e-5, 0, 0]), np.zeros(2, bool)).xi.any()
    xi = d.step(1, np.array([5.0, 0, 0]), np.zeros(2, bool)).xi
    np.testing.assert_allclose(xi, [1.0, -1.0])


def test_arithmetic_geometric_progression_and_limit() -> None:
    w = 0.8
    d = Detector(MU, DetectorCfg(forgetting_off=w, threshold_off=1e9, threshold_on=1e9))
    for n in range(60):
        rho = d.step(n, np.array([1e-3, 0, 0]), np.zeros(2, bool)).rho_off[P]
        assert rho == pytest.approx((1 - w ** (n + 1)) / (1 - w))
    assert rho == pytest.approx(1 / (1 - w), rel=1e-5)


def test_single_spike_decays_geometrically() -> None:
    w = 0.7
    d = Detector(MU, DetectorCfg(forgetting_off=w, threshold_off=1e9, threshold_on=1e9))
    d.step(0, np.array([1e-3, 0, 0]), np.zeros(2, bool))
    for n in range(1, 20):
        rho = d.step(n, np.zeros(3), np.zeros(2, bool)).rho_off[P]
        assert rho == pytest.approx(w**n)


def test_first_crossing_names_thruster_and_type_then_latches() -> None:
    d = Detector(MU, DetectorCfg(forgetting_off=0.8, forgetting_on=0.8, threshold_off=2.5,
                                 threshold_on=2.5), ("X+", "X-"))
    dets = [d.step(n, np.array([1e-3, 0, 0]), np.array([False, n >= 1])).detection
            for n in range(10)]
    first = [x for x in dets if x is not None]
    assert len(first) == 1
    assert (first[0].thruster, first[0].kind, first[0].tick) == (P, STUCK_ON, 3)


def test_tie_prefers_fail_to_fire() -> None:
    # X- commanded every tick and not firing: rho_on(X-) and rho_off(X+) move together.
    d = Detector(MU, DetectorCfg(forgetting_off=0.8, forgetting_on=0.8, threshold_off=2.5,
                                 threshold_on=2.5))
    det = None
    for n in range(10):
        det = det or d.step(n, np.array([1e-3, 0, 0]), np.array([False, True])).detection
    assert (det.thruster, det.kind) == (M, FAIL_TO_FIRE)


def test_same_direction_is_reported_as_a_group() -> None:
    mu = np.array([[0.01, 0, 0], [0.02, 0.0001, 0], [-0.01, 0, 0]])
    d = Detector(mu, DetectorCfg(threshold_off=1.5, forgetting_off=0.9), ("A", "B", "C"))
    det = None
    for n in range(5):
        det = det or d.step(n, np.array([1e-3, 0, 0]), np.zeros(3, bool)).detection
    assert det.group == (0, 1)
    assert det.describe() == "one of {A, B} stuck_on"


def test_rebaseline_zeroes_and_holds() -> None:
    d = Detector(MU, CFG)
    d.step(0, np.array([1e-3, 0, 0]), np.zeros(2, bool))
    d.rebaseline(hold_ticks=2)
    assert not d.rho_off.any()
    assert d.step(1, np.array([1e-3, 0, 0]), np.zeros(2, bool)).held
    assert d.step(2, np.array([1e-3, 0, 0]), np.zeros(2, bool)).held
    assert d.step(3, np.array([1e-3, 0, 0]), np.zeros(2, bool)).rho_off[P] == 1.0
