"""Safe states (docs/design.md section 4, issue 5 item 4), without sockets or with python-can's
in-process ``virtual`` bus.

Flight: safe mode (no firing, FDIR_STATUS safe flag, an event) after ``gyro_lost_ticks`` ticks
with no accepted gyro sample, whether none came or every one was rejected; left on the next
valid one. Plant (real time): every valve and manifold closed when THR_CMD stopped for
``thr_cmd_lost_ticks`` ticks or the flight heartbeat was silent for ``heartbeat_lost_s``;
(lockstep): when THR_CMD misses its deadline ``thr_cmd_lost_ticks`` times in a row. The counts
come from the scenario's ``safety:`` block; ``python -m hil.nodes`` flags override them.
"""

from __future__ import annotations

import re
import threading
import time
import uuid
from pathlib import Path

import pytest

from bus.catalog import GyroStatus, Node, NodeState
from bus.codec import FdirStatus, Frame, Gyro, Heartbeat, ThrCmd
from bus.transport import BusConfig, Port, open_bus
from hil.config import load_scenario
from hil.flight_shell import FlightShell
from hil.node_settings import parse_settings
from hil.node_shell import lockstep_receiver, open_port
from hil.plant_shell import PlantShell
from hil.recorder import read_jsonl
from hil.safe_states import FlightLinkWatch, GyroLossWatch, safety_settings


def _scenario(tmp_path: Path, safety: str = "", duration_s: float = 30.0) -> Path:
    p = tmp_path / "s.yaml"
    p.write_text("name: safe\nvehicle: generic\n"
                 f"duration_s: {duration_s}\nseed: 0\n"
                 "initial: {attitude: {axis: [1, 0, 0], angle_deg: 10.0}}\n" + safety)
    return p


def _args(node: str, scen: Path, out: Path, channel: str, mode: str, *extra: str):
    return parse_settings(
        [node, "--scenario", str(scen), "--out", str(out), "--mode", mode,
         "--interface", "virtual", "--channel", channel, *extra])


def _channel() -> str:
    return f"safe-{uuid.uuid4().hex[:12]}"


# ----------------------------------------------------------------------------- pure watches


def test_gyro_loss_watch_enters_after_n_ticks_and_leaves_on_the_next_sample() -> None:
    w = GyroLossWatch(3)
    got = [w.tick(f) for f in (True, False, False, True, False, False, False, False, True)]
    # A gap of 2 is not a loss; the 3rd tick in a row without a sample is; the next one back.
    assert got == [None, None, None, None, None, None, "lost", None, "back"]
    assert not w.safe and w.ticks_without == 0
    with pytest.raises(ValueError, match="lost_ticks: expected >= 1, got 0"):
        GyroLossWatch(0)


def test_flight_link_watch_thr_cmd_stopped() -> None:
    w = FlightLinkWatch(tick_s=0.2, thr_cmd_lost_ticks=2, heartbeat_lost_s=1.0)
    beat = Heartbeat(Node.FLIGHT, NodeState.RUN)
    cmd = ThrCmd(0, (0,) * 6, 1, 0)
    t = 0.0
    for _ in range(5):  # commands and beats every tick
        w.on_message(beat, t)
        w.on_message(cmd, t)
        assert w.poll(t) == []
        t += 0.2
    last_cmd = t - 0.2
    # Heartbeats go on, commands stop: lost once more than 2 ticks passed, said once.
    assert w.poll(last_cmd + 0.39) == []
    w.on_message(beat, last_cmd + 0.39)
    assert w.poll(last_cmd + 0.41) == ["no THR_CMD for 2 ticks"]
    assert w.poll(last_cmd + 0.6) == [] and w.alive
    w.on_message(cmd, last_cmd + 0.7)  # back: a later gap is a new loss
    assert w.poll(last_cmd + 1.2) == ["no THR_CMD for 2 ticks"]


def test_flight_link_watch_heartbeat_lost_and_back() -> None:
    w = FlightLinkWatch(tick_s=0.2, thr_cmd_lost_ticks=3, heartbeat_lost_s=1.0)
    assert w.poll(0.99) == []
    assert w.poll(1.01) == ["flight heartbeat lost (1.01 s silent)"]  # none since the start
    assert w.poll(5.0) == [] and not w.alive
    assert w.on_message(Heartbeat(Node.FLIGHT, NodeState.RUN), 5.0) == [
        "flight heartbeat back at 5.00 s"]
    assert w.alive and w.poll(5.9) == []
    assert w.on_message(Heartbeat(Node.PLANT, NodeState.RUN), 6.0) == []  # its own: ignored
    assert w.poll(6.01) == ["flight heartbeat lost (1.01 s silent)"]


