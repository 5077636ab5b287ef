"""The plant and flight processes: thin shells around the pure cores, talking only over CAN.

``python -m hil.nodes plant --scenario S.yaml --out DIR [--mode lockstep|realtime] ...``
``python -m hil.nodes flight --scenario S.yaml --out DIR [--mode lockstep|realtime] ...``

Each shell owns a clock, a ``bus.transport.Port`` and a per-tick JSON lines file in ``DIR``
(``plant.jsonl`` / ``flight.jsonl``, flushed every tick, see ``hil.recorder``). ``hil run`` and
``hil up`` start them; they can also be started by hand on two machines sharing a CAN bus.

Lockstep (docs/design.md section 3): the plant is the time master: GYRO + SYNC(n), wait for
THR_CMD(n) (deadline ``--reply-timeout``; a miss applies the safe action), apply it at
``t_n`` + command latency, integrate to ``t_n+1``. Real time: the plant integrates on
CLOCK_MONOTONIC and publishes each gyro sample when it is due; the flight runs the strict
tick scheduler (``hil.scheduler``) on the same clock, its grid placed on the observed gyro
arrivals, and each tick waits (bounded) for its own sample before it computes; the plant
applies each THR_CMD at its kernel receive time and records the latency chain (gyro sample
time, publish, THR_CMD receive, apply) per command (``PlantShell.run_realtime``,
``FlightShell.run_realtime``).

Scheduler policy (without ``--rt-priority``): the plant SCHED_BATCH, the flight SCHED_OTHER
(``_set_policy``), so on one CPU the plant does not interrupt a flight tick; the policy each
node got is in its first record (``sched``).

Safe states (docs/design.md section 4), counts from the scenario's ``safety:`` block
(``hil.config.SafetyCfg``; ``--lost-after``, ``--heartbeat-lost-s`` and ``--gyro-lost-after``
override them): the plant closes every valve (and manifold) when THR_CMD is missing for
``thr_cmd_lost_ticks`` ticks or, in real time, the flight heartbeat is silent for
``heartbeat_lost_s`` (``FlightLinkWatch``); the flight enters safe mode (no firing, FDIR_STATUS
safe flag, heartbeat state SAFE) when no valid gyro sample arrived for ``gyro_lost_ticks`` ticks
(``GyroLossWatch``). Both are events in the records and on the terminal. In lockstep the flight
ticks on SYNC, so a dead plant stops its ticks instead (nothing is fired without a SYNC).

Each node's first record carries ``config`` (scenario, vehicle and its file, thruster names,
mode, bus, the safe-state settings it uses): ``hil fault`` learns the vehicle of a running
``hil up`` from it, and ``hil.summary`` puts the settings in ``summary.json``. With
``--rt-priority`` (``hil run --rt``, ``hil up --rt``) the first record also has an event that
says what was granted or refused.
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import signal
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bus.catalog import (
    CATALOG,
    HEARTBEAT_PERIOD_S,
    AckReason,
    AckStatus,
    Catalog,
    DetectedFault,
    FaultAction,
    FaultKind,
    NodeState,
)
from bus.catalog import Node as NodeId
from bus.codec import FaultAck, FaultCmd, FdirStatus, FlightTiming, Gyro, ThrCmd
from bus.protocol import (
    CommandLost,
    DeadlineMissed,
    FlightLockstep,
    HeartbeatMonitor,
    HeartbeatSender,
    PeerBack,
    PeerLost,
    PlantLockstep,
    TickRequest,
)
from bus.receiver import Receiver
from bus.transport import BusConfig, BusLogger, Port, open_bus
from hil.config import SafetyCfg, Scenario, load_scenario, resolve_vehicle_path
from hil.errors import FaultCommandError, HilError
from hil.recorder import JsonlWriter, newly_active_faults
from hil.scheduler import (
    RateGroup,
    TickRecord,
    TickScheduler,
    align_to_samples,
    monotonic_sleep_until,
    wait_for,
)

XYZ = ("x", "y", "z")
DEG = 180.0 / math.pi
REALTIME_MAX_WAIT_S = 0.02  # the real-time plant wakes at least this often (see run_realtime)
REALTIME_PRE_WAKE_S = 0.005  # ... and this long before each gyro sample
REPEAT_WINDOW_S = 10.0  # an identical FAULT_CMD this soon is the panel's resend (not applied)


def _r6(x: float | None) -> float | None:
    return None if x is None else round(x, 6)


def _xyz(v, scale: float = 1.0) -> dict[str, float]:
    return {k: float(v[i]) * scale for i, k in enumerate(XYZ)}


def _named(names, values) -> dict[str, float]:
    return {n: float(x) for n, x in zip(names, values, strict=True)}


class _Stop:
    """SIGTERM/SIGINT set a flag; loops finish the current tick and exit cleanly."""

    def __init__(self) -> None:
        self.flag = False
        signal.signal(signal.SIGTERM, self._set)
        signal.signal(signal.SIGINT, self._set)

    def _set(self, *_: object) -> None:
        self.flag = True

    def __call__(self) -> bool:
        return self.flag


def _lockstep_receiver(reply_timeout_s: float) -> Receiver:
    """A receiver whose age limits follow the lockstep, not the wall clock.

    In lockstep the plant is the time master and the lockstep protocol enforces the THR_CMD
    deadline; a frame that waited in the socket while its reader computed (a slow or loaded
    machine) is not stale in simulated time, and dropping it would make a run depend on the
    machine. CRC, counter, length, range and completeness checks stay as they are.
    """
    limit = max(10 * reply_timeout_s, 5.0)
    cat = Catalog(tuple(replace(f, deadline_s=max(f.deadline_s, limit)) for f in CATALOG.frames))
    return Receiver(catalog=cat)


def _open_port(args, out: Path, name: str) -> Port:
    cfg = BusConfig(interface=args.interface, channel=args.channel)
    logger = BusLogger(out / f"{name}.bus.log", channel=args.channel) if args.bus_log else None
    receiver = _lockstep_receiver(args.reply_timeout) if args.mode == "lockstep" else None
    return Port(open_bus(cfg), receiver=receiver, logger=logger)


def _say(name: str, text: str) -> None:
    print(f"[{name}] {text}", flush=True)


# ============================================================================ safe states


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
    ``thr_cmd_lost_ticks`` ticks of ``tick_s``. ``poll(now_s)`` returns the reasons that newly
    hold (each once per loss); ``on_message`` returns the events of the link coming back.
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

    def on_message(self, msg, t_s: float) -> list[str]:
        out = [f"flight heartbeat back at {t_s:.2f} s" for ev in self.mon.on_message(msg, t_s)
               if isinstance(ev, PeerBack)]
        if isinstance(msg, ThrCmd):
            self.last_cmd_s, self.cmd_lost = t_s, False
        return out

    def poll(self, now_s: float) -> list[str]:
        out = [f"flight heartbeat lost ({ev.silent_s:.2f} s silent)"
               for ev in self.mon.poll(now_s) if isinstance(ev, PeerLost)]
        if self.last_cmd_s is not None and not self.cmd_lost and \
                now_s - self.last_cmd_s > self.cmd_limit_s:
            self.cmd_lost = True
            out.append(f"no THR_CMD for {self.thr_cmd_lost_ticks} ticks")
        return out

    @property
    def alive(self) -> bool:
        return self.mon.alive


def safety_settings(sc: Scenario, args) -> SafetyCfg:
    """The scenario's ``safety`` block with this node's command-line overrides applied."""
    over = {k: v for k, v in (("thr_cmd_lost_ticks", getattr(args, "lost_after", None)),
                              ("heartbeat_lost_s", getattr(args, "heartbeat_lost_s", None)),
                              ("gyro_lost_ticks", getattr(args, "gyro_lost_after", None)))
            if v is not None}
    return sc.cfg.safety.model_copy(update=over) if over else sc.cfg.safety


def node_config(sc: Scenario, args, safety: dict) -> dict:
    """The ``config`` field of a node's first record (see the module doc)."""
    vfile = resolve_vehicle_path(sc.cfg.vehicle, relative_to=sc.path.parent)
    return {"scenario": sc.cfg.name, "vehicle": sc.vehicle.name,
            "vehicle_file": str(vfile.resolve()),
            "thrusters": [t.name for t in sc.vehicle.thrusters], "mode": args.mode,
            "bus": f"{args.interface} {args.channel}", "safety": safety}


