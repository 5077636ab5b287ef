"""Tick scheduler driven by a fake clock: absolute grid, rate groups, forced overruns."""

from __future__ import annotations

import pytest

from hil.scheduler import (
    RateGroup,
    TickScheduler,
    align_to_samples,
    seq_at_or_after,
    wait_for,
)

TICK = 200_000_000  # 200 ms in ns


class FakeClock:
    """A clock that advances only when told: by sleeping, or by the work's declared cost."""

    def __init__(self, t0: int = 1_000_000_000) -> None:
        self.t = t0

    def now(self) -> int:
        return self.t

    def sleep_until(self, target: int) -> None:
        self.t = max(self.t, target)

    def work(self, ns: int) -> None:
        self.t += ns


def test_releases_on_absolute_grid_without_drift() -> None:
    clk = FakeClock()
    seen: list[tuple[int, int]] = []

    def base(tick: int, release: int) -> None:
        seen.append((tick, release))
        clk.work(3_000_000 + 1000 * tick)  # work time varies: must not shift the grid

    TickScheduler(TICK, [RateGroup("base", 1, 0, base)], clk.now, clk.sleep_until).run(50)
    t0 = 1_000_000_000
    assert seen == [(n, t0 + n * TICK) for n in range(50)]


def test_rate_groups_as_divisors_with_offsets() -> None:
    clk = FakeClock()
    runs: dict[str, list[int]] = {"base": [], "hk": [], "hk2": []}
    groups = [
        RateGroup("base", 1, 0, lambda n, r: runs["base"].append(n)),
        RateGroup("hk", 5, 0, lambda n, r: runs["hk"].append(n)),   # 1 Hz at a 5 Hz base
        RateGroup("hk2", 5, 2, lambda n, r: runs["hk2"].append(n)),
    ]
    TickScheduler(TICK, groups, clk.now, clk.sleep_until).run(12)
    assert runs["base"] == list(range(12))
    assert runs["hk"] == [0, 5, 10]
    assert runs["hk2"] == [2, 7]


def test_forced_overrun_is_counted_and_grid_kept() -> None:
    clk = FakeClock()
    releases: list[int] = []

    def base(tick: int, release: int) -> None:
        releases.append(tick)
        if tick == 3:
            clk.work(int(2.5 * TICK))  # ends 1.5 ticks after the next release

    records = []
    sched = TickScheduler(TICK, [RateGroup("base", 1, 0, base)], clk.now, clk.sleep_until,
                          on_tick=records.append)
    stats = sched.run(10)
    assert stats.overruns == 1
    assert stats.skipped_releases == 2          # releases 4 and 5 were in the past
    assert releases == [0, 1, 2, 3, 6, 7, 8, 9]
    rec6 = next(r for r in records if r.tick == 6)
    assert rec6.release_ns == sched.t0_ns + 6 * TICK   # back on the grid, not shifted
    assert rec6.jitter_ns == 0
    assert "overrun: tick 3" in stats.events[0]


def test_exactly_finishing_at_next_release_is_not_an_overrun() -> None:
    clk = FakeClock()
    stats = TickScheduler(TICK, [RateGroup("b", 1, 0, lambda n, r: clk.work(TICK))],
                          clk.now, clk.sleep_until).run(5)
    assert stats.overruns == 0


@pytest.mark.parametrize(("divisor", "offset"), [(0, 0), (5, 5), (3, -1)])
def test_bad_rate_group_rejected(divisor: int, offset: int) -> None:
    with pytest.raises(ValueError, match="rate group g"):
        RateGroup("g", divisor, offset, lambda n, r: None)


# --- the real-time flight's grid on the gyro's arrivals (hil.scheduler.align_to_samples)

MS = 1_000_000


def test_grid_on_earliest_arrival_not_the_first() -> None:
    # 5 Hz gyro, 5 Hz tick: samples 7, 8, 9 arrive 3 ms, 0.5 ms and 1 ms after their time.
    t = {7: 1_400 * MS, 8: 1_600 * MS, 9: 1_800 * MS}
    seen = [(7, t[7] + 3 * MS), (8, t[8] + MS // 2), (9, t[9] + MS)]
    g = align_to_samples(seen, TICK, TICK, offset_ns=-MS)
    assert g.per_tick == 1 and g.seq_first == 10
    assert g.t0_ns == 2_000 * MS + MS // 2 - MS  # sample 10's earliest arrival, minus 1 ms
    assert [g.expected_seq(n) for n in range(3)] == [10, 11, 12]


def test_grid_ticks_on_samples_at_tick_boundaries() -> None:
    # 50 Hz gyro under a 5 Hz tick: ticks take samples 20, 30, ... (seq % 10 == 0).
    period = TICK // 10
    seen = [(13, 13 * period + MS), (14, 14 * period + MS)]
    g = align_to_samples(seen, period, TICK)
    assert (g.per_tick, g.seq_first, g.t0_ns) == (10, 20, 20 * period + MS)
    assert g.expected_seq(3) == 50


def test_grid_without_whole_samples_per_tick_does_not_wait() -> None:
    g = align_to_samples([(0, 0)], period_ns=TICK * 2 // 3, tick_ns=TICK)
    assert g.per_tick == 0 and g.expected_seq(4) is None
    assert g.reached(5, 4) and not g.reached(None, 4)


def test_sample_counter_wraps() -> None:
    g = align_to_samples([(65534, 0)], TICK, TICK)
    assert g.seq_first == 65535 and g.expected_seq(1) == 0 and g.expected_seq(2) == 1
    assert g.reached(0, 1) and g.reached(3, 1) and not g.reached(65535, 1)
    assert seq_at_or_after(2, 65530) and not seq_at_or_after(65530, 2)


def test_alignment_needs_a_sample() -> None:
    with pytest.raises(ValueError, match="at least one sample"):
        align_to_samples([], TICK, TICK)


def test_tick_waits_for_its_sample_within_the_bound_and_keeps_the_grid() -> None:
    """A late sample delays the tick's work (not its release); a missing one is waited for
    only up to the bound; the grid and the overrun count are unaffected."""
    clk = FakeClock()
    arrivals = {0: 2 * MS, 1: 0, 2: 40 * MS, 3: None}  # tick -> sample delay after release
    newest: list[int] = [-1]
    log: list[tuple[int, bool, int]] = []

    def base(tick: int, release: int) -> None:
        def bus_wait(timeout_s: float) -> None:  # a blocking read: sleeps until the sample
            d = arrivals[tick]
            if d is not None and release + d <= clk.now() + timeout_s * 1e9:
                clk.sleep_until(release + d)
                newest[0] = tick
            else:
                clk.work(int(timeout_s * 1e9))
        got = wait_for(lambda: newest[0] >= tick, bus_wait, clk.now, release + 20 * MS)
        log.append((tick, got, clk.now() - release))
        clk.work(3 * MS)  # the tick's compute

    sched = TickScheduler(TICK, [RateGroup("base", 1, 0, base)], clk.now, clk.sleep_until)
    stats = sched.run(4)
    assert log == [(0, True, 2 * MS), (1, True, 0), (2, False, 20 * MS), (3, False, 20 * MS)]
    assert stats.overruns == 0