def test_settings_come_from_the_scenario_and_the_node_flags_override(tmp_path) -> None:
    scen = _scenario(tmp_path, "safety: {thr_cmd_lost_ticks: 5, heartbeat_lost_s: 2.5, "
                               "gyro_lost_ticks: 4}\n")
    sc = load_scenario(scen)
    base = _args("plant", scen, tmp_path, "x", "lockstep")
    assert safety_settings(sc, base).model_dump() == {
        "thr_cmd_lost_ticks": 5, "heartbeat_lost_s": 2.5, "gyro_lost_ticks": 4,
        "recover_ticks": 3, "thr_cmd_missing": "zero"}
    over = _args("plant", scen, tmp_path, "x", "lockstep", "--lost-after", "2",
                 "--heartbeat-lost-s", "0.8", "--gyro-lost-after", "6")
    assert safety_settings(sc, over).model_dump() == {
        "thr_cmd_lost_ticks": 2, "heartbeat_lost_s": 0.8, "gyro_lost_ticks": 6,
        "recover_ticks": 3, "thr_cmd_missing": "zero"}
    default = load_scenario(_scenario(tmp_path))
    assert safety_settings(default, base).model_dump() == {
        "thr_cmd_lost_ticks": 3, "heartbeat_lost_s": 1.5, "gyro_lost_ticks": 3,
        "recover_ticks": 3, "thr_cmd_missing": "zero"}


@pytest.mark.parametrize(("flag", "value", "msg"), [
    ("--lost-after", "0", "expected an integer >= 1, got 0"),
    ("--gyro-lost-after", "two", "expected an integer >= 1, got 'two'"),
    ("--heartbeat-lost-s", "0.5", "expected > the heartbeat period 0.5 s, got 0.5"),
])
def test_node_flags_are_checked(tmp_path, capsys, flag, value, msg) -> None:
    with pytest.raises(SystemExit) as info:
        _args("plant", tmp_path / "s.yaml", tmp_path, "x", "lockstep", flag, value)
    assert info.value.code == 2 and msg in capsys.readouterr().err


# ----------------------------------------------------------------------------- flight shell


class _FlightBench:
    """A ``FlightShell`` on a virtual bus and a port playing the plant; ticks driven by hand."""

    def __init__(self, tmp_path: Path, safety: str) -> None:
        ch = _channel()
        scen = _scenario(tmp_path, safety)
        self.out = tmp_path / "flight"
        self.out.mkdir()
        args = _args("flight", scen, self.out, ch, "lockstep")
        self.shell = FlightShell(load_scenario(scen), open_port(args, self.out, "flight"),
                                 self.out, args)
        # Age limits of the lockstep (a loaded machine must not make frames stale here).
        self.plant = Port(open_bus(BusConfig(interface="virtual", channel=ch)),
                          receiver=lockstep_receiver(2.0))
        self.seq = 0

    def gyro(self, corrupt: bool = False) -> None:
        msg = Gyro(self.seq, (0.001, -0.002, 0.0005), 1)
        self.seq += 1
        if not corrupt:
            self.plant.send(msg)
            return
        for fr in self.plant.protect(msg):  # CRC broken: the receiver rejects it
            self.plant.send_frame(Frame(fr.arbitration_id, bytes([fr.data[0] ^ 0xFF])
                                        + fr.data[1:]))

    def tick(self, n: int) -> tuple[ThrCmd, FdirStatus]:
        self.shell.absorb(self.shell.port.poll(0.02))
        self.shell.tick(n)
        got = {type(m): m for m, _ in self.plant.poll(0.05)}
        return got[ThrCmd], got[FdirStatus]

    def records(self) -> list[dict]:
        self.shell.rec.close()
        return list(read_jsonl(self.out / "flight.jsonl"))

    def close(self) -> None:
        self.shell.port.close()
        self.plant.close()