def _first_record(sc: Scenario, args, safety: dict) -> dict:
    """Fields only the first record of a node carries (``config``, ``sched``, --rt events)."""
    first: dict = {"config": node_config(sc, args, safety)}
    if getattr(args, "sched_note", None) is not None:
        first["sched"] = args.sched_note
    first["events"] = [args.rt_event] if getattr(args, "rt_event", None) else []
    return first


# ============================================================================ plant


_KIND_FROM_BUS = {
    FaultKind.STUCK_ON: "stuck_on", FaultKind.FAIL_TO_FIRE: "fail_to_fire",
    FaultKind.DEGRADED: "degraded", FaultKind.GYRO_SPIKE: "gyro_spike",
    FaultKind.GYRO_BIAS_STEP: "gyro_bias_step", FaultKind.GYRO_FROZEN: "gyro_frozen",
    FaultKind.GYRO_NOISE: "gyro_noise", FaultKind.BUS_DROP: "bus_drop",
    FaultKind.BUS_DELAY: "bus_delay", FaultKind.BUS_CORRUPT: "bus_corrupt",
    FaultKind.NODE_SILENT: "node_silent",
}


class PlantShell:
    """Plant process: the ``plant.core.Plant`` behind a CAN port."""

    def __init__(self, sc: Scenario, port: Port, out: Path, args) -> None:
        from plant.core import Plant

        self.sc, self.port, self.args = sc, port, args
        self.v = sc.vehicle
        self.h = self.v.timing.tick_s
        self.plant = Plant(self.v, seed=sc.cfg.seed, overrides=sc.cfg.plant,
                           initial=sc.cfg.initial)
        self.names = self.plant.arrays.names
        self.n_thr, self.n_man = len(self.names), len(self.plant.arrays.manifolds)
        self.all_open = (1 << self.n_man) - 1
        for f in sc.cfg.faults:
            if f.kind.startswith("bus_") or f.kind == "node_silent":
                continue  # bus faults act in the shells' send paths, not in the physics
            self.plant.inject(f)
        self.rec = JsonlWriter(out / "plant.jsonl")
        self.events: list[str] = []
        self.reported_faults: set[int] = set()
        self.gyro_time: dict[int, float] = {}   # seq -> sample time (sim s) for latency tracing
        self.gyro_pub: dict[int, float] = {}    # seq -> when it was sent (real time only)
        self.last_gyro: Gyro | None = None
        self.safe = False
        self.target = sc.cfg.target.quaternion()
        self.last_cmd_tick_s = 0.0
        self.safety = safety_settings(sc, args)
        self.cleared: list[dict] = []  # faults the panel ended since the last record
        self.last_fault: tuple[FaultCmd, float, FaultAck] | None = None  # for repeats
        self.first = _first_record(sc, args, {
            "thr_cmd_lost_ticks": self.safety.thr_cmd_lost_ticks,
            "heartbeat_lost_s": self.safety.heartbeat_lost_s})
        self.events.extend(self.first.pop("events"))

    # -- faults from the panel ------------------------------------------------------------

    def on_fault_cmd(self, m: FaultCmd) -> None:
        from hil.config import FaultSpec

        now = time.monotonic()
        last = self.last_fault
        if last is not None and last[0] == m and now - last[1] < REPEAT_WINDOW_S:
            # The panel sent it again (no ACK seen in time, see hil.panel.send_and_wait).
            self.port.send(last[2])
            self.events.append(f"FAULT_CMD request {m.request_id} repeated: acknowledged "
                               f"again, not applied again")
            return
        reason, status = AckReason.NONE, AckStatus.ACCEPTED
        try:
            if m.action == FaultAction.CLEAR:
                thr = None if m.thruster is None else self.names[m.thruster]
                changed = self.plant.clear_faults(thr)
                if not changed:
                    status, reason = AckStatus.REJECTED, AckReason.NOT_ACTIVE
                else:
                    self.events.append(f"fault cleared: {thr or 'all'} (request {m.request_id})")
                    # Matched by hil.summary with faults_injected (thruster, type, start).
                    self.cleared.extend(
                        {"thruster": e.spec.thruster, "type": e.spec.kind,
                         "t_on_s": round(e.t_on_s, 6), "t_s": round(e.t_off_s, 6)}
                        for e in changed)
            else:
                kind = _KIND_FROM_BUS.get(m.kind)
                if kind is None:
                    raise FaultCommandError("fault: kind: expected a known kind, got none")
                if m.thruster is not None and m.thruster >= self.n_thr:
                    status, reason = AckStatus.REJECTED, AckReason.BAD_THRUSTER
                else:
                    spec = FaultSpec(
                        kind=kind, t_s=max(m.start_time_s, self.plant.t),
                        clear_t_s=m.clear_time_s,
                        thruster=None if m.thruster is None else self.names[m.thruster],
                        fraction=m.fraction if kind in ("stuck_on", "degraded") else None,
                        magnitude_rad_s=1e-3 if kind.startswith("gyro") and kind != "gyro_frozen"
                        else None,
                        node="flight" if kind.startswith("bus") or kind == "node_silent" else None,
                    )
                    self.plant.inject(spec)
                    self.events.append(f"fault injected by panel: {kind} "
                                       f"{spec.thruster or ''} at {spec.t_s:.2f} s")
        except (FaultCommandError, ValueError) as exc:
            status, reason = AckStatus.REJECTED, AckReason.BAD_FRACTION
            self.events.append(f"fault command rejected: {exc}")
        ack = FaultAck(m.request_id, status, reason, m.kind)
        self.last_fault = (m, now, ack)
        self.port.send(ack)

    # -- gyro and commands ------------------------------------------------------------------

    def gyro_messages(self, samples, t_pub_s: float | None = None) -> list[Gyro]:
        """GYRO messages of the samples, remembered for latency tracing (sample time, and
        ``t_pub_s``, the real-time publish time on the plant's clock)."""
        out = []
        for s in samples:
            seq = s.seq & 0xFFFF
            self.gyro_time[seq] = s.t_meas_s
            if t_pub_s is not None:
                self.gyro_pub[seq] = t_pub_s
            rate = np.clip(np.asarray(s.rate_B_rad_s, dtype=float), -0.2, 0.2)
            g = Gyro(seq, tuple(float(x) for x in rate), int(s.status) or 1)
            self.last_gyro = g
            out.append(g)
        if len(self.gyro_time) > 4096:
            for k in list(self.gyro_time)[:2048]:
                del self.gyro_time[k]
                self.gyro_pub.pop(k, None)
        return out

    def apply(self, cmd: ThrCmd, t_apply_s: float) -> None:
        on_ms = np.asarray(cmd.on_quanta, dtype=float) * 10.0
        if on_ms.shape[0] != self.n_thr:
            self.events.append(f"THR_CMD rejected: {on_ms.shape[0]} thrusters, "
                               f"expected {self.n_thr}")
            return
        mask = np.array([(cmd.manifold_enable >> m) & 1 for m in range(self.n_man)], dtype=bool)
        self.plant.apply_command(cmd.tick, t_apply_s, on_ms, mask)
        self.last_cmd_tick_s = t_apply_s

    def go_safe(self, t_s: float, why: str) -> None:
        if not self.safe:
            self.safe = True
            self.plant.close_all_valves(t_s, manifolds=True)
            self.events.append(f"safe: all valves and manifolds closed at {t_s:.2f} s ({why})")
            _say("plant", self.events[-1])

    # -- recording ----------------------------------------------------------------------------

    def record(self, tick: int, extra: dict | None = None) -> None:
        from flight.attitude import error_quaternion, rotation_angle, small_angle_vector

        tr = self.plant.truth
        n_err = error_quaternion(self.target, tr.q_BO)
        att = small_angle_vector(n_err) * DEG
        injected = newly_active_faults(self.plant.faults.entries, self.reported_faults, tr.t_s)
        for f in injected:
            self.events.append(f"fault active: {f['type']} {f['thruster'] or ''} "
                               f"at {f['t_s']:.2f} s")
        rec = {
            "tick": tick, "t_s": round(tr.t_s, 9),
            "series": {
                "truth/omega_deg_s": _xyz(tr.omega_BO_B_rad_s, DEG),
                "truth/omega_BI_deg_s": _xyz(tr.omega_B_rad_s, DEG),  # as flight/omega_meas
                "truth/attitude_error_deg": _xyz(att),
                "truth/thrust_n": _named(self.names, tr.thrust_n),
                "truth/flex_gyro_deg_s": _xyz(tr.flex_rate_gyro_B_rad_s, DEG),
            },
            "events": self.events,
            "faults_injected": injected,
            "att_err_deg": float(rotation_angle(n_err) * DEG),
            "rate_err_deg_s": float(np.linalg.norm(tr.omega_BO_B_rad_s) * DEG),
            "fuel_kg": float(np.sum(tr.fuel_kg)),
            "dv_B_m_s": [float(x) for x in tr.dv_B_m_s],
            "safe": self.safe,
            "bus": self.port.counts(),
        }
        if self.cleared:
            rec["faults_cleared"], self.cleared = self.cleared, []
        if extra:
            extra = dict(extra)
            rec["series"].update(extra.pop("series", {}))
            rec.update(extra)
        if self.first:
            rec.update(self.first)
            self.first = {}
        self.rec.write(rec)
        self.events = []
        idle_gc(rec["tick"])

    # -- lockstep -------------------------------------------------------------------------

    def run_lockstep(self, stop: _Stop) -> int:
        a = self.args
        n_ticks = int(round(self.sc.cfg.duration_s / self.h))
        lost_after = self.safety.thr_cmd_lost_ticks
        lock = PlantLockstep(self.n_thr, reply_timeout_s=a.reply_timeout,
                             lost_after_misses=lost_after, tick_s=self.h,
                             manifold_enable_safe=self.all_open)
        cpu0 = time.process_time()
        t_wall0 = time.monotonic()
        for n in range(n_ticks):
            if stop():
                break
            t_n = n * self.h
            self.plant.advance_to(t_n)
            # The newest sample measured by t_n is this tick's (the tick's sensor read).
            ready = self.plant.gyro_samples_until(t_n)
            # GYRO and SYNC in one send: the flight wakes once per tick, not twice.
            self.port.send(*self.gyro_messages(ready[-1:]),
                           lock.begin_tick(n, self.port.now_s(), round(t_n * 1000)))
            latency = None
            while lock.result is None and not stop():
                wait = max(0.0, min(lock.deadline_s - self.port.now_s(), 0.02))
                for msg, rx in self.port.poll(wait):
                    if isinstance(msg, FaultCmd):
                        self.on_fault_cmd(msg)
                        continue
                    for ev in lock.on_message(msg, rx):
                        if hasattr(ev, "latency_s"):
                            latency = ev.latency_s
                for ev in lock.poll(self.port.now_s()):
                    if isinstance(ev, CommandLost):
                        self.go_safe(t_n, f"no THR_CMD for {ev.consecutive} ticks")
                    elif isinstance(ev, DeadlineMissed) and ev.consecutive <= lost_after:
                        self.events.append(f"deadline missed: tick {ev.tick} "
                                           f"({ev.consecutive} in a row)")
            res = lock.result
            if res is not None and not res.safe:
                if self.safe:
                    self.safe = False
                    self.events.append(f"THR_CMD back at tick {n}: leaving safe state")
                self.apply(res.command, self.plant.apply_time(t_n))
            elif res is not None and not self.safe:
                self.apply(res.command, self.plant.apply_time(t_n))
            self.plant.advance_to(t_n + self.h)
            extra = {"rt_factor": round((t_n + self.h) / max(time.monotonic() - t_wall0, 1e-9), 2),
                     "sync_to_cmd_s": latency, "deadline_misses": lock.deadline_misses}
            self.record(n, extra)
        self.record_end(time.monotonic() - t_wall0, n_ticks, time.process_time() - cpu0)
        return 0

    # -- real time ------------------------------------------------------------------------

    def run_realtime(self, stop: _Stop) -> int:
        """Integrate on CLOCK_MONOTONIC; publish each gyro sample when it is due.

        The loop sleeps on the bus socket until the next thing that is due (a gyro sample, a
        record, a heartbeat), at most ``REALTIME_MAX_WAIT_S``, so a THR_CMD wakes it at once
        and is applied at its kernel receive time. It also wakes ``REALTIME_PRE_WAKE_S``
        before each sample and integrates up to there, so that when the sample is due only a
        few milliseconds remain to integrate before it goes out (this replaces a 2 ms
        polling loop that kept busy the one CPU the flight also needs under user-mode Linux).
        Every THR_CMD is traced back to the gyro sample it was computed from
        (``ThrCmd.gyro_seq``): ``chain`` in the per-tick record holds sample time, publish
        time, command receive time and apply time (plant clock, seconds since its start), and
        ``s2a_s`` the sensor-to-actuator latency (apply time minus sample time).
        """
        duration = self.sc.cfg.duration_s
        cpu0 = time.process_time()
        t0 = time.monotonic()
        hb = HeartbeatSender(NodeId.PLANT, 0.0)
        watch = FlightLinkWatch(self.h, self.safety.thr_cmd_lost_ticks,
                                self.safety.heartbeat_lost_s)
        period, gyro_latency = self.plant.gyro.period_s, self.plant.gyro.latency_s
        cmd_latency = self.sc.cfg.plant.command_latency_ms / 1e3
        next_record = self.h
        tick = 0
        s2a: list[float] = []
        chain: list[dict] = []
        while not stop():
            now = time.monotonic() - t0
            if now >= duration:
                break
            self.plant.advance_to(now)
            # Publish first: the flight is waiting for this sample.
            ready = self.plant.gyro_samples_until(now)
            if ready:
                self.port.send(*self.gyro_messages(ready, time.monotonic() - t0))
            for why in watch.poll(now):
                self.go_safe(self.plant.t, why)
            beat = hb.poll(now, NodeState.SAFE if self.safe else NodeState.RUN)
            if beat:
                self.port.send(beat)
            if self.plant.t >= next_record:
                self.record(tick, self._timing_extra(s2a, chain))
                s2a, chain = [], []
                tick += 1
                next_record += self.h
            k_next = math.floor(self.plant.t / period + 1e-9) + 1
            t_sample = k_next * period + gyro_latency
            t_now = time.monotonic() - t0
            # Wake once shortly before a sample to integrate up to it, so that at the sample
            # only a few milliseconds remain to integrate before it goes out.
            pre = t_sample - REALTIME_PRE_WAKE_S
            due = min(t_sample if t_now >= pre else pre, next_record, hb.next_s, duration)
            wait = min(max(due - t_now, 0.0), REALTIME_MAX_WAIT_S)
            for msg, rx in self.port.poll(wait):
                rx_sim = self.port.to_monotonic_s(rx) - t0
                self.events.extend(watch.on_message(msg, rx_sim))
                if isinstance(msg, FaultCmd):
                    self.on_fault_cmd(msg)
                elif isinstance(msg, ThrCmd):
                    t_apply = max(rx_sim, self.plant.t) + cmd_latency
                    if self.safe and watch.alive:
                        self.safe = False
                        self.events.append(f"THR_CMD back at {rx_sim:.2f} s: leaving safe state")
                    if not self.safe:
                        self.apply(msg, t_apply)
                    t_meas = self.gyro_time.get(msg.gyro_seq)
                    if t_meas is not None:
                        s2a.append(t_apply - t_meas)
                        chain.append({"tick": msg.tick, "gyro_seq": msg.gyro_seq,
                                      "sample_s": round(t_meas, 6),
                                      "published_s": _r6(self.gyro_pub.get(msg.gyro_seq)),
                                      "received_s": round(rx_sim, 6),
                                      "applied_s": round(t_apply, 6)})
        self.record_end(time.monotonic() - t0, tick, time.process_time() - cpu0)
        return 0

    @staticmethod
    def _timing_extra(s2a: list[float], chain: list[dict]) -> dict:
        extra: dict = {"s2a_s": s2a, "chain": chain}
        if s2a:
            # One scalar per record for the rerun time series: the worst of the tick.
            extra["series"] = {"timing/s2a_ms": {"s2a": max(s2a) * 1e3}}
        return extra

    def record_end(self, wall_s: float, ticks: int, cpu_s: float | None = None) -> None:
        cpu = "" if cpu_s is None else f", {cpu_s:.1f} s CPU"
        self.events.append(f"plant done: {ticks} ticks, {self.plant.t:.1f} s simulated in "
                           f"{wall_s:.1f} s wall{cpu}")
        _say("plant", self.events[-1])
        self.record(ticks, {"final": True, "wall_s": round(wall_s, 4),
                            "cpu_s": None if cpu_s is None else round(cpu_s, 4),
                            "last_gyro_seq": None if self.last_gyro is None
                            else self.last_gyro.sample_seq})
        self.rec.close()


