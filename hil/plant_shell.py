"""The plant process: ``plant.core.Plant`` behind a CAN port (``python -m hil.nodes plant``).

Lockstep (docs/design.md section 3): the plant is the time master: GYRO + SYNC(n), wait for
THR_CMD(n) (deadline ``--reply-timeout``; a miss applies the safe action), apply it at
``t_n`` + command latency, integrate to ``t_n+1``. Real time: the plant integrates on
CLOCK_MONOTONIC and publishes each gyro sample when it is due, applies each THR_CMD at its
kernel receive time and records the latency chain (gyro sample time, publish, THR_CMD receive,
apply) per command (``PlantShell.run_realtime``). Safe states: ``hil.safe_states``.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from pathlib import Path

from bus.catalog import (
    CATALOG,
    ON_QUANTUM_MS,
    AckReason,
    AckStatus,
    FaultAction,
    GyroStatus,
    NodeState,
)
from bus.catalog import Node as NodeId
from bus.codec import FaultAck, FaultCmd, Gyro, ThrCmd
from bus.protocol import CommandLost, DeadlineMissed, HeartbeatSender, PlantLockstep
from bus.transport import Port
from common.units import DEG
from hil.binding import FAULT_KIND_FROM_BUS, fault_spec, gyro_message, plant_command
from hil.config import Scenario
from hil.errors import FaultCommandError
from hil.node_settings import NodeSettings
from hil.node_shell import (
    BUS_FAULT_KINDS,
    Stop,
    attach_bus_faults,
    bus_fault_fields,
    first_record,
    named_values,
    round6,
    say,
    write_record,
    xyz_values,
)
from hil.recorder import JsonlWriter
from hil.records import PlantRecord, newly_active_faults, truth_fields
from hil.safe_states import CommandGate, FlightLinkWatch, safety_settings

REALTIME_MAX_WAIT_S = 0.02  # the real-time plant wakes at least this often (see run_realtime)
REALTIME_PRE_WAKE_S = 0.005  # ... and this long before each gyro sample
# A THR_CMD computed from a gyro sample older than this on arrival is stale (the catalog's
# deadline of the THR_CMD frames: half a tick).
THR_CMD_DEADLINE_S = CATALOG.frame("THR_CMD_0").deadline_s
DROPPED_EVENTS_PER_CLASS = 5  # events for the first dropped commands of each class; then counts
REPEAT_WINDOW_S = 10.0  # an identical FAULT_CMD this soon is the panel's resend (not applied)


class PlantShell:
    """Plant process: the ``plant.core.Plant`` behind a CAN port."""

    def __init__(self, sc: Scenario, port: Port, out: Path, settings: NodeSettings) -> None:
        from plant.core import Plant

        self.sc, self.port, self.settings = sc, port, settings
        self.v = sc.vehicle
        self.h = self.v.timing.tick_s
        self.plant = Plant(self.v, seed=sc.cfg.seed, overrides=sc.cfg.plant,
                           initial=sc.cfg.initial)
        self.names = self.plant.arrays.names
        self.n_thr, self.n_man = len(self.names), len(self.plant.arrays.manifolds)
        self.all_open = (1 << self.n_man) - 1
        for f in sc.cfg.faults:
            if f.kind in BUS_FAULT_KINDS:
                continue  # bus faults act in the shells' send paths (bus.faults), not in physics
            self.plant.inject(f)
        self.bus_faults = attach_bus_faults(port, sc, "plant")
        self.bus_new: list[dict] = []  # bus faults that became active since the last record
        # Whether the flight's last command was applied as sent; the next GYRO says so
        # (GyroStatus.CMD_NOT_APPLIED) and the flight keeps that tick out of its evidence.
        self.cmd_applied = True
        # A flagged sample is followed by one more: at the flagged tick the flight restarts its
        # onboard model from the measurement, believing the unapplied command burnt (its carry
        # into the next interval too), so the next tick's prediction is no evidence either.
        self.flag_next = False
        # Real time, time-triggered: a command that came after its actuation time is applied on
        # arrival, and the GYRO samples until this time say CMD_NOT_APPLIED.
        self.late_until_s = -math.inf
        self.late_actuations = 0
        self.last_applied: ThrCmd | None = None
        self.applied_as_sent: list[list[int]] = []  # [tick, on ms] since the last record
        self.held_ticks = 0  # ticks in a row the last command was repeated (thr_cmd_missing hold)
        self.rec = JsonlWriter(out / "plant.jsonl")
        self.events: list[str] = []
        self.reported_faults: set[int] = set()
        self.gyro_time: dict[int, float] = {}   # seq -> sample time (sim s) for latency tracing
        self.gate: CommandGate | None = None  # real time: the freshness of THR_CMD
        self.gyro_pub: dict[int, float] = {}    # seq -> when it was sent (real time only)
        self.last_gyro: Gyro | None = None
        self.safe = False
        self.target = sc.cfg.target.quaternion()
        self.programme = sc.cfg.programme_ticks(sc.vehicle.timing.tick_s)
        self.last_cmd_tick_s = 0.0
        self.safety = safety_settings(sc, settings)
        self.cleared: list[dict] = []  # faults the panel ended since the last record
        self.last_fault: tuple[FaultCmd, float, FaultAck] | None = None  # for repeats
        self.first = first_record(sc, settings, {
            "thr_cmd_lost_ticks": self.safety.thr_cmd_lost_ticks,
            "heartbeat_lost_s": self.safety.heartbeat_lost_s,
            "thr_cmd_missing": self.safety.thr_cmd_missing})
        self.events.extend(self.first.pop("events"))

    # -- faults from the panel ------------------------------------------------------------

    def on_fault_cmd(self, m: FaultCmd) -> None:
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
            if FAULT_KIND_FROM_BUS.get(m.kind) in BUS_FAULT_KINDS:
                status, reason = self.on_bus_fault_cmd(m)
            elif m.action == FaultAction.CLEAR:
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
                if m.kind not in FAULT_KIND_FROM_BUS:
                    raise FaultCommandError("fault: kind: expected a known kind, got none")
                if m.thruster is not None and m.thruster >= self.n_thr:
                    status, reason = AckStatus.REJECTED, AckReason.BAD_THRUSTER
                else:
                    spec = fault_spec(m, self.names, self.plant.t)
                    self.plant.inject(spec)
                    self.events.append(f"fault injected by panel: {spec.kind} "
                                       f"{spec.thruster or ''} at {spec.t_s:.2f} s")
        except (FaultCommandError, ValueError) as exc:
            status, reason = AckStatus.REJECTED, AckReason.BAD_FRACTION
            self.events.append(f"fault command rejected: {exc}")
        ack = FaultAck(m.request_id, status, reason, m.kind)
        self.last_fault = (m, now, ack)
        self.port.send(ack)

    def on_bus_fault_cmd(self, m: FaultCmd) -> tuple[AckStatus, AckReason]:
        """A bus fault from the panel: ``thruster`` carries the node id. The plant's own go
        on its send path; the flight's are the flight's to apply (it hears FAULT_CMD too,
        ``hil.flight_shell``), the plant acknowledges that the command was valid."""
        kind = FAULT_KIND_FROM_BUS[m.kind]
        node = {NodeId.PLANT: "plant", NodeId.FLIGHT: "flight"}.get(m.thruster)
        if node is None:
            return AckStatus.REJECTED, AckReason.BAD_THRUSTER
        if node == "plant":
            if m.action == FaultAction.CLEAR:
                if not self.bus_faults.clear(kind, self.plant.t):
                    return AckStatus.REJECTED, AckReason.NOT_ACTIVE
            else:
                spec = fault_spec(m, self.names, self.plant.t, node="plant")
                self.bus_faults.add(spec)
        self.events.append(f"bus fault {'cleared' if m.action == FaultAction.CLEAR else 'injected'}"
                           f" by panel: {kind} on {node} (request {m.request_id})")
        return AckStatus.ACCEPTED, AckReason.NONE

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
            g = gyro_message(s)
            if not self.cmd_applied or self.flag_next:
                g = replace(g, status=g.status | GyroStatus.CMD_NOT_APPLIED)
            self.flag_next = not self.cmd_applied
            self.last_gyro = g
            out.append(g)
        if len(self.gyro_time) > 4096:
            for k in list(self.gyro_time)[:2048]:
                del self.gyro_time[k]
                self.gyro_pub.pop(k, None)
        return out

    def apply(self, cmd: ThrCmd, t_apply_s: float, as_sent: bool = True) -> None:
        """Apply ``cmd`` from ``t_apply_s``; ``as_sent``: the command as received (False: a
        held one under a new tick number)."""
        on_ms, mask = plant_command(cmd, self.n_man)
        if on_ms.shape[0] != self.n_thr:
            self.events.append(f"THR_CMD rejected: {on_ms.shape[0]} thrusters, "
                               f"expected {self.n_thr}")
            return
        self.plant.apply_command(cmd.tick, t_apply_s, on_ms, mask)
        self.last_cmd_tick_s = t_apply_s
        self.last_applied = cmd
        if as_sent:
            self.applied_as_sent.append([int(cmd.tick), ON_QUANTUM_MS * int(sum(cmd.on_quanta))])

    def dropped_command(self, cmd: ThrCmd, verdict: str, rx_s: float,
                        t_sample_s: float | None) -> None:
        """A THR_CMD the gate refused: counted by class (``command_gate`` in the records) and
        an event for the first few of each class, so a flood of them cannot flood the log."""
        n = self.gate.counts[verdict]
        if n <= DROPPED_EVENTS_PER_CLASS:
            age = "" if t_sample_s is None else f", {1e3 * (rx_s - t_sample_s):.0f} ms after " \
                                                   "its gyro sample"
            more = " (further ones counted only)" if n == DROPPED_EVENTS_PER_CLASS else ""
            self.events.append(f"THR_CMD of tick {cmd.tick} dropped: {verdict}{age}{more}")

    def go_safe(self, t_s: float, why: str) -> None:
        if not self.safe:
            self.safe = True
            self.plant.close_all_valves(t_s, manifolds=True)
            self.events.append(f"safe: all valves and manifolds closed at {t_s:.2f} s ({why})")
            say("plant", self.events[-1])

    # -- recording ----------------------------------------------------------------------------

    def record(self, tick: int, extra: dict | None = None) -> None:
        from common.scenario import target_at
        from flight.attitude import error_quaternion, small_angle_vector

        tr = self.plant.truth
        # the attitude error to the target the flight flew this tick (programmed turns)
        n_err = error_quaternion(target_at(self.target, self.programme, tick), tr.q_BO)
        att = small_angle_vector(n_err) * DEG
        injected = newly_active_faults(self.plant.faults.entries, self.reported_faults, tr.t_s)
        injected = injected + self.bus_new
        self.bus_new = []
        for f in injected:
            self.events.append(f"fault active: {f['type']} {f['thruster'] or ''} "
                               f"at {f['t_s']:.2f} s")
        rec: PlantRecord = {
            "tick": tick, "t_s": round(tr.t_s, 9),
            "series": {
                "truth/omega_deg_s": xyz_values(tr.omega_BO_B_rad_s, DEG),
                "truth/omega_BI_deg_s": xyz_values(tr.omega_B_rad_s, DEG),  # as flight/omega_meas
                "truth/attitude_error_deg": xyz_values(att),
                "truth/thrust_n": named_values(self.names, tr.thrust_n),
                "truth/flex_gyro_deg_s": xyz_values(tr.flex_rate_gyro_B_rad_s, DEG),
            },
            "events": self.events,
            "faults_injected": injected,
            **truth_fields(tr, n_err),
            "safe": self.safe,
            "bus": self.port.counts(),
        }
        if self.cleared:
            rec["faults_cleared"], self.cleared = self.cleared, []
        if extra:
            extra = dict(extra)
            rec["series"].update(extra.pop("series", {}))
            rec.update(extra)
        if self.gate is not None:
            rec["command_gate"] = dict(self.gate.counts)
            rec["late_actuations"] = self.late_actuations
        if self.applied_as_sent:
            rec["thr_cmd_applied"], self.applied_as_sent = self.applied_as_sent, []
        write_record(self, rec)

    # -- lockstep -------------------------------------------------------------------------

    def run_lockstep(self, stop: Stop) -> int:
        a = self.settings
        n_ticks = int(round(self.sc.cfg.duration_s / self.h))
        lost_after = self.safety.thr_cmd_lost_ticks
        lock = PlantLockstep(self.n_thr, reply_timeout_s=a.reply_timeout,
                             lost_after_misses=lost_after, tick_s=self.h,
                             manifold_enable_safe=self.all_open)
        phase = a.actuation_phase_s()  # 0 unless --actuation-phase-ms
        cpu0 = time.process_time()
        t_wall0 = time.monotonic()
        good_in_a_row = 0
        for n in range(n_ticks):
            if stop():
                break
            t_n = n * self.h
            self.plant.advance_to(t_n)
            self.bus_new += bus_fault_fields(self, t_n)
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
            good_in_a_row = good_in_a_row + 1 if res is not None and not res.safe else 0
            self.cmd_applied = False
            if res is not None and not res.safe:
                if self.safe and good_in_a_row >= self.safety.recover_ticks:
                    self.safe = False
                    self.events.append(f"THR_CMD back at tick {n}: leaving safe state "
                                       f"({good_in_a_row} ticks in a row)")
                if not self.safe:
                    self.apply(res.command, self.plant.apply_time(t_n) + phase)
                    self.cmd_applied = True
                    self.held_ticks = 0
            elif res is not None and not self.safe:
                self.apply(self.missing_command(n, res.command),
                           self.plant.apply_time(t_n) + phase,
                           as_sent=False)
            self.plant.advance_to(t_n + self.h)
            extra = {"rt_factor": round((t_n + self.h) / max(time.monotonic() - t_wall0, 1e-9), 2),
                     "sync_to_cmd_s": latency, "deadline_misses": lock.deadline_misses}
            self.record(n, extra)
        self.record_end(time.monotonic() - t_wall0, n_ticks, time.process_time() - cpu0, t_wall0)
        return 0

    def missing_command(self, tick: int, safe_cmd: ThrCmd) -> ThrCmd:
        """What the plant applies for a tick whose THR_CMD is missing (``safety.
        thr_cmd_missing``): ``zero``: ``safe_cmd`` (nothing fires); ``hold``: the last command
        applied again, under the tick's number (until ``thr_cmd_lost_ticks`` make it safe)."""
        last = self.last_applied
        if self.safety.thr_cmd_missing != "hold" or last is None:
            return safe_cmd
        self.held_ticks += 1
        self.events.append(f"THR_CMD of tick {tick} missing: holding the command of tick "
                           f"{last.tick} ({self.held_ticks} in a row)")
        return replace(last, tick=tick)

    # -- real time ------------------------------------------------------------------------

    def run_realtime(self, stop: Stop) -> int:
        """Integrate on CLOCK_MONOTONIC; publish each gyro sample when it is due.

        The loop sleeps on the bus socket until the next thing that is due (a gyro sample, a
        record, a heartbeat), at most ``REALTIME_MAX_WAIT_S``, so a THR_CMD wakes it at once.
        Actuation is time-triggered: THR_CMD(n) takes effect the actuation phase
        (``NodeSettings.actuation_phase_s``) after its sample went out, as the flight's onboard
        model assumes, whatever the flight's compute and the bus took; one received later is
        applied at its kernel receive time, counted (``late_actuations``) and the next two GYRO
        samples say CMD_NOT_APPLIED (its burn and the tail it spills past the next sample are
        not where the flight's model put them), so those ticks are not FDIR evidence: taken as
        evidence, a few late ticks taught the effectiveness learning "every thruster 4 %
        strong and 4 % leaking", which the model's prediction (strong, leaks not fed back)
        then kept wrong for the rest of the run (``kalman_cube``, S002-15). Phase 0: every
        command is applied at its receive time. It also wakes ``REALTIME_PRE_WAKE_S``
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
        gate = self.gate = CommandGate(THR_CMD_DEADLINE_S, self.safety.recover_ticks)
        period, gyro_latency = self.plant.gyro.period_s, self.plant.gyro.latency_s
        cmd_latency = self.sc.cfg.plant.command_latency_ms / 1e3
        phase = self.settings.actuation_phase_s()
        next_record = self.h
        tick = 0
        s2a: list[float] = []
        chain: list[dict] = []
        while not stop():
            now = time.monotonic() - t0
            if now >= duration:
                break
            self.plant.advance_to(now)
            self.bus_new += bus_fault_fields(self, now)
            # A command applied within the last tick (and its deadline) is the one in force.
            self.cmd_applied = not self.safe and now >= self.late_until_s and \
                now - self.last_cmd_tick_s <= self.h + THR_CMD_DEADLINE_S
            if not self.cmd_applied and not self.safe and self.last_applied is not None and \
                    self.safety.thr_cmd_missing == "hold" and \
                    self.held_ticks < self.safety.thr_cmd_lost_ticks - 1 and \
                    now - self.last_cmd_tick_s >= self.h + THR_CMD_DEADLINE_S:
                held = self.missing_command(self.last_applied.tick + 1, self.last_applied)
                self.apply(held, now + cmd_latency, as_sent=False)
                # The flight's model has no such burn: the next sample is no evidence (and the
                # one after it, see flag_next).
                self.late_until_s = now + cmd_latency + self.h
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
                if isinstance(msg, ThrCmd):
                    t_meas = self.gyro_time.get(msg.gyro_seq)
                    verdict = gate.judge(msg.tick, t_meas, rx_sim)
                    if verdict != "fresh":  # counted, never applied, not a sign of life
                        self.dropped_command(msg, verdict, rx_sim, t_meas)
                        continue
                self.events.extend(watch.on_message(msg, rx_sim))
                if isinstance(msg, FaultCmd):
                    self.on_fault_cmd(msg)
                elif isinstance(msg, ThrCmd):
                    # Time-triggered: in force from the tick's sample out + phase; one that
                    # comes later is applied on arrival and its tick is no evidence.
                    t_due = None if t_meas is None or phase <= 0.0 else \
                        t_meas + gyro_latency + phase
                    t_in = max(rx_sim, self.plant.t)
                    late = t_due is not None and t_in > t_due
                    t_apply = (t_in if t_due is None or late else t_due) + cmd_latency
                    if self.safe and watch.alive and gate.may_leave_safe():
                        self.safe = False
                        self.events.append(f"THR_CMD back at {rx_sim:.2f} s: leaving safe state "
                                           f"({gate.run_length} fresh ticks in a row)")
                    if not self.safe:
                        self.apply(msg, t_apply)
                        self.held_ticks = 0
                        if late:
                            # Its burn is not where the flight's model put it: the next
                            # sample says so (and the one after it, see flag_next).
                            self.late_until_s = t_apply + self.h
                            self.late_actuations += 1
                    if t_meas is not None:
                        s2a.append(t_apply - t_meas)
                        link = {"tick": msg.tick, "gyro_seq": msg.gyro_seq,
                                "sample_s": round(t_meas, 6),
                                "published_s": round6(self.gyro_pub.get(msg.gyro_seq)),
                                "received_s": round(rx_sim, 6),
                                "applied_s": round(t_apply, 6)}
                        if late:
                            link["late"] = True
                        chain.append(link)
        self.record_end(time.monotonic() - t0, tick, time.process_time() - cpu0, t0)
        return 0

    @staticmethod
    def _timing_extra(s2a: list[float], chain: list[dict]) -> dict:
        extra: dict = {"s2a_s": s2a, "chain": chain}
        if s2a:
            # One scalar per record for the rerun time series: the worst of the tick.
            extra["series"] = {"timing/s2a_ms": {"s2a": max(s2a) * 1e3}}
        return extra

    def record_end(self, wall_s: float, ticks: int, cpu_s: float | None = None,
                   t0_monotonic_s: float | None = None) -> None:
        """The final record: the loop's wall and CPU time, and when the loop started
        (``loop_t0_monotonic_s``, CLOCK_MONOTONIC: the supervisor's start-up figure)."""
        cpu = "" if cpu_s is None else f", {cpu_s:.1f} s CPU"
        self.events.append(f"plant done: {ticks} ticks, {self.plant.t:.1f} s simulated in "
                           f"{wall_s:.1f} s wall{cpu}")
        say("plant", self.events[-1])
        self.record(ticks, {"final": True, "wall_s": round(wall_s, 4),
                            "cpu_s": None if cpu_s is None else round(cpu_s, 4),
                            "loop_t0_monotonic_s": t0_monotonic_s,
                            "last_gyro_seq": None if self.last_gyro is None
                            else self.last_gyro.sample_seq})
        self.rec.close()


# ============================================================================ flight