def test_flight_goes_safe_when_the_gyro_stops_and_comes_back(tmp_path) -> None:
    b = _FlightBench(tmp_path, "safety: {gyro_lost_ticks: 4}\n")
    try:
        cmds = []
        for n in range(5):
            b.gyro()
            cmds.append(b.tick(n))
        assert any(sum(c.on_quanta) for c, _ in cmds), "the flight should fire at 10 deg"
        assert not any(f.safe_mode for _, f in cmds)
        stopped = [b.tick(n) for n in range(5, 12)]  # the gyro stops
        # Ticks 5, 6, 7 without a sample: still flying; the 4th (tick 8) goes safe.
        assert [f.safe_mode for _, f in stopped] == [False] * 3 + [True] * 4
        assert all(sum(c.on_quanta) == 0 for c, _ in stopped[3:])
        b.gyro()
        back_cmd, back_fdir = b.tick(12)
        assert not back_fdir.safe_mode
    finally:
        b.close()
    recs = b.records()
    assert recs[0]["config"]["safety"] == {"gyro_lost_ticks": 4}
    assert recs[0]["config"]["vehicle"] == "generic"
    # (The made-up gyro does not match the flight's model: detections come too; not checked.)
    events = {r["tick"]: [e for e in r["events"] if "safe mode" in e] for r in recs
              if any("safe mode" in e for e in r["events"])}
    assert events == {8: ["safe mode: no valid gyro for 4 ticks: no firing"],
                      12: ["gyro back: leaving safe mode"]}
    assert [r["safe"] for r in recs] == [False] * 8 + [True] * 4 + [False]
    assert all(r["thr_cmd_on_ms"] == 0 for r in recs[8:12])
    assert sum(r["thr_cmd_on_ms"] for r in recs[:5]) > 0


def test_rejected_gyro_samples_count_as_no_gyro(tmp_path) -> None:
    b = _FlightBench(tmp_path, "safety: {gyro_lost_ticks: 2}\n")
    try:
        b.gyro()
        assert not b.tick(0)[1].safe_mode
        b.gyro(corrupt=True)
        assert not b.tick(1)[1].safe_mode
        b.gyro(corrupt=True)
        cmd, fdir = b.tick(2)
        assert fdir.safe_mode and sum(cmd.on_quanta) == 0
        assert b.shell.port.counts()["bad_crc"] >= 2
    finally:
        b.close()
    assert b.records()[2]["events"] == ["safe mode: no valid gyro for 2 ticks: no firing"]


# ----------------------------------------------------------------------------- plant shell


def _plant_bench(tmp_path: Path, safety: str, duration_s: float, mode: str):
    ch = _channel()
    scen = _scenario(tmp_path, safety, duration_s)
    out = tmp_path / "plant"
    out.mkdir()
    extra = ["--reply-timeout", "0.05"] if mode == "lockstep" else []
    args = _args("plant", scen, out, ch, mode, *extra)
    shell = PlantShell(load_scenario(scen), open_port(args, out, "plant"), out, args)
    flight = Port(open_bus(BusConfig(interface="virtual", channel=ch)))
    return shell, flight, out


SLACK_S = 0.6  # how late a wall-clock deadline may be seen on a loaded machine


def _run_realtime_with(shell, flight: Port, fake_flight, done: threading.Event) -> None:
    """The plant's real-time loop with ``fake_flight`` on another thread; both closed after."""
    th = threading.Thread(target=fake_flight)
    th.start()
    try:
        assert shell.run_realtime(lambda: False) == 0
    finally:
        done.set()
        th.join()
        shell.port.close()
        flight.close()


def _closed_at(event: str) -> float:
    """The plant time in "safe: all valves and manifolds closed at 1.23 s (...)"."""
    return float(re.match(r"safe: all valves and manifolds closed at ([0-9.]+) s", event)[1])