# ============================================================================ flight


class FlightShell:
    """Flight process: ``flight.software.FlightSoftware`` behind a CAN port."""

    def __init__(self, sc: Scenario, port: Port, out: Path, args) -> None:
        from flight.software import FlightSoftware

        self.sc, self.port, self.args = sc, port, args
        self.v = sc.vehicle
        self.h = self.v.timing.tick_s
        self.fs = FlightSoftware(self.v, target=sc.cfg.target,
                                 initial_attitude=sc.cfg.initial.attitude)
        self.names = self.fs.arrays.names
        self.rec = JsonlWriter(out / "flight.jsonl")
        self.events: list[str] = []
        self.overruns = 0
        self.detections = 0
        self.safe = False
        self.gyro: Gyro | None = None
        self.gyro_fresh = False
        self.safety = safety_settings(sc, args)
        self.gyro_watch = GyroLossWatch(self.safety.gyro_lost_ticks)
        self.last_out = None
        self.late_gyro = 0
        self.first = _first_record(sc, args, {"gyro_lost_ticks": self.safety.gyro_lost_ticks})
        self.events.extend(self.first.pop("events"))
        if args.mode == "realtime":
            self._warm_up(sc)

    @staticmethod
    def _warm_up(sc: Scenario) -> None:
        """A few firing ticks of a throwaway flight software before the first real one.

        The first solve imports and sets up the LP solver (highspy): 200 ms once, measured
        under user-mode Linux, which made tick 0 of every real-time run an overrun. The
        instance that flies is untouched (lockstep runs skip this and stay bit for bit).
        """
        from flight.software import FlightSoftware

        fs = FlightSoftware(sc.vehicle, target=sc.cfg.target,
                            initial_attitude=sc.cfg.initial.attitude)
        for n in range(3):
            fs.step(n, np.array([0.02, -0.02, 0.01]))

    def tick(self, n: int, jitter_s: float | None = None, rt: dict | None = None) -> None:
        """One flight tick: stages in order, each timed; THR_CMD, FDIR_STATUS, telemetry out.

        Stage times come from one clock read per stage boundary (a clock read is a system
        call under user-mode Linux). ``rt``: real-time figures of this tick for the record.
        """
        fs, clk = self.fs, time.perf_counter_ns
        t_start = clk()
        change = self.gyro_watch.tick(self.gyro is not None and self.gyro_fresh)
        if change == "lost":
            self.safe = True
            fs.peer_lost()
            self.events.append(f"safe mode: no valid gyro for {self.gyro_watch.ticks_without} "
                               f"ticks: no firing")
            _say("flight", self.events[-1])
        elif change == "back":
            self.safe = False
            fs.peer_back()
            self.events.append("gyro back: leaving safe mode")
            _say("flight", self.events[-1])
        omega = np.zeros(3) if self.gyro is None else np.asarray(self.gyro.omega_B_rad_s)
        self.gyro_fresh = False
        stage_ns = {}
        t0 = clk()
        fs.begin(n, omega)
        t1 = clk()
        stage_ns["gyro_in"] = t1 - t0
        for name in fs.STAGES:
            getattr(fs, "stage_" + name)()
            t0, t1 = t1, clk()
            stage_ns[name] = t1 - t0
        out = fs.finish()
        t0 = t1
        quanta = tuple(int(x) // 10 for x in out.on_ms)
        if self.safe:
            quanta = (0,) * len(quanta)
        mask = sum(1 << m for m, o in enumerate(out.manifold_open) if o)
        seq = self.gyro.sample_seq if self.gyro else 0
        cmd = self._reply(n, quanta, mask, seq)
        if cmd is not None:
            self.port.send(cmd)
        det = out.detection
        detection = None
        if det is not None:
            self.detections += 1
            names = [self.names[i] for i in det.group]
            thr = names[0] if len(names) == 1 else names
            detection = {"t_s": round(n * self.h, 6), "tick": n, "thruster": thr,
                         "type": det.kind, "source": det.source, "rho": float(det.rho)}
            self.events.append(f"detection: {det.kind} of "
                               f"{thr if isinstance(thr, str) else 'one of ' + str(thr)} "
                               f"at {n * self.h:.1f} s ({det.source})")
            _say("flight", self.events[-1])
        t1 = clk()
        stage_ns["thr_cmd_out"] = t1 - t0
        t0 = t1
        ftype = {"stuck_on": DetectedFault.STUCK_ON, "fail_to_fire": DetectedFault.FAIL_TO_FIRE}
        closed = sum(1 << m for m, o in enumerate(out.manifold_open) if not o)
        if det is not None:
            self.last_det = det
        last = getattr(self, "last_det", None)
        g = last.group if last else ()
        fdir = FdirStatus(
            last.tick if last else 0, ftype.get(last.kind, DetectedFault.NONE) if last else 0,
            g[0] if g else None, g[1] if len(g) > 1 else None,
            closed, self.safe or out.safe_mode, 0)
        # FLIGHT_TIMING cannot carry the time of its own sending; the record's compute_s does.
        so_far_s = (clk() - t_start) / 1e9
        self.port.send(fdir, FlightTiming(n, min(so_far_s, 0.065), self.overruns % 256))
        t1 = clk()
        stage_ns["fdir_tm_out"] = t1 - t0
        compute_s = (t1 - t_start) / 1e9
        self.thr_cmd_on_ms = 10 * sum(quanta) if cmd is not None else 0
        self.record(n, out, detection, stage_ns, compute_s, jitter_s, rt)

    def _reply(self, n, quanta, mask, seq):
        lock = getattr(self, "lock", None)
        if lock is not None:
            return lock.reply(n, quanta, mask, seq)
        return ThrCmd(n, quanta, mask, seq)

    def record(self, n, out, detection, stage_ns, compute_s, jitter_s, rt=None) -> None:
        thr_off = out.threshold_off
        rec = {
            "tick": n, "t_s": round(n * self.h, 6),
            "series": {
                "flight/omega_meas_deg_s": _xyz(out.omega_meas, DEG),
                "flight/omega_est_deg_s": _xyz(out.omega_est, DEG),
                "flight/omega_pred_deg_s": _xyz(out.omega_pred, DEG),
                "flight/residual_deg_s": _xyz(out.residual, DEG),
                "flight/attitude_error_deg": _xyz(out.att_err_rad, DEG),
                "flight/rho_on": _named(self.names, out.rho_on),
                "flight/rho_off": _named(self.names, out.rho_off),
                "flight/thresholds": {"off": thr_off, "on": -out.threshold_on},
                "flight/on_ms": _named(self.names, out.on_ms),
                "flight/compute_ms": {k: v / 1e6 for k, v in stage_ns.items()},
            },
            "events": self.events,
            "detection": detection,
            "compute_s": compute_s,
            "stage_s": {k: v / 1e9 for k, v in stage_ns.items()},
            "jitter_s": jitter_s,
            "overruns": self.overruns,
            "safe": self.safe,
            # What THR_CMD carried (flight/on_ms is the allocator's wish; safe mode zeroes it).
            "thr_cmd_on_ms": getattr(self, "thr_cmd_on_ms", 0),
            "bus": self.port.counts(),
        }
        if rt is not None:
            # Real time only: lockstep records stay identical run to run (bit for bit).
            rec.update(rt)
            rec["series"]["timing/flight_ms"] = {
                "release_jitter": (jitter_s or 0.0) * 1e3, "gyro_wait": rt["gyro_wait_s"] * 1e3,
                "compute": compute_s * 1e3}
        if self.first:
            rec.update(self.first)
            self.first = {}
        self.rec.write(rec)
        self.events = []
        idle_gc(rec["tick"])

    def absorb(self, msgs) -> list:
        """Take messages from the bus; returns lockstep events (TickRequest...)."""
        evs = []
        for msg, rx in msgs:
            if isinstance(msg, Gyro):
                self.gyro, self.gyro_fresh = msg, True
            lock = getattr(self, "lock", None)
            if lock is not None:
                evs.extend(lock.on_message(msg, rx))
        return evs

    def run_lockstep(self, stop: _Stop) -> int:
        self.lock = FlightLockstep()
        while not stop():
            for ev in self.absorb(self.port.poll(0.05)):
                if isinstance(ev, TickRequest):
                    self.tick(ev.tick)
        self.rec.close()
        return 0

    def _sleep_until(self, target_ns: int) -> None:
        """Sleep to an absolute time reading the bus meanwhile (frames never wait to go stale),
        then finish with ``monotonic_sleep_until``'s fine sleep."""
        while True:
            remaining = target_ns - time.monotonic_ns()
            if remaining <= 2_000_000:
                break
            self.absorb(self.port.poll((remaining - 1_000_000) / 1e9))
        monotonic_sleep_until(target_ns)

    def _observe_gyro(self, stop: _Stop) -> list[tuple[int, int]] | None:
        """(seq, arrival ns on CLOCK_MONOTONIC) of the first ``--align-samples`` gyro samples
        (kernel receive stamps); None when stopped first."""
        seen: list[tuple[int, int]] = []
        while len(seen) < max(1, self.args.align_samples):
            if stop():
                return None
            for msg, rx in self.port.poll(0.1):
                if isinstance(msg, Gyro):
                    self.gyro, self.gyro_fresh = msg, True
                    seen.append((msg.sample_seq, int(self.port.to_monotonic_s(rx) * 1e9)))
        return seen

    def run_realtime(self, stop: _Stop) -> int:
        """Strict absolute tick grid aligned to the gyro; each tick waits for its sample.

        The plant publishes a sample every ``1 / gyro.rate_hz``; the flight watches when the
        first samples arrive and puts its release grid on the earliest arrival plus
        ``--release-offset-ms`` (``hil.scheduler.align_to_samples``; default -2 ms: the
        flight is already waiting when the sample comes, and it wakes after the plant's
        pre-wake work, not in the middle of it). At each release the tick waits on
        the socket for the sample that belongs to it (its sequence number follows from the
        grid), at most ``--gyro-wait-ms``, then computes and sends THR_CMD at once. So the
        command is computed from its own tick's sample however late (within the bound) the
        sample comes, and sensor-to-actuator latency is sample delay + compute + bus.
        Before, the tick was released 1 ms after the first sample's arrival and read
        whatever had come: a sample a little later than that was used one tick late (or
        went stale in the socket and was dropped), which put 200 ms and more into the p99.
        A sample later than the bound is counted (``late_gyro``, an event) and the tick uses
        the newest sample it has. Releases stay on the absolute grid and the scheduler
        counts overruns as before; release jitter is the wake-up minus the scheduled
        release, the wait for the sample is reported apart (``gyro_wait_s``). Between ticks
        the flight sleeps on the socket, so frames are read when they come.
        """
        a = self.args
        seen = self._observe_gyro(stop)
        if seen is None:
            self.rec.close()
            return 0
        tick_ns = int(round(self.h * 1e9))
        grid = align_to_samples(seen, int(round(1e9 / self.v.gyro.rate_hz)), tick_ns,
                                int(round(a.release_offset_ms * 1e6)))
        if not grid.per_tick:
            self.events.append(f"gyro at {self.v.gyro.rate_hz:g} Hz is not a whole number of "
                               f"samples per tick: ticks use the newest sample, no wait")
        wait_ns = int(round(a.gyro_wait_ms * 1e6))
        hb = HeartbeatSender(NodeId.FLIGHT, 0.0)
        cpu0 = time.process_time()

        def newest() -> int | None:
            return None if self.gyro is None else self.gyro.sample_seq

        def base(n: int, release_ns: int) -> None:
            start = time.monotonic_ns()
            self.absorb(self.port.poll(0.0))
            got = grid.per_tick == 0 or wait_for(
                lambda: grid.reached(newest(), n),
                lambda timeout_s: self.absorb(self.port.poll(timeout_s)),
                time.monotonic_ns, release_ns + wait_ns)
            waited = time.monotonic_ns() - start
            if not got:
                self.late_gyro += 1
                self.events.append(f"late gyro: tick {n} expected sample "
                                   f"{grid.expected_seq(n)}, newest {newest()} after "
                                   f"{a.gyro_wait_ms:g} ms")
            rt = {"gyro_wait_s": waited / 1e9, "gyro_late": not got,
                  "late_gyro": self.late_gyro, "gyro_seq_expected": grid.expected_seq(n),
                  "gyro_seq": newest()}
            self.tick(n, (start - release_ns) / 1e9, rt)

        def housekeeping(n: int, release_ns: int) -> None:
            beat = hb.poll(n * self.h, NodeState.SAFE if self.safe else NodeState.RUN)
            if beat:
                self.port.send(beat)

        def on_tick(r: TickRecord) -> None:
            if r.overrun:
                self.overruns += 1
                self.events.append(f"overrun: tick {r.tick} busy {r.busy_ns / 1e6:.2f} ms, "
                                   f"{r.skipped} release(s) skipped")

        per_hb = max(1, int(round(0.5 / self.h)))
        sched = TickScheduler(
            tick_ns,
            [RateGroup("base", 1, 0, base), RateGroup("housekeeping", per_hb, 0, housekeeping)],
            time.monotonic_ns, self._sleep_until, on_tick=on_tick)
        stats = sched.run(t0_ns=grid.t0_ns, stop=stop)
        self.rec.close()
        _say("flight", f"flight done: {stats.ticks} ticks, {stats.overruns} overruns, "
                       f"{self.late_gyro} late gyro samples, "
                       f"{time.process_time() - cpu0:.1f} s CPU")
        return 0


# ============================================================================ entry point


GC_EVERY_TICKS = 10  # 2 s at the 200 ms tick


def quiet_gc() -> None:
    """Garbage collection out of the tick: what start-up made is frozen (never scanned again)
    and automatic collection is off. A generation-2 collection started by an allocation took
    ~4.5 ms in the middle of a flight stage (bench/bench_flight_tick.py: whole-tick p99 5.2 ms
    with it, 1.1 ms without); the cycles a tick leaves are collected by :func:`idle_gc`."""
    gc.collect()
    gc.freeze()
    gc.disable()


def idle_gc(tick: int) -> None:
    """Collect every ``GC_EVERY_TICKS`` ticks, after the tick's record is written: THR_CMD
    and the tick's figures are out, the rest of the tick is idle."""
    if tick % GC_EVERY_TICKS == GC_EVERY_TICKS - 1:
        gc.collect()


_POLICIES = {getattr(os, k): k for k in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR", "SCHED_BATCH",
                                          "SCHED_IDLE") if hasattr(os, k)}


