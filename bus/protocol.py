"""Lockstep and heartbeat protocols as sans-IO state machines (docs/design.md sections 3 and 4).

No sockets, no clocks: every call takes the time ``now_s`` (float seconds, any one clock the
caller chooses) and returns events (frozen dataclasses) and messages to send. The process
shells move messages between these machines and a ``bus.transport.Port``; tests move them
through ``bus.link.FakeLink``.

Lockstep (docs/design.md section 3): the plant is the time master. ``PlantLockstep.begin_tick``
gives SYNC(n) to send; THR_CMD(n) must arrive within ``reply_timeout_s``; ``poll`` at or
after the deadline turns a missing command into ``DeadlineMissed`` and the safe action (all
thrusters off, manifolds as commanded last); after ``lost_after_misses`` consecutive misses
``CommandLost`` and the safe action closes every manifold (docs/design.md section 4: loss of
THR_CMD for N ticks puts the plant's valves closed). ``FlightLockstep`` turns SYNC(n) into a
``TickRequest`` and the computed command into THR_CMD(n).

Heartbeats: ``HeartbeatSender`` is due on an absolute grid (start + k * period, no drift);
``HeartbeatMonitor`` declares the peer lost after ``missed_limit`` periods without a
heartbeat (``PeerLost``) and back on the next one (``PeerBack``).

The transitions are written as data (``*_TRANSITIONS``); an input that has no transition
from the current state is ignored and counted in ``ignored``.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

from bus.catalog import HEARTBEAT_PERIOD_S, NodeState
from bus.catalog import Node as NodeId
from bus.codec import Gyro, Heartbeat, Message, Sync, ThrCmd
from common.errors import ConfigError

# --- events -----------------------------------------------------------------------------


@dataclass(frozen=True)
class CommandReady:
    """THR_CMD(tick) arrived complete and valid ``latency_s`` after SYNC(tick) was sent."""

    tick: int
    command: ThrCmd
    latency_s: float


@dataclass(frozen=True)
class DeadlineMissed:
    tick: int
    consecutive: int


@dataclass(frozen=True)
class CommandLost:
    """``consecutive`` ticks without a valid THR_CMD: the plant closes every manifold."""

    tick: int
    consecutive: int


@dataclass(frozen=True)
class UnexpectedCommand:
    """A complete THR_CMD for a tick that is not the one awaited (late or early)."""

    expected_tick: int | None
    got_tick: int


@dataclass(frozen=True)
class TickRequest:
    """Flight: compute tick ``tick`` (SYNC received at ``rx_s``)."""

    tick: int
    sim_time_ms: int
    rx_s: float


@dataclass(frozen=True)
class SyncGap:
    expected_tick: int
    got_tick: int


@dataclass(frozen=True)
class DuplicateSync:
    tick: int


@dataclass(frozen=True)
class PeerLost:
    node: NodeId
    at_s: float
    silent_s: float


@dataclass(frozen=True)
class PeerBack:
    node: NodeId
    at_s: float


@dataclass(frozen=True)
class TickResult:
    """What the plant applies for ``tick``: the flight's command or the safe action."""

    tick: int
    command: ThrCmd
    safe: bool
    reason: str = ""


# --- plant side -------------------------------------------------------------------------

PLANT_TRANSITIONS = {
    ("idle", "begin"): "waiting",
    ("commanded", "begin"): "waiting",
    ("missed", "begin"): "waiting",
    ("waiting", "command"): "commanded",
    ("waiting", "deadline"): "missed",
}