def test_realtime_plant_closes_every_valve_when_thr_cmd_stops(tmp_path) -> None:
    """The real loop (``PlantShell.run_realtime``, wall clock) with a fake flight that beats
    all along, fires every thruster for 0.6 s and then stops commanding."""
    shell, flight, out = _plant_bench(
        tmp_path, "safety: {thr_cmd_lost_ticks: 2, heartbeat_lost_s: 1.0}\n", 1.6, "realtime")
    done = threading.Event()
    t_last_cmd: list[float] = []

    def fake_flight() -> None:
        t0 = time.monotonic()
        k = 0
        while not done.is_set() and time.monotonic() - t0 < 1.6:
            flight.send(Heartbeat(Node.FLIGHT, NodeState.RUN))
            seq = _next_gyro_seq(flight, 0.3)
            if time.monotonic() - t0 < 0.6 and seq is not None:
                flight.send(ThrCmd(k, (20,) * 6, 1, seq))  # fresh: from the newest sample
                t_last_cmd.append(time.monotonic() - t0)
            k += 1

    _run_realtime_with(shell, flight, fake_flight, done)
    recs = [r for r in read_jsonl(out / "plant.jsonl") if not r.get("final")]
    assert recs[0]["config"]["safety"] == {"thr_cmd_lost_ticks": 2, "heartbeat_lost_s": 1.0,
                                           "thr_cmd_missing": "zero"}
    events = [e for r in recs for e in r["events"] if e.startswith("safe:")]
    assert len(events) == 1 and events[0].endswith("(no THR_CMD for 2 ticks)"), events
    closed_at = _closed_at(events[0])
    # The last command came at ~0.5 s: closed 2 ticks (0.4 s) later, not before (the two
    # clocks start a few ms apart), and not much after (slack for a loaded machine).
    assert t_last_cmd[-1] + 0.4 - 0.05 <= closed_at <= t_last_cmd[-1] + 0.4 + SLACK_S, \
        (t_last_cmd, events)
    safe_at = next(r["t_s"] for r in recs if r["safe"])
    # It fired before; after the closure (valves and manifolds, decay < 0.1 s) nothing burns.
    assert max(max(r["series"]["truth/thrust_n"].values()) for r in recs
               if r["t_s"] < 0.6) > 0.5
    after = [r for r in recs if r["t_s"] >= safe_at + 0.2]
    assert after and all(max(r["series"]["truth/thrust_n"].values()) < 1e-6 for r in after)


def _next_gyro_seq(port: Port, wait_s: float) -> int | None:
    """The sequence number of the next GYRO sample to arrive within ``wait_s`` (a flight
    computes its tick from the sample as soon as it comes)."""
    t_end = time.monotonic() + wait_s
    while time.monotonic() < t_end:
        for msg, _ in port.poll(max(0.0, t_end - time.monotonic())):
            if isinstance(msg, Gyro):
                return msg.sample_seq
    return None


def test_realtime_stale_and_out_of_order_commands_are_dropped_and_counted(tmp_path) -> None:
    """Issue 17: after a stall a flight sends a command computed from a gyro sample taken
    before it; before, the plant applied it (it lifted the safe state and fired).
    Now it is dropped and counted as stale, a repeated tick as out of order, and the plant
    leaves its safe state only after ``recover_ticks`` fresh commands of consecutive ticks."""
    shell, flight, out = _plant_bench(
        tmp_path, "safety: {thr_cmd_lost_ticks: 2, heartbeat_lost_s: 1.0, recover_ticks: 3}\n",
        2.6, "realtime")
    done = threading.Event()
    log: list[tuple[str, float]] = []

    def fake_flight() -> None:
        t0 = time.monotonic()
        k, seen, last_k = 0, [], 0  # seen: (gyro seq, when it arrived)
        while not done.is_set() and time.monotonic() - t0 < 2.1:
            flight.send(Heartbeat(Node.FLIGHT, NodeState.RUN))
            seq = _next_gyro_seq(flight, 0.3)
            now = time.monotonic() - t0
            if seq is None:
                continue
            seen.append((seq, now))
            old = [q for q, t in seen if t < now - 0.5]
            if 0.9 <= now and old and not any(w == "stale" for w, _ in log):
                # After a stall: a command computed from a sample of half a second ago,
                # then the last applied tick once more.
                flight.send(ThrCmd(k, (20,) * 6, 1, old[-1]))
                log.append(("stale", now))
                flight.send(ThrCmd(last_k, (20,) * 6, 1, seq))
                log.append(("repeat", now))
            elif not 0.5 <= now < 0.9:  # 0.5-0.9 s: silent (the plant goes safe)
                flight.send(ThrCmd(k, (20,) * 6, 1, seq))
                log.append(("fresh", now))
                last_k = k
            k += 1

    _run_realtime_with(shell, flight, fake_flight, done)
    recs = [r for r in read_jsonl(out / "plant.jsonl") if not r.get("final")]
    events = [(r["t_s"], e) for r in recs for e in r["events"]]
    assert recs[-1]["command_gate"]["stale"] >= 1  # in the records as they are written
    gate = shell.gate.counts  # to the end of the loop (after the last record too)
    # The command from before the stall is dropped as stale (a loaded machine may make a
    # fresh one late as well: counted the same way, never applied), the repeated tick as out
    # of order; every command is in one class.
    assert gate["stale"] >= 1 and gate["out_of_order"] == 1, (gate, log, events)
    # Every command reaching the plant's application is judged once; on a loaded machine the
    # receiver may refuse one first (counted among its own rejections, never applied).
    assert len(log) - 1 <= sum(gate.values()) <= len(log), (gate, log, shell.port.counts())
    ages = [int(m[1]) for _, e in events
            if (m := re.search(r"dropped: stale, (\d+) ms after its gyro sample", e))]
    assert ages and max(ages) >= 500, events  # the one computed half a second before
    assert any("dropped: out_of_order" in e for _, e in events), events
    # The stall made the plant safe (no THR_CMD for 2 ticks); the stale command did not lift
    # it; three fresh ticks in a row did.
    t_safe = next(t for t, e in events if e.startswith("safe:"))
    t_back = next(t for t, e in events if "leaving safe state" in e)
    t_stale = next(t for w, t in log if w == "stale")
    assert t_safe < t_back and t_back > t_stale + 0.2, (events, log)
    assert "(3 fresh ticks in a row)" in next(e for _, e in events if "leaving safe" in e)