def sched_policy() -> str:
    """This process's scheduler policy as a name (and priority for the real-time ones)."""
    try:
        pol = os.sched_getscheduler(0)
        name = _POLICIES.get(pol, f"policy {pol}")
        if name in ("SCHED_FIFO", "SCHED_RR"):
            name += f" {os.sched_getparam(0).sched_priority}"
        return name
    except (OSError, AttributeError):
        return "unknown"


def _set_policy(node: str, choice: str) -> str:
    """The default (non real-time) policy of a node; says what it got.

    ``auto``: the plant runs SCHED_BATCH, the flight SCHED_OTHER. A SCHED_BATCH process does
    not preempt another when it wakes up, so on a machine with one CPU (user-mode Linux) the
    plant, woken by each THR_CMD frame or its own timer, no longer interrupts the flight
    software in the middle of a tick: it runs when the flight blocks. Measured under
    user-mode Linux (orel, real time): flight compute p50 9.8 -> 4.0 ms, of which sending
    THR_CMD 4.6 -> 0.7 ms. With several CPUs both run at once and nothing changes. Set
    explicitly, not inherited, so a caller's policy does not leak into the nodes.
    """
    want = {"auto": "batch" if node == "plant" else "other"}.get(choice, choice)
    pol = os.SCHED_BATCH if want == "batch" else os.SCHED_OTHER
    try:
        os.sched_setscheduler(0, pol, os.sched_param(0))
    except (PermissionError, OSError, AttributeError) as exc:
        return f"{sched_policy()} ({want} refused: {exc.__class__.__name__})"
    return sched_policy()


