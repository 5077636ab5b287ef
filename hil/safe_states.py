"""The safe states of the process shells (docs/design.md section 4), sans-IO.

The flight enters safe mode (no firing, FDIR_STATUS safe flag, heartbeat state SAFE) when no
valid gyro sample arrived for ``gyro_lost_ticks`` ticks (``GyroLossWatch``); the real-time plant
closes every valve (and manifold) when THR_CMD is missing for ``thr_cmd_lost_ticks`` ticks or
the flight heartbeat is silent for ``heartbeat_lost_s`` (``FlightLinkWatch``). The counts come
from the scenario's ``safety:`` block with the node's command-line overrides
(``safety_settings``).
"""

from __future__ import annotations

from bus.catalog import Node as NodeId
from bus.codec import Heartbeat, ThrCmd
from bus.protocol import HeartbeatMonitor, PeerBack, PeerLost
from hil.config import SafetyCfg, Scenario
from hil.node_settings import NodeSettings


class GyroLossWatch:
    """Flight side of the safe states (sans-IO): safe mode after ``lost_ticks`` ticks in a row
    without a valid gyro sample, left at the next valid one.

    Call ``tick(fresh)`` once per flight tick (``fresh``: a sample that passed the receiver's
    checks arrived since the last tick); it returns ``"lost"`` on entering safe mode,
    ``"back"`` on leaving it, otherwise None.
    """

    def __init__(self, lost_ticks: int) -> None:
        if lost_ticks < 1:
            raise ValueError(f"GyroLossWatch: lost_ticks: expected >= 1, got {lost_ticks}")
        self.lost_ticks = lost_ticks
        self.ticks_without = 0
        self.safe = False

    def tick(self, fresh: bool) -> str | None:
        self.ticks_without = 0 if fresh else self.ticks_without + 1
        if not self.safe and self.ticks_without >= self.lost_ticks:
            self.safe = True
            return "lost"
        if self.safe and fresh:
            self.safe = False
            return "back"
        return None


class FlightLinkWatch:
    """Real-time plant side of the safe states (sans-IO; times are seconds on the plant's clock).

    The flight is lost when its heartbeat has been silent for ``heartbeat_lost_s`` (counted
    from ``start_s`` until a first beat), or, once a THR_CMD has come, when none came for
    ``thr_cmd_lost_ticks`` ticks of ``tick_s``. A flight that beats but whose commands never
    arrive (they are all refused: forged sets ahead of them took their alive counters) is lost
    too: ``heartbeat_lost_s`` plus those ticks after its first beat with no THR_CMD yet.
    ``poll(now_s)`` returns the reasons that newly hold (each once per loss); ``on_message``
    returns the events of the link coming back.
    """

    def __init__(self, tick_s: float, thr_cmd_lost_ticks: int, heartbeat_lost_s: float,
                 start_s: float = 0.0) -> None:
        self.thr_cmd_lost_ticks = thr_cmd_lost_ticks
        self.cmd_limit_s = thr_cmd_lost_ticks * tick_s
        # The monitor's timeout is period x missed_limit: here the configured silence.
        self.mon = HeartbeatMonitor(NodeId.FLIGHT, start_s, period_s=heartbeat_lost_s,
                                    missed_limit=1)
        self.last_cmd_s: float | None = None
        self.cmd_lost = False
        self.heartbeat_lost_s = heartbeat_lost_s
        self.first_beat_s: float | None = None

    def on_message(self, msg, t_s: float) -> list[str]:
        out = [f"flight heartbeat back at {t_s:.2f} s" for ev in self.mon.on_message(msg, t_s)
               if isinstance(ev, PeerBack)]
        if isinstance(msg, ThrCmd):
            self.last_cmd_s, self.cmd_lost = t_s, False
        elif self.first_beat_s is None and isinstance(msg, Heartbeat) and \
                msg.node == NodeId.FLIGHT:
            self.first_beat_s = t_s
        return out

    def poll(self, now_s: float) -> list[str]:
        out = [f"flight heartbeat lost ({ev.silent_s:.2f} s silent)"
               for ev in self.mon.poll(now_s) if isinstance(ev, PeerLost)]
        if self.last_cmd_s is not None and not self.cmd_lost and \
                now_s - self.last_cmd_s > self.cmd_limit_s:
            self.cmd_lost = True
            out.append(f"no THR_CMD for {self.thr_cmd_lost_ticks} ticks")
        elif self.last_cmd_s is None and self.first_beat_s is not None and not self.cmd_lost \
                and now_s - self.first_beat_s > self.heartbeat_lost_s + self.cmd_limit_s:
            self.cmd_lost = True
            out.append(f"no THR_CMD in {now_s - self.first_beat_s:.2f} s since the flight's "
                       "first heartbeat")
        return out

    @property
    def alive(self) -> bool:
        return self.mon.alive


class CommandGate:
    """Plant side: which THR_CMD may be applied, and when a safe state may be left (sans-IO;
    times are seconds on the plant's clock).

    A command is applied only when it belongs to a tick newer than the last one applied
    (``out_of_order`` otherwise: a repeated, reordered or delayed frame) and it is fresh: the
    gyro sample it was computed from (``ThrCmd.gyro_seq``) was taken at most ``deadline_s``
    before the command arrived (``stale`` otherwise: a flight that stalled sends a command
    for a craft that has moved on; ``unknown_sample`` when that sample is not one this plant
    published). A dropped command is counted and never applied.

    Leaving a safe state needs the flight's recovery to be established: ``recover_ticks``
    fresh commands of consecutive ticks, not one frame. ``judge`` returns the class of the
    command; ``may_leave_safe`` says whether the run of fresh consecutive commands is long
    enough.
    """

    CLASSES = ("fresh", "stale", "out_of_order", "unknown_sample")

    def __init__(self, deadline_s: float, recover_ticks: int) -> None:
        if recover_ticks < 1:
            raise ValueError(f"CommandGate: recover_ticks: expected >= 1, got {recover_ticks}")
        self.deadline_s = deadline_s
        self.recover_ticks = recover_ticks
        self.last_tick: int | None = None
        self.run_length = 0  # fresh commands of consecutive ticks, the newest last
        self.counts = {k: 0 for k in self.CLASSES}

    def judge(self, tick: int, t_sample_s: float | None, rx_s: float) -> str:
        if self.last_tick is not None and tick <= self.last_tick:
            verdict = "out_of_order"
        elif t_sample_s is None:
            verdict = "unknown_sample"
        elif rx_s - t_sample_s > self.deadline_s:
            verdict = "stale"
        else:
            verdict = "fresh"
        self.counts[verdict] += 1
        if verdict == "fresh":
            consecutive = self.last_tick is not None and tick == self.last_tick + 1
            self.run_length = self.run_length + 1 if consecutive else 1
            self.last_tick = tick
        elif verdict != "out_of_order":
            self.run_length = 0
        return verdict

    def may_leave_safe(self) -> bool:
        return self.run_length >= self.recover_ticks


def safety_settings(sc: Scenario, settings: NodeSettings) -> SafetyCfg:
    """The scenario's ``safety`` block with this node's command-line overrides applied."""
    over = {k: v for k, v in (("thr_cmd_lost_ticks", settings.lost_after),
                              ("heartbeat_lost_s", settings.heartbeat_lost_s),
                              ("gyro_lost_ticks", settings.gyro_lost_after))
            if v is not None}
    return sc.cfg.safety.model_copy(update=over) if over else sc.cfg.safety
