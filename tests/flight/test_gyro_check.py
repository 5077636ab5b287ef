"""Gyro check (flight.gyro_check) on synthetic residuals whose truth is known by construction:
a thruster fault's residual keeps its sign along the thruster's direction, a sensor fault's does
not; white noise's squared differences are chi-square (scipy.stats is the oracle for the
noise test's false-alarm and detection figures)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from flight.gyro_check import (
    _BIG_COUNT,
    _BIG_RATIO,
    _BIG_WINDOW,
    BIAS_STEP,
    NOISE,
    SPIKE,
    GyroCheck,
)

NOISE_STD = 5e-6


def _check() -> GyroCheck:
    return GyroCheck(jump_rad_s=1e-3, noise_floor_rad_s=np.sqrt(18) * NOISE_STD)


def _feed(chk: GyroCheck, ys, thrust=None, inc=None):
    """Step ``chk`` through samples ``ys``; ``thrust``/``inc`` per tick (or None)."""
    out = []
    for k, y in enumerate(ys):
        ta = 0.0 if thrust is None else thrust[k]
        u = None if inc is None else inc[k]
        out.append(chk.step(np.asarray(y, float), np.zeros(3), ta, u))
    return out


def _quiet(n: int, seed: int = 1, noise=NOISE_STD) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return 1e-4 + np.asarray(noise) * rng.standard_normal((n, 3))


def test_a_counter_glitch_of_an_integrating_gyro_is_one_spike() -> None:
    """One bad counter reading: the mean rates around it are off by +s and -s (residual +s,
    -2s, +s). Named a spike on the second tick; the three ticks are kept out of the evidence,
    the estimators resynchronised on the third."""
    ys = _quiet(60)
    ys[40, 1] += 0.01
    ys[41, 1] -= 0.01
    v = _feed(_check(), ys)
    assert [k for k, x in enumerate(v) if x.fault] == [41]
    assert v[41].fault == SPIKE and v[41].drop_previous and not v[41].resync
    assert v[40].hold and v[41].suspect and v[42].suspect and v[42].resync
    assert not any(x.suspect for x in v[43:])


def test_a_spike_inside_a_burn_is_recognised_from_the_thrusters_of_the_tick() -> None:
    """A burn of one thruster (0.02 rad/s along +y per tick) on every tick; a spike of +0.03
    along +y at tick 40. The total-thrust gate (1.5 x the thrust) would take it for thrust;
    the per-thruster one knows a burn along +y cannot be 0.03 stronger than commanded."""
    n = 60
    ys = _quiet(n)
    ys[40, 1] += 0.03
    u = np.zeros((n, 2, 3))
    u[:, 0, 1] = 0.02
    thrust = [0.02] * n
    assert not any(x.fault for x in _feed(_check(), ys, thrust))
    v = _feed(_check(), ys, thrust, u)
    assert [(k, x.fault) for k, x in enumerate(v) if x.fault] == [(41, SPIKE)]


def test_a_thruster_that_fails_to_fire_once_is_not_a_bias_step() -> None:
    """Commanded on one tick only (0.02 along +x), it does not fire: residual -0.02 along x,
    then nothing: the pattern of a bias step, but one thruster of the tick explains it."""
    n = 60
    ys = _quiet(n)
    ys[40:, 0] -= 0.02
    u = np.zeros((n, 1, 3))
    u[40, 0, 0] = 0.02
    thrust = [0.02 if k == 40 else 0.0 for k in range(n)]
    v = _feed(_check(), ys, thrust, u)
    assert not any(x.fault for x in v)
    # evidence at once (only that thruster explains it), and not taken back on the next tick
    assert not v[40].suspect and not v[41].taint_previous and not v[41].suspect
    # the same step with no thruster commanded is a bias step
    v = _feed(_check(), ys)
    assert [(k, x.fault) for k, x in enumerate(v) if x.fault] == [(41, BIAS_STEP)]


def test_a_step_while_the_thruster_that_could_explain_it_fires_right_is_a_bias_step() -> None:
    """The output steps by -0.02 along x on a tick X+ (0.02 along +x) is commanded: one
    thruster failing would explain it, but X+ is commanded again on the next tick and gives
    its full increment: the output stepped."""
    n = 60
    ys = _quiet(n)
    ys[40:, 0] -= 0.02
    u = np.zeros((n, 1, 3))
    u[40:43, 0, 0] = 0.02
    thrust = [0.02 if 40 <= k < 43 else 0.0 for k in range(n)]
    v = _feed(_check(), ys, thrust, u)
    assert [(k, x.fault) for k, x in enumerate(v) if x.fault] == [(41, BIAS_STEP)]
    assert not v[40].suspect and v[41].taint_previous  # evidence at once, then taken back


def test_a_leak_coming_and_going_with_the_burns_is_not_a_bias_step() -> None:
    """A thruster stuck on while it is commanded leaks only in the closed part of each tick:
    2e-3 rad/s per tick along x times the closed share, 0.3-0.8 for 20 ticks, then a whole
    tick closed (2e-3) followed by a tick it burns almost throughout (2e-4, under 0.3 of the
    jump): the pattern of a bias step, but out of a residual that was anything but calm along
    it (kalman_cube-leaks run 10). Out of calm ticks the same two ticks are a bias step."""
    closed = [0.7, 0.4, 0.3, 0.6, 0.35, 0.8, 0.45, 0.3, 0.6, 0.4] * 2 + [1.0, 0.1, 0.3]
    rng = np.random.default_rng(7)
    w = np.full(3, 1e-4)
    ys = []
    for k in range(60):
        if 10 <= k < 10 + len(closed):
            w = w + np.array([2e-3 * closed[k - 10], 0.0, 0.0])
        ys.append(w + NOISE_STD * rng.standard_normal(3))
    v = _feed(_check(), ys)
    assert not any(x.fault for x in v)
    jump = 10 + 20  # the whole closed tick
    assert v[jump].hold and v[jump + 1].drop_previous  # held, then not evidence
    # the same two ticks out of calm: a bias step (the naming is judged on the tick after)
    calm = _quiet(60)
    calm[30:, 0] += 2e-3  # the whole closed tick
    calm[31:, 0] += 2e-4  # the tick it burns almost throughout, then nothing
    v = _feed(_check(), calm)
    assert [(k, x.fault) for k, x in enumerate(v) if x.fault] == [(31, BIAS_STEP)]


def test_a_stuck_thruster_is_held_one_tick_then_committed() -> None:
    """A stuck-on thruster adds 2e-3 rad/s per tick from tick 10: the first jump is held (it
    could be a sensor step), every later one is dynamics and goes to the detector at once."""
    w = np.zeros(3)
    rng = np.random.default_rng(5)
    chk = _check()
    holds, suspects = [], []
    for k in range(30):
        if k >= 10:
            w = w + np.array([2e-3, 0, 0])
        v = chk.step(w + NOISE_STD * rng.standard_normal(3), np.zeros(3), 0.0, np.zeros((2, 3)))
        assert v.fault is None and not v.drop_previous
        holds.append(v.hold)
        suspects.append(v.suspect)
    assert [k for k, h in enumerate(holds) if h] == [10]
    assert not any(suspects[11:])


def _first_noise(ys) -> int | None:
    v = _feed(_check(), ys)
    found = [k for k, x in enumerate(v) if x.fault]
    assert all(v[k].fault == NOISE for k in found)
    return found[0] if found else None


def test_the_noise_level_is_learnt_so_exceedances_follow_the_chi_square() -> None:
    """White noise at twice the floor's sigma (the level is learnt, not the floor), a rate gyro:
    the second difference of a sample has variance 6 sigma^2 per axis, and its square over the
    learnt level exceeds ``_BIG_RATIO`` as often as chi-square(1) says (scipy.stats)."""
    chk = _check()
    flags = []
    for y in _quiet(20_000, seed=3, noise=2.0 * NOISE_STD):  # twice the floor: learnt level
        chk.step(y, np.zeros(3), 0.0)
        if chk._big:
            flags.append(chk._big[-1])
    flags = np.asarray(flags[200:])
    p = stats.chi2.sf(_BIG_RATIO, 1)
    n = flags.size
    # The flags cluster (a second difference's squares are correlated), so not a binomial
    # interval: within 15 % (the robust level runs a few % low: capped samples, frozen axes).
    assert flags.sum() == pytest.approx(n * p, rel=0.15), (flags.sum(), n * p)
    assert _BIG_COUNT <= _BIG_WINDOW


def test_no_noise_alarm_on_a_long_clean_hold() -> None:
    """30,000 quiet ticks (100 min at 0.2 s) of white noise at the floor: no alarm."""
    assert _first_noise(_quiet(30_000, seed=7)) is None


@pytest.mark.parametrize(("factor", "median_max", "all_max"), [(3.0, 60, 300), (5.0, 30, 80),
                                                              (10.0, 20, 60)])
def test_a_noise_increase_on_one_axis_is_named(factor: float, median_max: int,
                                               all_max: int) -> None:
    """Noise up by ``factor`` on the z axis only from tick 100, 30 seeds: ticks to the name.
    Three times up is the hard end (module doc: median 27 with the level known)."""
    ticks = []
    for seed in range(30):
        ys = _quiet(500, seed=seed)
        rng = np.random.default_rng(100 + seed)
        ys[100:, 2] += NOISE_STD * np.sqrt(factor ** 2 - 1.0) * rng.standard_normal(400)
        k = _first_noise(ys)
        assert k is not None and k >= 100, (seed, k)
        ticks.append(k - 100)
    assert np.median(ticks) <= median_max and max(ticks) <= all_max, ticks


def test_a_small_jump_below_the_naming_level_is_held_and_dropped_unless_repeated() -> None:
    """``hold_rad_s`` under the jump level: a lone 5e-4 jump (half the jump level) is held a
    tick and dropped from the evidence without a name; the same jump repeated along itself (a
    stuck-on thruster) is committed."""
    n = 40
    ys = _quiet(n)
    ys[20, 0] += 5e-4  # one bad sample, half the jump level
    chk = GyroCheck(jump_rad_s=1e-3, noise_floor_rad_s=np.sqrt(18) * NOISE_STD, hold_rad_s=2e-4)
    v = _feed(chk, ys)
    assert v[20].hold and v[21].drop_previous and not any(x.fault for x in v)
    ys = _quiet(n)
    ys[20:, 0] += 5e-4 * np.arange(1, n - 19)  # 5e-4 more every tick
    v = _feed(GyroCheck(jump_rad_s=1e-3, noise_floor_rad_s=np.sqrt(18) * NOISE_STD,
                        hold_rad_s=2e-4), ys)
    assert v[20].hold and not v[21].drop_previous and not v[21].suspect
    assert not any(x.fault for x in v)
