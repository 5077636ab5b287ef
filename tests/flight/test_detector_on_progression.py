"""Detector's integral residual for ON ticks (seed 000): progressions and opposing pairs.

Seed 000: ``rho_on,j[n] = w_on rho_on,j[n-1] + xi_j[n]`` on the ticks thruster j is commanded
(and only on those). For a constant ``xi`` the k-th commanded tick gives the arithmetic-geometric
sum ``xi (1 + w + ... + w^(k-1)) = xi (1 - w^k) / (1 - w)``, limit ``xi / (1 - w)``; after a single
spike ``xi`` followed by zero residuals, ``rho = xi w^n``. Seed 000 tables 1-2: a tick on which
both thrusters of an opposing pair are commanded carries no information for the pair, and the
detector keeps ``rho_on`` of both unchanged on it (no forgetting either).

``w_on`` and ``w_off`` differ in every test, so using the wrong one shows.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from flight.detector import FAIL_TO_FIRE, Detector
from hil.config import DetectorCfg

W_ON, W_OFF = 0.85, 0.6
BIG = 1e9
# X+ and X- (opposing, unequal), Y (orthogonal to both), and a thruster 60 deg from X+ in x-y.
MU = np.array([
    [0.010, 0.0, 0.0],
    [-0.008, 0.0, 0.0],
    [0.0, 0.012, 0.0],
    [0.005, 0.005 * math.sqrt(3.0), 0.0],
])
XP, XM, Y, S60 = range(4)
CFG = DetectorCfg(dead_zone_rad_s=1e-4, forgetting_on=W_ON, forgetting_off=W_OFF,
                  threshold_on=BIG, threshold_off=BIG)


def agp(xi: float, w: float, k: int) -> float:
    """xi (1 + w + ... + w^(k-1)), summed term by term (no closed form used)."""
    return xi * sum(w**m for m in range(k))


def cmd(*idx: int) -> np.ndarray:
    a = np.zeros(len(MU), dtype=bool)
    a[list(idx)] = True
    return a


@pytest.mark.parametrize(("dw", "xi"), [
    (np.array([1e-3, 0.0, 0.0]), 0.5),                   # 60 deg from S60's direction
    (np.array([-4e-3, 0.0, 0.0]), -0.5),                 # 120 deg: S60 looks weak
    (np.array([0.0, 2e-3, 0.0]), 0.5 * math.sqrt(3.0)),  # 30 deg
    (np.array([-1e-3, -1e-3 * math.sqrt(3.0), 0.0]), -1.0),  # against S60: fails to fire
])
def test_rho_on_constant_xi_arithmetic_geometric_progression(dw, xi) -> None:
    """Thruster S60 commanded every tick: rho_on = xi (1 - w_on^k) / (1 - w_on) -> xi/(1-w_on)."""
    d = Detector(MU, CFG)
    xi_exact = xi
    for k in range(1, 81):
        out = d.step(k, dw, cmd(S60))
        assert out.xi[S60] == pytest.approx(xi_exact, rel=1e-12)
        assert out.rho_on[S60] == pytest.approx(agp(xi_exact, W_ON, k), rel=1e-12, abs=1e-15)
        assert out.rho_on[S60] == pytest.approx(
            xi_exact * (1 - W_ON**k) / (1 - W_ON), rel=1e-12, abs=1e-15)
        assert out.rho_off[S60] == 0.0  # never an off tick
    assert out.rho_on[S60] == pytest.approx(xi_exact / (1 - W_ON), rel=1e-5)


def test_rho_on_decays_as_w_on_power_after_a_single_spike() -> None:
    d = Detector(MU, CFG)
    d.step(0, np.array([-3e-3, 0.0, 0.0]), cmd(XP))  # xi(X+) = -1 once
    for n in range(1, 40):
        # Below the dead zone, and exactly zero: both count as xi = 0.
        dw = np.array([5e-5, 0.0, 0.0]) if n % 2 else np.zeros(3)
        out = d.step(n, dw, cmd(XP))
        assert out.dead_zone
        assert out.rho_on[XP] == pytest.approx(-(W_ON**n), rel=1e-12)


def test_rho_on_moves_only_on_commanded_ticks() -> None:
    """Interleaved commands: rho_on follows the progression in the count of commanded ticks and
    holds its value between them; rho_off follows w_off on the others."""
    rng = np.random.default_rng(17)
    pattern = rng.random(120) < 0.4
    d = Detector(MU, CFG)
    dw = np.array([2e-3, 0.0, 0.0])  # xi(X+) = +1
    k_on = k_off = 0
    for n, on in enumerate(pattern):
        out = d.step(n, dw, cmd(XP) if on else cmd())
        k_on += int(on)
        k_off += int(not on)
        assert out.rho_on[XP] == pytest.approx(agp(1.0, W_ON, k_on), rel=1e-12, abs=1e-15)
        assert out.rho_off[XP] == pytest.approx(agp(1.0, W_OFF, k_off), rel=1e-12, abs=1e-15)


# --------------------------------------------------------------------------- opposing pairs


def test_both_of_an_opposing_pair_commanded_keeps_rho_on_unchanged() -> None:
    d = Detector(MU, CFG)
    dw = np.array([-2e-3, 0.0, 0.0])
    for n in range(5):  # X+ alone: rho_on(X+) builds with xi = -1
        d.step(n, dw, cmd(XP))
    before = d.rho_on.copy()
    before_off = d.rho_off.copy()
    for n in range(5, 15):  # X+ and X- together: no information for the pair
        out = d.step(n, dw, cmd(XP, XM))
        assert out.rho_on[XP] == before[XP] and out.rho_on[XM] == before[XM]
        assert out.rho_off[XP] == before_off[XP] and out.rho_off[XM] == before_off[XM]
    # X- alone again: rho_on(X-) resumes its own progression (xi(X-) = +1 here).
    out = d.step(15, dw, cmd(XM))
    assert out.rho_on[XM] == pytest.approx(W_ON * before[XM] + 1.0, rel=1e-12)
    assert out.rho_on[XP] == before[XP]  # X+ not commanded: its rho_on holds
    assert out.rho_on[XP] == pytest.approx(agp(-1.0, W_ON, 5), rel=1e-12)


def test_non_opposing_thrusters_commanded_together_are_not_excluded() -> None:
    """X+ with Y (orthogonal) or with S60 (60 deg): both keep their on-progressions."""
    d = Detector(MU, CFG)
    dw = np.array([1e-3, 1e-3, 0.0])
    xi = d.e_B @ (dw / np.linalg.norm(dw))
    for k in range(1, 20):
        out = d.step(k, dw, cmd(XP, Y, S60))
        for i in (XP, Y, S60):
            assert out.rho_on[i] == pytest.approx(agp(xi[i], W_ON, k), rel=1e-12)
        assert out.rho_on[XM] == 0.0  # X- not commanded: untouched on the on side
        assert out.rho_off[XM] == pytest.approx(agp(xi[XM], W_OFF, k), rel=1e-12)


@pytest.mark.parametrize(("angle_deg", "opposing"), [(180.0, True), (179.0, True),
                                                     (175.0, False), (90.0, False)])
def test_opposition_tolerance_is_same_direction_deg(angle_deg: float, opposing: bool) -> None:
    """Default ``opposite_deg`` = ``same_direction_deg`` (2 deg)."""
    a = math.radians(angle_deg)
    mu = np.array([[0.01, 0.0, 0.0], [0.01 * math.cos(a), 0.01 * math.sin(a), 0.0]])
    d = Detector(mu, DetectorCfg(forgetting_on=W_ON, forgetting_off=W_OFF, threshold_on=BIG,
                                 threshold_off=BIG, same_direction_deg=2.0))
    out = d.step(0, np.array([1e-3, 0.0, 0.0]), np.array([True, True]))
    if opposing:
        assert not out.rho_on.any()
    else:
        np.testing.assert_allclose(out.rho_on, out.xi, rtol=1e-15)


def test_fail_to_fire_detection_tick_from_the_progression() -> None:
    """X- fails to fire (seed 000 table 2): residual along +x on ticks X- is commanded.

    rho_on(X-) after k counted ticks is -(1 - w^k)/(1 - w); with w_on = 0.85 and threshold 2.0 the
    first k with (1 - 0.85^k)/0.15 > 2 is 3. Ticks with X+ and X- both commanded do not count:
    each delays the detection by one tick.
    """
    thr = 2.0
    k_needed = next(k for k in range(1, 100) if agp(1.0, W_ON, k) > thr)
    assert k_needed == 3
    cfg = DetectorCfg(dead_zone_rad_s=1e-4, forgetting_on=W_ON, forgetting_off=W_OFF,
                      threshold_on=thr, threshold_off=BIG)
    schedule = [cmd(XM), cmd(XP, XM), cmd(XP, XM), cmd(XM), cmd(), cmd(XP, XM), cmd(XM), cmd(XM)]
    d = Detector(MU, cfg, ("X+", "X-", "Y", "S60"))
    det, counted = None, 0
    for n, act in enumerate(schedule):
        fails = act[XM] and not act[XP]
        dw = np.array([1.6e-3, 0.0, 0.0]) if act[XM] else np.zeros(3)
        out = d.step(n, dw, act)
        counted += int(fails)
        if out.detection is not None:
            det = out.detection
            break
    assert det is not None and (det.thruster, det.kind) == (XM, FAIL_TO_FIRE)
    assert counted == k_needed and det.tick == 6
    assert det.rho == pytest.approx(-agp(1.0, W_ON, k_needed), rel=1e-12)


def test_unavailable_thruster_rho_on_stays_zero() -> None:
    d = Detector(MU, CFG)
    av = np.ones(len(MU), dtype=bool)
    av[S60] = False
    for n in range(10):
        out = d.step(n, np.array([0.0, 1e-3, 0.0]), cmd(S60, Y), av)
        assert out.rho_on[S60] == 0.0 and out.rho_off[S60] == 0.0
        assert out.rho_on[Y] == pytest.approx(agp(1.0, W_ON, n + 1), rel=1e-12)