def test_realtime_a_dropped_stale_command_flags_the_next_two_samples(tmp_path) -> None:
    """A fresh command every tick but one, which is computed from an old sample and dropped as
    stale: the flight's model fired that tick and the plant did not, so the next two GYRO
    samples say CMD_NOT_APPLIED (the flight keeps those ticks out of its evidence). Only the
    first one said so before: in a 720 s real-time run a dropped full-tick command showed in the
    second sample too and read as a gyro bias step."""
    shell, flight, out = _plant_bench(
        tmp_path, "safety: {thr_cmd_lost_ticks: 5, heartbeat_lost_s: 1.0}\n", 2.4, "realtime")
    done = threading.Event()
    samples: list[tuple[float, int]] = []  # (arrival, status) of every GYRO sample
    sent: list[tuple[str, float]] = []

    def fake_flight() -> None:
        t0 = time.monotonic()
        k, first = 0, None
        while not done.is_set() and time.monotonic() - t0 < 2.2:
            flight.send(Heartbeat(Node.FLIGHT, NodeState.RUN))
            t_end = time.monotonic() + 0.3
            got = None
            while got is None and time.monotonic() < t_end:
                for msg, _ in flight.poll(max(0.0, t_end - time.monotonic())):
                    if isinstance(msg, Gyro):
                        got = msg
                        break
            if got is None:
                continue
            now = time.monotonic() - t0
            samples.append((now, int(got.status)))
            first = got.sample_seq if first is None else first
            if 1.0 <= now and not any(w == "stale" for w, _ in sent):
                flight.send(ThrCmd(k, (20,) * 6, 1, first))  # from the first sample: stale
                sent.append(("stale", now))
            else:
                flight.send(ThrCmd(k, (20,) * 6, 1, got.sample_seq))
                sent.append(("fresh", now))
            k += 1

    _run_realtime_with(shell, flight, fake_flight, done)
    assert shell.gate.counts["stale"] == 1, (shell.gate.counts, sent)
    t_stale = next(t for w, t in sent if w == "stale")
    flagged = [bool(st & GyroStatus.CMD_NOT_APPLIED) for t, st in samples if t > t_stale]
    assert len(flagged) >= 3, (samples, sent)
    # The two samples after the dropped command are flagged, the third (after a fresh command
    # applied in time) is evidence again.
    assert flagged[:3] == [True, True, False], (samples, sent)
    events = [e for r in read_jsonl(out / "plant.jsonl") for e in r.get("events", [])]
    assert any("dropped: stale" in e for e in events), events
    assert not any(e.startswith("safe:") for e in events), events


def test_a_flagged_sample_is_followed_by_one_more(tmp_path) -> None:
    """At a flagged tick the flight restarts its onboard model from the measurement, believing
    the unapplied command burnt, so the next tick's prediction is no evidence either: the plant
    flags one more sample after every flagged run. In a 720 s real-time S002-100 the first sample
    after the plant left a safe state was evidence and read as a gyro bias step (the model
    carried the un-burnt command's tail into it)."""
    shell, flight, out = _plant_bench(tmp_path, "", 2.0, "lockstep")
    applied = [True, True, False, True, True, False, False, True, True]
    flags: list[bool] = []
    try:
        shell.plant.advance_to(0.1)
        shell.gyro_messages(shell.plant.gyro_samples_until(0.1))  # the sample at 0
        for k, a in enumerate(applied):
            t = 0.2 * (k + 1)
            shell.plant.advance_to(t)
            shell.cmd_applied = a
            msgs = shell.gyro_messages(shell.plant.gyro_samples_until(t))
            flags += [bool(g.status & GyroStatus.CMD_NOT_APPLIED) for g in msgs]
    finally:
        shell.port.close()
        flight.close()
    assert flags == [False, False, True, True, False, True, True, True, False], flags