RT_PRIORITY = {"flight": 50, "plant": 40}  # the software under test above its emulator


def _try_realtime_priority(name: str) -> str:
    """SCHED_FIFO and locked memory when permitted; says what it got.

    The flight gets the higher priority: with equal priorities a FIFO process is never
    preempted by its peer, so on one CPU the flight's release waited for the plant's work
    (release jitter p50 1.9 ms under user-mode Linux, and 230 ms once while the plant
    wrote its last record).
    """
    notes = []
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY.get(name, 45)))
    except (PermissionError, OSError, AttributeError) as exc:
        notes.append(f"SCHED_FIFO refused ({exc.__class__.__name__}: "
                     f"{getattr(exc, 'strerror', None) or exc})")
    notes.insert(0, sched_policy())
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        if libc.mlockall(3) == 0:  # MCL_CURRENT | MCL_FUTURE
            notes.append("memory locked")
        else:
            notes.append(f"memory not locked (errno {ctypes.get_errno()})")
    except OSError:
        notes.append("memory not locked")
    return ", ".join(notes)


def realtime_event(note: str) -> str:
    """The event line of a ``--rt-priority`` request: says plainly what was refused."""
    fifo = note.startswith(("SCHED_FIFO", "SCHED_RR"))
    locked = "memory locked" in note
    if fifo and locked:
        return f"--rt: {note}"
    return f"--rt {'partly refused' if fifo or locked else 'refused'}: {note}"


