"""Orbit correction's trim (``Allocator.allocate_trim``): attitude first, then as much of the
remaining delta-v as the tick can give with it.

Oracle: ``scipy.optimize.linprog`` on the same problem written with the progress fraction ``f``
as a variable (maximise ``f``). The allocator finds ``f`` by bisection, so its progress on each
axis is at least ``(f* - 2^-steps)`` of the axis's capacity; the rate demand is met within the
tick; no axis is pushed past its remainder plus half the tolerance.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from flight.allocator import TRIM_STEPS, Allocator
from hil.config import load_vehicle

DEG = np.pi / 180.0
TOL = 0.02


@pytest.fixture(scope="module")
def orel() -> Allocator:
    return Allocator(load_vehicle("orel"))


def _oracle_f(alloc: Allocator, lo, hi, rem, av) -> tuple[float, np.ndarray]:
    """Largest f in [0, 1] with the rate demand met in the tick and every active axis given
    at least f * c_i (the allocator's own definition of c_i, written out again here)."""
    half = TOL / 2
    sign = np.sign(rem)
    active = np.abs(rem) > half
    acc, mu = alloc.acc[av], alloc.mu[av]
    k = len(acc)
    cap = np.where(active, np.minimum(np.clip(sign * acc, 0, None).sum(axis=0)
                                      * alloc.tau_max_s, np.abs(rem)), 0.0)
    A_ub, b_ub = [], []
    for ch in range(3):  # lo <= mu.T tau <= hi
        A_ub += [np.append(mu[:, ch], 0.0), np.append(-mu[:, ch], 0.0)]
        b_ub += [hi[ch], -lo[ch]]
    for ax in range(3):
        a = acc[:, ax]
        if active[ax]:  # sign*dv >= f*cap, sign*dv <= |rem| + tol/2
            A_ub += [np.append(-sign[ax] * a, cap[ax]), np.append(sign[ax] * a, 0.0)]
            b_ub += [0.0, abs(rem[ax]) + half]
        else:
            A_ub += [np.append(a, 0.0), np.append(-a, 0.0)]
            b_ub += [rem[ax] + half, -(rem[ax] - half)]
    c = np.zeros(k + 1)
    c[-1] = -1.0
    res = linprog(c, A_ub=np.array(A_ub), b_ub=np.array(b_ub),
                  bounds=[(0, alloc.tau_max_s)] * k + [(0, 1)], method="highs")
    return float(res.x[-1]) if res.status == 0 else -1.0, cap


@pytest.mark.parametrize("seed", range(40))
def test_trim_holds_attitude_and_progresses_as_far_as_the_tick_allows(orel: Allocator,
                                                                         seed: int) -> None:
    rng = np.random.default_rng(seed)
    orel.reset()
    av = np.ones(orel.n, dtype=bool)
    if seed % 4 == 3:  # a closed manifold: fewer thrusters to trim with
        av = orel.available_mask(closed_manifolds=[orel.arrays.manifolds[seed % 2]])
    # A phase-plane rate demand: a band of 0.2-0.3 deg/s around a centre within 0.25 deg/s.
    centre = rng.uniform(-0.25, 0.25, 3) * DEG
    width = rng.uniform(0.1, 0.15, 3) * DEG
    lo, hi = centre - width, centre + width
    rem = rng.uniform(-2.0, 2.0, 3) * (rng.uniform(size=3) < 0.7)
    f_star, cap = _oracle_f(orel, lo, hi, rem, av)
    a = orel.allocate_trim(lo, hi, av, rem, TOL)
    tau = a.tau_eff_lp_s
    assert np.all(tau[~av] == 0.0) and np.all(tau <= orel.tau_max_s * (1 + 1e-9))
    if f_star < 0:  # not even the attitude alone in the tick: the attitude-only allocation
        ref = orel.solve_lp(lo, hi, av)
        assert a.status == ref.status and np.allclose(tau, ref.tau_eff_s)
        return
    dw = orel.mu.T @ tau
    assert np.all(dw >= lo - 1e-9) and np.all(dw <= hi + 1e-9), "rate demand not met"
    dv = orel.acc.T @ tau
    half = TOL / 2
    active = np.abs(rem) > half
    sign = np.sign(rem)
    got = sign * dv
    assert np.all(got[active] <= np.abs(rem[active]) + half + 1e-9), "pushed past the remainder"
    need = (f_star - 2.0 ** -TRIM_STEPS) * cap
    assert np.all(got[active] >= need[active] - 1e-9), (f_star, got, cap)
    assert np.all(np.abs(dv[~active] - rem[~active]) <= half + 1e-9)


def test_a_remainder_the_tick_can_give_is_given_whole(orel: Allocator) -> None:
    orel.reset()
    rem = np.array([0.0, -0.004 - TOL / 2, 0.0])  # just outside the tolerance
    lo, hi = np.full(3, -0.2 * DEG), np.full(3, 0.2 * DEG)
    a = orel.allocate_trim(lo, hi, None, rem, TOL)
    assert a.status == "optimal"
    dv = orel.acc.T @ a.tau_eff_lp_s
    assert dv[1] == pytest.approx(rem[1], abs=1e-9)  # f = 1: the whole remainder, no more fuel


def test_a_rate_demand_beyond_the_tick_gets_the_attitude_only_allocation(orel: Allocator) -> None:
    orel.reset()
    lo, hi = np.full(3, 5.0 * DEG), np.full(3, 6.0 * DEG)  # far beyond one tick's authority
    rem = np.array([0.0, -1.0, 0.5])
    f_star, _ = _oracle_f(orel, lo, hi, rem, np.ones(orel.n, dtype=bool))
    assert f_star < 0
    a = orel.allocate_trim(lo, hi, None, rem, TOL)
    ref = orel.solve_lp(lo, hi)
    assert a.status == ref.status != "optimal"
    assert np.allclose(a.tau_eff_lp_s, ref.tau_eff_s)