class PlantLockstep:
    """Plant side of the lockstep: SYNC(n) out, THR_CMD(n) in before the deadline.

    ``n_thrusters``: size of the safe command. ``manifold_enable_safe``: the mask applied on
    a single miss before any command was received. ``lost_reply_timeout_s``: once the peer is
    declared lost (``lost_after_misses`` misses in a row), the plant waits only this long for
    each later tick's command, so a dead flight does not slow the run down by a whole
    ``reply_timeout_s`` per tick; the first command that comes back restores the full wait.
    """

    def __init__(
        self,
        n_thrusters: int,
        reply_timeout_s: float = 0.1,
        lost_after_misses: int = 3,
        tick_s: float = 0.2,
        manifold_enable_safe: int = 0,
        lost_reply_timeout_s: float = 0.05,
    ):
        for name, value, ok in (
            ("n_thrusters", n_thrusters, n_thrusters >= 1),
            ("reply_timeout_s", reply_timeout_s, reply_timeout_s > 0),
            ("lost_after_misses", lost_after_misses, lost_after_misses >= 1),
            ("lost_reply_timeout_s", lost_reply_timeout_s, lost_reply_timeout_s > 0),
        ):
            if not ok:
                raise ConfigError("PlantLockstep", name, "> 0", value)
        self.n_thrusters = n_thrusters
        self.reply_timeout_s = reply_timeout_s
        self.lost_reply_timeout_s = min(lost_reply_timeout_s, reply_timeout_s)
        self.lost_after_misses = lost_after_misses
        self.tick_s = tick_s
        self.state = "idle"
        self.tick: int | None = None
        self.sent_s = 0.0
        self.deadline_s = 0.0
        self.consecutive_misses = 0
        self.deadline_misses = 0
        self.last_mask = manifold_enable_safe
        self.ignored: Counter[str] = Counter()
        self._result: TickResult | None = None

    def _go(self, what: str) -> bool:
        nxt = PLANT_TRANSITIONS.get((self.state, what))
        if nxt is None:
            self.ignored[f"{self.state}/{what}"] += 1
            return False
        self.state = nxt
        return True

    def begin_tick(self, tick: int, now_s: float, sim_time_ms: int | None = None) -> Sync:
        """Start tick ``tick``: returns the SYNC to send. A tick still waiting is missed first."""
        if self.state == "waiting":
            self.poll(max(now_s, self.deadline_s))
        self._go("begin")
        self.tick = tick
        self.sent_s = now_s
        self.deadline_s = now_s + (self.lost_reply_timeout_s if self.lost
                                   else self.reply_timeout_s)
        self._result = None
        ms = round(tick * self.tick_s * 1000) if sim_time_ms is None else sim_time_ms
        return Sync(tick, ms)

    def on_message(self, msg: Message, now_s: float) -> list:
        if not isinstance(msg, ThrCmd):
            return []
        if self.state != "waiting" or msg.tick != self.tick:
            self.ignored["unexpected_command"] += 1
            return [UnexpectedCommand(self.tick if self.state == "waiting" else None, msg.tick)]
        if now_s > self.deadline_s:  # arrived, but after the deadline: poll decides
            return self.poll(now_s)
        self._go("command")
        self.consecutive_misses = 0
        self.last_mask = msg.manifold_enable
        self._result = TickResult(msg.tick, msg, False)
        return [CommandReady(msg.tick, msg, now_s - self.sent_s)]

    def poll(self, now_s: float) -> list:
        """Deadline check; call at (or after) ``deadline_s`` if no command came."""
        if self.state != "waiting" or now_s < self.deadline_s:
            return []
        self._go("deadline")
        self.consecutive_misses += 1
        self.deadline_misses += 1
        events: list = [DeadlineMissed(self.tick, self.consecutive_misses)]
        lost = self.consecutive_misses >= self.lost_after_misses
        if lost:
            events.append(CommandLost(self.tick, self.consecutive_misses))
        mask = 0 if lost else self.last_mask
        safe = ThrCmd(self.tick, (0,) * self.n_thrusters, mask, 0)
        self._result = TickResult(
            self.tick, safe, True, "command lost: manifolds closed" if lost else "deadline missed"
        )
        return events

    @property
    def lost(self) -> bool:
        """The peer is declared lost: ``lost_after_misses`` or more misses in a row."""
        return self.consecutive_misses >= self.lost_after_misses

    @property
    def result(self) -> TickResult | None:
        """The command to apply for the current tick once decided (ready or missed)."""
        return self._result


# --- flight side ------------------------------------------------------------------------

FLIGHT_TRANSITIONS = {
    ("idle", "sync"): "computing",
    ("replied", "sync"): "computing",
    ("computing", "sync"): "computing",  # a newer SYNC overtakes an unfinished tick
    ("computing", "reply"): "replied",
}


