"""Strict tick scheduler: one base tick, rate groups as divisors, absolute releases, overruns.

Modelled on F Prime's ``Svc/RateGroupDriver`` + ``ActiveRateGroup`` (docs/style.md): a base tick of
``tick_ns`` drives rate groups given as ``(divisor, offset)``; a group runs on base tick ``n``
when ``n % divisor == offset``. Releases are on an absolute grid ``t0 + n * tick`` (docs/design.md
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


# --------------------------------------------------------------------------- sensor alignment

SEQ_MOD = 1 << 16  # the gyro sample counter on the bus (``Gyro.sample_seq``) is 16 bits


def seq_at_or_after(seq: int, ref: int, mod: int = SEQ_MOD) -> bool:
    """``seq`` is ``ref`` or a later sample on a wrapping counter (half the range ahead)."""
    return (seq - ref) % mod < mod // 2


@dataclass(frozen=True)
class SampleGrid:
    """A tick grid placed on a periodic sensor's arrivals, and the sample each tick waits for.

    ``t0_ns``: release of tick 0 (absolute, the scheduler's clock); tick ``n`` is released at
    ``t0_ns + n * tick`` as always. ``seq_first``: the sample that belongs to tick 0;
    ``per_tick``: samples per tick, so tick ``n`` waits for ``seq_first + n * per_tick``; 0
    when the sample rate is not a whole multiple of the tick rate (ticks then take the newest
    sample and do not wait).
    """

    t0_ns: int
    seq_first: int
    per_tick: int

    def expected_seq(self, tick: int) -> int | None:
        if not self.per_tick:
            return None
        return (self.seq_first + tick * self.per_tick) % SEQ_MOD

    def reached(self, seq: int | None, tick: int) -> bool:
        """Has the sample of ``tick`` (or a later one) arrived, ``seq`` being the newest?"""
        want = self.expected_seq(tick)
        if want is None:
            return seq is not None
        return seq is not None and seq_at_or_after(seq, want)


def align_to_samples(observed: list[tuple[int, int]], period_ns: int, tick_ns: int,
                     offset_ns: int = 0) -> SampleGrid:
    """Place the tick grid on the arrivals of the first samples.

    ``observed``: (sequence number, arrival time ns) of the first samples received, in order.
    Sample ``seq0 + j`` is expected at ``phase + j * period_ns``; ``phase`` is the earliest
    of the observed ``arrival - j * period_ns``, so one sample delayed at start-up does not
    shift the grid (a release too late would add its delay to every tick's latency; one too
    early only makes the tick wait). Tick 0 is the first sample after the last observed one
    that falls on a tick boundary (``seq % per_tick == 0``: the sender numbers samples from
    its time zero, tick boundaries included; valid while the counter has not wrapped at
    alignment). Its release is that sample's expected arrival plus ``offset_ns``.
    """
    if not observed:
        raise ValueError("align_to_samples: observed: expected at least one sample, got none")
    if period_ns <= 0 or tick_ns <= 0:
        raise ValueError(f"align_to_samples: expected positive periods, got sample {period_ns} "
                         f"ns, tick {tick_ns} ns")
    seq0 = observed[0][0]
    rel = [((seq - seq0) % SEQ_MOD, rx) for seq, rx in observed]
    phase = min(rx - j * period_ns for j, rx in rel)
    j0 = max(j for j, _ in rel) + 1
    ratio = tick_ns / period_ns
    m = int(round(ratio))
    tied = m >= 1 and abs(ratio - m) < 1e-6
    if tied:
        while (seq0 + j0) % m:
            j0 += 1
    return SampleGrid(phase + j0 * period_ns + offset_ns, (seq0 + j0) % SEQ_MOD,
                      m if tied else 0)


def wait_for(done: Callable[[], bool], wait_s: Callable[[float], object],
             now_ns: Callable[[], int], until_ns: int) -> bool:
    """Bounded wait: call ``wait_s(timeout)`` (a blocking read of the bus) until ``done()`` or
    ``until_ns`` on the ``now_ns`` clock. Returns ``done()``."""
    now = now_ns()
    while not done() and now < until_ns:
        wait_s((until_ns - now) / 1e9)
        now = now_ns()
    return done()