def _ticks(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {n}")
    return n


def _heartbeat_s(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not x > HEARTBEAT_PERIOD_S:
        raise argparse.ArgumentTypeError(
            f"expected > the heartbeat period {HEARTBEAT_PERIOD_S:g} s, got {x:g}")
    return x


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m hil.nodes", description=__doc__.split("\n")[0])
    p.add_argument("node", choices=("plant", "flight"))
    p.add_argument("--scenario", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    p.add_argument("--interface", default="socketcan")
    p.add_argument("--channel", default="vcan0")
    p.add_argument("--reply-timeout", type=float, default=2.0,
                   help="lockstep: wall seconds the plant waits for THR_CMD(n) (generous: a "
                        "loaded machine must not change a lockstep run; once the flight is "
                        "declared lost the wait drops to 50 ms per tick)")
    p.add_argument("--lost-after", type=_ticks,
                   help="ticks without THR_CMD before the plant closes every valve "
                        "(default: the scenario's safety.thr_cmd_lost_ticks, 3)")
    p.add_argument("--heartbeat-lost-s", type=_heartbeat_s,
                   help="real time: seconds of flight heartbeat silence before the plant "
                        "closes every valve (default: safety.heartbeat_lost_s, 1.5)")
    p.add_argument("--gyro-lost-after", type=_ticks,
                   help="ticks without a valid gyro sample before the flight's safe mode "
                        "(default: safety.gyro_lost_ticks, 3)")
    p.add_argument("--gyro-wait-ms", type=float, default=50.0,
                   help="real time: longest wait after a release for the tick's gyro sample "
                        "(default 50 ms, a quarter of the tick)")
    p.add_argument("--release-offset-ms", type=float, default=-2.0,
                   help="real time: flight release relative to the earliest observed gyro "
                        "arrival (default -2 ms: already waiting when the sample comes, and "
                        "awake between the plant's pre-wake and its sample)")
    p.add_argument("--align-samples", type=int, default=3,
                   help="real time: gyro samples observed to place the flight's tick grid")
    p.add_argument("--rt-priority", action="store_true", help="try SCHED_FIFO and mlockall")
    p.add_argument("--sched", choices=("auto", "other", "batch"), default="auto",
                   help="scheduler policy without --rt-priority (auto: plant SCHED_BATCH, "
                        "flight SCHED_OTHER, see _set_policy)")
    p.add_argument("--bus-log", action="store_true", help="write NODE.bus.log (candump format)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stop = _Stop()
    try:
        sc = load_scenario(args.scenario)
        port = _open_port(args, out, args.node)
    except HilError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.rt_priority:
        args.sched_note = _try_realtime_priority(args.node)
        args.rt_event = realtime_event(args.sched_note)
        _say(args.node, args.rt_event)
    else:
        args.sched_note = _set_policy(args.node, args.sched)
    shell = (PlantShell if args.node == "plant" else FlightShell)(sc, port, out, args)
    quiet_gc()
    (out / f"{args.node}.ready").write_text(str(os.getpid()))
    try:
        run = shell.run_lockstep if args.mode == "lockstep" else shell.run_realtime
        return run(stop)
    finally:
        port.close()


if __name__ == "__main__":
    sys.exit(main())