class FlightLockstep:
    """Flight side: SYNC(n) -> ``TickRequest(n)``; ``reply`` builds THR_CMD(n).

    Keeps the newest GYRO sample (``gyro``) for the tick pipeline.
    """

    def __init__(self) -> None:
        self.state = "idle"
        self.tick: int | None = None
        self.last_tick: int | None = None
        self.gyro: Gyro | None = None
        self.gyro_rx_s: float | None = None
        self.ignored: Counter[str] = Counter()
        self.gaps = 0
        self.duplicates = 0

    def on_message(self, msg: Message, now_s: float) -> list:
        if isinstance(msg, Gyro):
            self.gyro, self.gyro_rx_s = msg, now_s
            return []
        if not isinstance(msg, Sync):
            return []
        events: list = []
        if self.last_tick is not None and msg.tick <= self.last_tick:
            self.duplicates += 1
            return [DuplicateSync(msg.tick)]
        if self.last_tick is not None and msg.tick != self.last_tick + 1:
            self.gaps += 1
            events.append(SyncGap(self.last_tick + 1, msg.tick))
        if self.state == "computing":
            self.ignored["computing/sync"] += 1
        self.state = FLIGHT_TRANSITIONS[(self.state, "sync")]
        self.tick = self.last_tick = msg.tick
        events.append(TickRequest(msg.tick, msg.sim_time_ms, now_s))
        return events

    def reply(
        self,
        tick: int,
        on_quanta: tuple[int, ...],
        manifold_enable: int,
        gyro_seq: int | None = None,
    ) -> ThrCmd | None:
        """THR_CMD for ``tick``; None (and counted) if that tick is not the one requested."""
        if (self.state, "reply") not in FLIGHT_TRANSITIONS or tick != self.tick:
            self.ignored[f"{self.state}/reply"] += 1
            return None
        self.state = FLIGHT_TRANSITIONS[(self.state, "reply")]
        if gyro_seq is None:
            gyro_seq = self.gyro.sample_seq if self.gyro else 0
        return ThrCmd(tick, tuple(on_quanta), manifold_enable, gyro_seq)


# --- heartbeats -------------------------------------------------------------------------

MONITOR_TRANSITIONS = {
    ("waiting", "seen"): "alive",
    ("alive", "seen"): "alive",
    ("lost", "seen"): "alive",
    ("waiting", "timeout"): "lost",
    ("alive", "timeout"): "lost",
}


class HeartbeatSender:
    """Due at start + k * period (absolute grid: a late call does not shift later ones)."""

    def __init__(self, node: NodeId, start_s: float, period_s: float = HEARTBEAT_PERIOD_S):
        self.node = node
        self.period_s = period_s
        self.next_s = start_s
        self.sent = 0

    def poll(
        self,
        now_s: float,
        state: NodeState,
        rx_ok: int = 0,
        rx_bad: int = 0,
        deadline_miss: int = 0,
    ) -> Heartbeat | None:
        if now_s < self.next_s:
            return None
        k = int((now_s - self.next_s) // self.period_s) + 1  # skip missed slots, stay on grid
        self.next_s += k * self.period_s
        self.sent += 1
        return Heartbeat(self.node, state, rx_ok % 65536, rx_bad % 65536, deadline_miss % 4096)


class HeartbeatMonitor:
    """Watches one peer: lost after ``missed_limit`` periods of silence, back when seen."""

    def __init__(
        self,
        peer: NodeId,
        start_s: float,
        period_s: float = HEARTBEAT_PERIOD_S,
        missed_limit: int = 3,
    ):
        self.peer = peer
        self.period_s = period_s
        self.missed_limit = missed_limit
        self.state = "waiting"
        self.last_seen_s = start_s  # silence is counted from the start until a first beat
        self.last: Heartbeat | None = None
        self.lost_count = 0

    @property
    def timeout_s(self) -> float:
        return self.period_s * self.missed_limit

    def on_message(self, msg: Message, now_s: float) -> list:
        if not isinstance(msg, Heartbeat) or msg.node != self.peer:
            return []
        was = self.state
        self.state = MONITOR_TRANSITIONS[(self.state, "seen")]
        self.last_seen_s = now_s
        self.last = msg
        return [PeerBack(self.peer, now_s)] if was == "lost" else []

    def poll(self, now_s: float) -> list:
        silent = now_s - self.last_seen_s
        if self.state == "lost" or silent <= self.timeout_s:
            return []
        self.state = MONITOR_TRANSITIONS[(self.state, "timeout")]
        self.lost_count += 1
        return [PeerLost(self.peer, now_s, silent)]

    @property
    def alive(self) -> bool:
        return self.state == "alive"