def test_command_gate_classes_and_recovery() -> None:
    from hil.safe_states import CommandGate

    g = CommandGate(0.1, recover_ticks=3)
    assert g.judge(0, 0.00, 0.01) == "fresh" and g.run_length == 1
    assert g.judge(0, 0.00, 0.02) == "out_of_order"          # the same tick again
    assert g.judge(1, 0.20, 0.31) == "stale"                 # 110 ms after its sample
    assert g.run_length == 0 and not g.may_leave_safe()
    assert g.judge(2, None, 0.45) == "unknown_sample"
    assert [g.judge(n, 0.2 * n, 0.2 * n + 0.01) for n in (3, 4, 5)] == ["fresh"] * 3
    assert g.may_leave_safe()
    assert g.judge(7, 1.4, 1.41) == "fresh" and g.run_length == 1  # tick 6 never came
    assert g.counts == {"fresh": 5, "stale": 1, "out_of_order": 1, "unknown_sample": 1}


def test_realtime_plant_closes_every_valve_when_the_heartbeat_is_lost(tmp_path) -> None:
    """The flight never beats: lost ``heartbeat_lost_s`` after the plant's start."""
    shell, flight, out = _plant_bench(tmp_path, "safety: {heartbeat_lost_s: 0.6}\n", 1.2,
                                      "realtime")
    try:
        assert shell.run_realtime(lambda: False) == 0
    finally:
        shell.port.close()
        flight.close()
    recs = [r for r in read_jsonl(out / "plant.jsonl") if not r.get("final")]
    events = [e for r in recs for e in r["events"] if e.startswith("safe:")]
    assert len(events) == 1 and "(flight heartbeat lost (0.6" in events[0], events
    assert 0.6 <= _closed_at(events[0]) <= 0.6 + SLACK_S, events
    assert all(r["safe"] for r in recs if r["t_s"] > _closed_at(events[0]) + 0.01)


def test_lockstep_plant_goes_safe_after_the_configured_missed_commands(tmp_path) -> None:
    """No flight on the bus: every tick's THR_CMD misses its (50 ms) deadline."""
    shell, flight, out = _plant_bench(tmp_path, "safety: {thr_cmd_lost_ticks: 4}\n", 1.6,
                                      "lockstep")
    try:
        assert shell.run_lockstep(lambda: False) == 0
    finally:
        shell.port.close()
        flight.close()
    recs = [r for r in read_jsonl(out / "plant.jsonl") if not r.get("final")]
    assert [r["safe"] for r in recs] == [False] * 3 + [True] * 5
    assert recs[3]["events"][-1] == ("safe: all valves and manifolds closed at 0.60 s "
                                     "(no THR_CMD for 4 ticks)")
    assert recs[0]["config"]["safety"]["thr_cmd_lost_ticks"] == 4


def test_flight_link_watch_a_beating_flight_whose_commands_never_arrive_is_lost() -> None:
    """The flight beats but none of its THR_CMD get through (a forger ahead of it took their
    alive counters: docs/hostile-bus.md): lost once heartbeat_lost_s plus the command ticks
    passed since its first beat, said once; a command that then arrives clears it."""
    w = FlightLinkWatch(tick_s=0.2, thr_cmd_lost_ticks=3, heartbeat_lost_s=1.0)
    beat = Heartbeat(Node.FLIGHT, NodeState.RUN)
    t = 0.5
    while t < 2.1:  # first beat at 0.5 s: lost after 0.5 + 1.0 + 0.6 = 2.1 s
        w.on_message(beat, t)
        assert w.poll(t) == []
        t += 0.2
    assert w.poll(2.11) == ["no THR_CMD in 1.61 s since the flight's first heartbeat"]
    w.on_message(beat, 2.9)
    assert w.poll(3.0) == []
    w.on_message(ThrCmd(10, (0,) * 6, 1, 10), 3.1)
    assert w.poll(3.2) == [] and not w.cmd_lost
