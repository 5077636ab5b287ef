"""Strict tick scheduler: one base tick, rate groups as divisors, absolute releases, overruns.

Modelled on F Prime's ``Svc/RateGroupDriver`` + ``ActiveRateGroup`` (STYLE.md): a base tick of
``tick_ns`` drives rate groups given as ``(divisor, offset)``; a group runs on base tick ``n``
when ``n % divisor == offset``. Releases are on an absolute grid ``t0 + n * tick`` (DESIGN.md
section 3: never "sleep h after the work", so no drift). A tick whose work ends after the next
release is an *overrun* (F Prime's "slip"): it is counted, reported as an event, and the
scheduler skips to the next release still ahead on the grid; the skipped releases are counted
too. Nothing is silently absorbed.

The scheduler owns no clock: ``now_ns`` and ``sleep_until_ns`` are injected, so tests drive it
with a fake clock and force overruns on purpose; the process shell passes
``time.monotonic_ns`` and a ``clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)`` sleeper.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass(frozen=True)
class RateGroup:
    """A group of work run every ``divisor`` base ticks, on ticks ``n % divisor == offset``."""

    name: str
    divisor: int
    offset: int
    run: Callable[[int, int], None]  # run(tick, release_ns)

    def __post_init__(self) -> None:
        if self.divisor < 1:
            raise ValueError(f"rate group {self.name}: divisor: expected >= 1, got {self.divisor}")
        if not 0 <= self.offset < self.divisor:
            raise ValueError(
                f"rate group {self.name}: offset: expected 0..{self.divisor - 1}, got {self.offset}"
            )


@dataclass(frozen=True)
class TickRecord:
    """What happened on one base tick (all times integer ns on the scheduler's clock)."""

    tick: int
    release_ns: int        # scheduled release t0 + tick * tick_ns
    start_ns: int          # when the work actually started
    end_ns: int            # when the last group of this tick finished
    groups: tuple[str, ...]
    overrun: bool          # the work ended after the next release
    skipped: int           # releases skipped after this tick to get back on the grid

    @property
    def jitter_ns(self) -> int:
        return self.start_ns - self.release_ns

    @property
    def busy_ns(self) -> int:
        return self.end_ns - self.start_ns


@dataclass
class SchedulerStats:
    ticks: int = 0
    overruns: int = 0
    skipped_releases: int = 0
    max_busy_ns: int = 0
    events: list[str] = field(default_factory=list)


class TickScheduler:
    """Run rate groups on an absolute tick grid with overrun accounting."""

    def __init__(
        self,
        tick_ns: int,
        groups: list[RateGroup],
        now_ns: Callable[[], int],
        sleep_until_ns: Callable[[int], None],
        on_tick: Callable[[TickRecord], None] | None = None,
        max_events: int = 1000,
    ) -> None:
        if tick_ns <= 0:
            raise ValueError(f"scheduler: tick_ns: expected > 0, got {tick_ns}")
        self.tick_ns = tick_ns
        self.groups = list(groups)
        self._now = now_ns
        self._sleep_until = sleep_until_ns
        self._on_tick = on_tick
        self._max_events = max_events
        self.stats = SchedulerStats()
        self.t0_ns: int | None = None

    def _event(self, text: str) -> None:
        # Throttled like F Prime's warnings: keep the first max_events, count the rest.
        if len(self.stats.events) < self._max_events:
            self.stats.events.append(text)

    def run(self, n_ticks: int | None = None, t0_ns: int | None = None,
            stop: Callable[[], bool] | None = None) -> SchedulerStats:
        """Run until ``n_ticks`` base ticks were released (or ``stop()`` is true)."""
        self.t0_ns = self._now() if t0_ns is None else t0_ns
        tick = 0
        while n_ticks is None or tick < n_ticks:
            if stop is not None and stop():
                break
            release = self.t0_ns + tick * self.tick_ns
            self._sleep_until(release)
            start = self._now()
            ran = []
            for g in self.groups:
                if tick % g.divisor == g.offset:
                    g.run(tick, release)
                    ran.append(g.name)
            end = self._now()
            next_release = release + self.tick_ns
            overrun = end > next_release
            skipped = 0
            if overrun:
                # Stay on the grid: the next release is the first grid point still ahead.
                skipped = (end - next_release) // self.tick_ns + 1
                self.stats.overruns += 1
                self.stats.skipped_releases += skipped
                self._event(
                    f"overrun: tick {tick} busy {(end - start) / 1e6:.3f} ms "
                    f"(tick {self.tick_ns / 1e6:.1f} ms), {skipped} release(s) skipped"
                )
            rec = TickRecord(tick, release, start, end, tuple(ran), overrun, skipped)
            self.stats.ticks += 1
            self.stats.max_busy_ns = max(self.stats.max_busy_ns, rec.busy_ns)
            if self._on_tick is not None:
                self._on_tick(rec)
            tick += 1 + skipped
        return self.stats


def monotonic_sleep_until(target_ns: int) -> None:
    """Sleep until an absolute CLOCK_MONOTONIC time (no drift from the work done before)."""
    import time

    while True:
        remaining = target_ns - time.monotonic_ns()
        if remaining <= 0:
            return
        # clock_nanosleep(TIMER_ABSTIME) is not exposed by Python; sleep short of the target and
        # finish with a short spin so the release lands within tens of microseconds.
        if remaining > 2_000_000:
            time.sleep((remaining - 1_000_000) / 1e9)
        elif remaining > 200_000:
            time.sleep(remaining / 2e9)
