"""The flight process: ``flight.software.FlightSoftware`` behind a CAN port
(``python -m hil.nodes flight``).

Lockstep: the flight ticks on each SYNC (``bus.protocol.FlightLockstep``). Real time: the strict
tick scheduler (``hil.scheduler``) on CLOCK_MONOTONIC, its grid placed on the observed gyro
arrivals; each tick waits (bounded) for its own sample before it computes
(``FlightShell.run_realtime``). Safe mode on gyro loss: ``hil.safe_states.GyroLossWatch``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from bus.catalog import ON_QUANTUM_MS, FaultAction, GyroStatus, NodeState
from bus.catalog import Node as NodeId
from bus.codec import FaultCmd, FlightTiming, Gyro, ThrCmd
from bus.protocol import FlightLockstep, HeartbeatSender, TickRequest
from bus.transport import Port
from common.units import DEG
from hil.binding import (
    FAULT_KIND_FROM_BUS,
    command_quanta,
    fault_spec,
    fdir_status,
    manifold_mask,
    saturated,
)
from hil.config import Scenario
from hil.node_settings import NodeSettings
from hil.node_shell import (
    BUS_FAULT_KINDS,
    Stop,
    attach_bus_faults,
    bus_fault_fields,
    first_record,
    named_values,
    say,
    write_record,
    xyz_values,
)
from hil.recorder import JsonlWriter
from hil.records import (
    FlightRecord,
    detection_record,
    fdir_action_text,
    fdir_actions,
    fdir_view,
)
from hil.safe_states import GyroLossWatch, safety_settings
from hil.scheduler import (
    RateGroup,
    TickRecord,
    TickScheduler,
    align_to_samples,
    monotonic_sleep_until,
    wait_for,
)


def with_actuation_phase(vehicle, phase_s: float):
    """The vehicle whose onboard model expects each command ``phase_s`` later than its
    nominal command latency (the plant applies it then: ``NodeSettings.actuation_phase_s``)."""
    if phase_s <= 0.0:
        return vehicle
    om = vehicle.flight.onboard_model
    om = om.model_copy(update={"command_latency_ms": om.command_latency_ms + 1000.0 * phase_s})
    flight = vehicle.flight.model_copy(update={"onboard_model": om})
    return vehicle.model_copy(update={"flight": flight})


def flight_software(sc: Scenario, phase_s: float):
    """The scenario's ``FlightSoftware`` for commands that take effect ``phase_s`` after their
    tick's sample: the onboard model expects them then (``with_actuation_phase``) and the
    controller acts on the state at actuation (``lead_s``, the phase ahead of the sample). The
    flight process and ``hil.sim.simulate`` both build the flight here."""
    from flight.software import FlightSoftware

    return FlightSoftware(with_actuation_phase(sc.vehicle, phase_s), target=sc.cfg.target,
                          initial_attitude=sc.cfg.initial.attitude, lead_s=phase_s,
                          programme=sc.cfg.programme_ticks(sc.vehicle.timing.tick_s))


class FlightShell:
    """Flight process: ``flight.software.FlightSoftware`` behind a CAN port."""

    def __init__(self, sc: Scenario, port: Port, out: Path, settings: NodeSettings) -> None:
        self.sc, self.port, self.settings = sc, port, settings
        self.fs = flight_software(sc, settings.actuation_phase_s())
        self.v = self.fs.vehicle
        self.h = self.v.timing.tick_s
        self.names = self.fs.arrays.names
        self.rec = JsonlWriter(out / "flight.jsonl")
        self.events: list[str] = []
        self.overruns = 0
        self.detections = 0
        self.safe = False
        self.gyro: Gyro | None = None
        self.gyro_fresh = False
        self.safety = safety_settings(sc, settings)
        self.gyro_watch = GyroLossWatch(self.safety.gyro_lost_ticks)
        self.last_out = None
        self.late_gyro = 0
        self.lock: FlightLockstep | None = None  # lockstep only (run_lockstep)
        self.last_det = None  # the newest detection, repeated in every FDIR_STATUS
        self.fdir_before = self.fdir_view = None  # hil.records.fdir_view, last tick's and now
        self.fdir_actions: list = []
        self.thr_cmd_on_ms = 0  # what the tick's THR_CMD carried, for the record
        self.bus_faults = attach_bus_faults(port, sc, "flight")
        self.bus_new: list[dict] = []  # bus faults newly active, for the next record
        self.last_bus_fault_cmd: FaultCmd | None = None
        self.no_evidence = 0  # ticks kept out of the detector's evidence (docs/hostile-bus.md)
        self.no_evidence_after_skip = 0  # real time: ticks still to keep out after a skip
        self.gyro_saturated_prev = False  # the last tick's sample was clipped (GYRO range)
        self.gyro_saturated_ticks = 0
        # Real time: the plant's time of tick 0's sample (the flight's grid starts on the
        # samples it observed first, so its tick n is not the plant's tick n); lockstep: 0.
        self.t0_plant_s = 0.0
        self.first = first_record(sc, settings, {"gyro_lost_ticks": self.safety.gyro_lost_ticks})
        self.events.extend(self.first.pop("events"))
        if settings.mode == "realtime":
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
        self.bus_new += bus_fault_fields(self, self.t_of(n))
        fresh = self.gyro is not None and self.gyro_fresh
        change = self.gyro_watch.tick(fresh)
        if change == "lost":
            self.safe = True
            fs.peer_lost()
            self.events.append(f"safe mode: no valid gyro for {self.gyro_watch.ticks_without} "
                               f"ticks: no firing")
            say("flight", self.events[-1])
        elif change == "back":
            self.safe = False
            fs.peer_back()
            self.events.append("gyro back: leaving safe mode")
            say("flight", self.events[-1])
        omega = np.zeros(3) if self.gyro is None else np.asarray(self.gyro.omega_B_rad_s)
        self.gyro_fresh = False
        # The plant says in the sample whether it applied our last command; a tick without a
        # fresh sample propagates; neither kind of tick is evidence about the thrusters.
        applied = self.gyro is None or not self.gyro.status & GyroStatus.CMD_NOT_APPLIED
        if self.no_evidence_after_skip > 0:
            # A release was skipped (an overrun): the residual now spans more than the tick
            # the model predicted, and the plant held our last command in between.
            self.no_evidence_after_skip -= 1
            applied = False
        # A sample clipped to the GYRO range, or the first after one: the rate change is not
        # the craft's (hil.binding.saturated; the in-process lockstep does the same).
        sat = saturated(self.gyro)
        if sat != self.gyro_saturated_prev:
            self.events.append("gyro saturated (GYRO range): no thruster evidence" if sat
                               else "gyro back inside its range")
            say("flight", self.events[-1])
        if sat:
            self.gyro_saturated_ticks += 1
        if sat or self.gyro_saturated_prev:
            applied = False
        self.gyro_saturated_prev = sat
        if not (fresh and applied):
            self.no_evidence += 1
        stage_ns = {}
        t0 = clk()
        fs.begin(n, omega, fresh=fresh, evidence=applied)
        t1 = clk()
        stage_ns["gyro_in"] = t1 - t0
        for name in fs.STAGES:
            getattr(fs, "stage_" + name)()
            t0, t1 = t1, clk()
            stage_ns[name] = t1 - t0
        out = fs.finish()
        t0 = t1
        quanta = command_quanta(out.on_ms, self.safe)
        mask = manifold_mask(out.manifold_open)
        seq = self.gyro.sample_seq if self.gyro else 0
        cmd = self._reply(n, quanta, mask, seq)
        if cmd is not None:
            self.port.send(cmd)
        det = out.detection
        detection = None
        if det is not None:
            self.detections += 1
            detection = detection_record(det, n, self.h, self.names, t_s=self.t_of(n))
            thr = detection["thruster"]
            self.events.append(f"detection: {det.kind} of "
                               f"{thr if isinstance(thr, str) else 'one of ' + str(thr)} "
                               f"at {self.t_of(n):.1f} s ({det.source})")
            say("flight", self.events[-1])
        t1 = clk()
        stage_ns["thr_cmd_out"] = t1 - t0
        t0 = t1
        if det is not None:
            self.last_det = det
        view = fdir_view(out, self.names, self.v.manifolds,
                         [t.manifold for t in self.v.thrusters])
        self.fdir_actions = fdir_actions(self.fdir_before, view, round(self.t_of(n), 6))
        self.fdir_before = self.fdir_view = view
        for a in self.fdir_actions:
            self.events.append(fdir_action_text(a))
            say("flight", self.events[-1])
        fdir = fdir_status(self.last_det, out, self.safe)
        # FLIGHT_TIMING cannot carry the time of its own sending; the record's compute_s does.
        so_far_s = (clk() - t_start) / 1e9
        self.port.send(fdir, FlightTiming(n, min(so_far_s, 0.065), self.overruns % 256))
        t1 = clk()
        stage_ns["fdir_tm_out"] = t1 - t0
        compute_s = (t1 - t_start) / 1e9
        self.thr_cmd_on_ms = ON_QUANTUM_MS * sum(quanta) if cmd is not None else 0
        self.record(n, out, detection, stage_ns, compute_s, jitter_s, rt)

    def _reply(self, n, quanta, mask, seq):
        if self.lock is not None:
            return self.lock.reply(n, quanta, mask, seq)
        return ThrCmd(n, quanta, mask, seq)  # real time: no lockstep state to keep

    def t_of(self, n: int) -> float:
        """Tick ``n``'s time on the plant's clock (when its sample was measured), the time base of
        faults, detections and the plant's records. Before, a real-time flight wrote ``n h``,
        its own count from the samples it aligned on, some 0.4-0.6 s behind the plant, so a
        detection 0.4 s after a fault was judged a false alarm before it."""
        return self.t0_plant_s + n * self.h

    def record(self, n, out, detection, stage_ns, compute_s, jitter_s, rt=None) -> None:
        thr_off = out.threshold_off
        rec: FlightRecord = {
            "tick": n, "t_s": round(self.t_of(n), 6),
            "series": {
                "flight/omega_meas_deg_s": xyz_values(out.omega_meas, DEG),
                "flight/omega_est_deg_s": xyz_values(out.omega_est, DEG),
                "flight/omega_pred_deg_s": xyz_values(out.omega_pred, DEG),
                "flight/residual_deg_s": xyz_values(out.residual, DEG),
                "flight/attitude_error_deg": xyz_values(out.att_err_rad, DEG),
                "flight/rho_on": named_values(self.names, out.rho_on),
                "flight/rho_off": named_values(self.names, out.rho_off),
                "flight/thresholds": {"off": thr_off, "on": -out.threshold_on},
                "flight/on_ms": named_values(self.names, out.on_ms),
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
            "thr_cmd_on_ms": self.thr_cmd_on_ms,
            "bus": self.port.counts(),
            "fdir": self.fdir_view,
            "no_evidence_ticks": self.no_evidence,
            "gyro_saturated_ticks": self.gyro_saturated_ticks,
        }
        if self.fs.detector.cfg.pulse_test_below is not None:
            rec["pulse_tests"] = dict(self.fs.pulse_tests)
        if self.fdir_actions:
            rec["fdir_actions"] = self.fdir_actions
        if self.bus_new:
            rec["faults_injected"], self.bus_new = self.bus_new, []
        if rt is not None:
            # Real time only: lockstep records stay identical run to run (bit for bit).
            rec.update(rt)
            rec["series"]["timing/flight_ms"] = {
                "release_jitter": (jitter_s or 0.0) * 1e3, "gyro_wait": rt["gyro_wait_s"] * 1e3,
                "compute": compute_s * 1e3}
        write_record(self, rec)

    def absorb(self, msgs) -> list:
        """Take messages from the bus; returns lockstep events (TickRequest...)."""
        evs = []
        for msg, rx in msgs:
            if isinstance(msg, Gyro):
                self.gyro, self.gyro_fresh = msg, True
            elif isinstance(msg, FaultCmd):
                self.on_fault_cmd(msg)
            if self.lock is not None:
                evs.extend(self.lock.on_message(msg, rx))
        return evs

    def on_fault_cmd(self, m: FaultCmd) -> None:
        """A panel FAULT_CMD: the flight applies the bus faults addressed to its own node
        (``thruster`` = node id; the plant acknowledges, ``PlantShell.on_bus_fault_cmd``) and
        ignores the rest. A resend of the same request is not applied twice."""
        kind = FAULT_KIND_FROM_BUS.get(m.kind)
        if kind not in BUS_FAULT_KINDS or m.thruster != NodeId.FLIGHT or \
                m == self.last_bus_fault_cmd:
            return
        self.last_bus_fault_cmd = m
        t_s = self.bus_faults.t_s
        if m.action == FaultAction.CLEAR:
            self.bus_faults.clear(kind, t_s)
            return
        try:
            self.bus_faults.add(fault_spec(m, self.names, t_s, node="flight"))
        except ValueError as exc:
            self.events.append(f"bus fault command refused: {exc}")
        self.events.append(f"bus fault injected by panel: {kind} on flight "
                           f"(request {m.request_id})")

    def run_lockstep(self, stop: Stop) -> int:
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

    def _observe_gyro(self, stop: Stop) -> list[tuple[int, int]] | None:
        """(seq, arrival ns on CLOCK_MONOTONIC) of the first ``--align-samples`` gyro samples
        (kernel receive stamps); None when stopped first."""
        seen: list[tuple[int, int]] = []
        while len(seen) < max(1, self.settings.align_samples):
            if stop():
                return None
            for msg, rx in self.port.poll(0.1):
                if isinstance(msg, Gyro):
                    self.gyro, self.gyro_fresh = msg, True
                    seen.append((msg.sample_seq, int(self.port.to_monotonic_s(rx) * 1e9)))
        return seen

    def run_realtime(self, stop: Stop) -> int:
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
        a = self.settings
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
        else:  # sample k is measured at k / rate on the plant's clock (lockstep: tick n's
            self.t0_plant_s = grid.seq_first / self.v.gyro.rate_hz  # is measured at n h)
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
                self.gyro_fresh = False  # the tick's own sample is late: propagate
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
                if r.skipped:
                    self.no_evidence_after_skip = 2
                self.events.append(f"overrun: tick {r.tick} busy {r.busy_ns / 1e6:.2f} ms, "
                                   f"{r.skipped} release(s) skipped")

        per_hb = max(1, int(round(0.5 / self.h)))
        sched = TickScheduler(
            tick_ns,
            [RateGroup("base", 1, 0, base), RateGroup("housekeeping", per_hb, 0, housekeeping)],
            time.monotonic_ns, self._sleep_until, on_tick=on_tick)
        stats = sched.run(t0_ns=grid.t0_ns, stop=stop)
        self.rec.close()
        say("flight", f"flight done: {stats.ticks} ticks, {stats.overruns} overruns, "
                       f"{self.late_gyro} late gyro samples, "
                       f"{time.process_time() - cpu0:.1f} s CPU")
        return 0
