"""Tick scheduler driven by a fake clock: absolute grid, rate groups, forced overruns."""

from __future__ import annotations

import pytest

from hil.scheduler import RateGroup, TickScheduler

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
