"""The loop under bus faults: both process shells, in this process, over python-can's
``virtual`` bus (the plant in the test's thread, the flight in another), lockstep.

* ``bus_drop`` p = 0.3 on the plant's GYRO: the flight propagates the ticks without a
  sample, keeps them out of the detector's evidence, and raises no detection;
* ``node_silent`` of the flight for 2 s: the plant goes safe, and leaves its safe state when
  the flight is back (docs/hostile-bus.md);
* the faults appear in the summary (``faults``, ``bus_faults``), counted on both sides.
"""

from __future__ import annotations

import threading
import uuid
from pathlib import Path

from hil.config import load_scenario
from hil.flight_shell import FlightShell
from hil.hostile import forged_used
from hil.node_settings import parse_settings
from hil.node_shell import open_port
from hil.plant_shell import PlantShell
from hil.recorder import read_jsonl
from hil.secoc_key import new_key_file
from hil.summary import summarise
from tests.hil.shell_pair import run_lockstep_pair

BASE = ("name: hostile\nvehicle: generic\nduration_s: {d}\nseed: 0\n"
        "initial: {{attitude: {{axis: [1.0, 0.0, 0.0], angle_deg: 22.5}}}}\n")


def run_pair(tmp_path: Path, body: str, duration_s: float = 30.0,
             reply_timeout_s: float = 0.3, key: bool = False,
             attacker=None) -> tuple[list, list, dict]:
    scen = tmp_path / "s.yaml"
    scen.write_text(BASE.format(d=duration_s) + body)
    sc = load_scenario(scen)
    channel = f"hb-{uuid.uuid4().hex[:12]}"
    out = tmp_path / "run"
    out.mkdir()
    extra = ["--key-file", str(new_key_file(out))] if key else []

    def settings(node):
        return parse_settings([node, "--scenario", str(scen), "--out", str(out), "--mode",
                               "lockstep", "--interface", "virtual", "--channel", channel,
                               "--reply-timeout", str(reply_timeout_s), *extra])

    precs, frecs = run_lockstep_pair(sc, out, settings, attacker, channel)
    summary = summarise(scenario="hostile", vehicle="generic", mode="lockstep",
                        plant_records=precs, flight_records=frecs, expect=sc.cfg.expect)
    return precs, frecs, summary


def test_gyro_drop_30_percent_raises_no_thruster_detection(tmp_path):
    precs, frecs, s = run_pair(
        tmp_path, "faults:\n  - {kind: bus_drop, node: plant, message: GYRO, probability: 0.3,"
                  " t_s: 2.0}\n")
    assert s["detections"] == [] and s["false_alarms"] == []
    assert [(f["type"], f["node"], f["message"]) for f in s["faults"]] == \
        [("bus_drop", "plant", "GYRO")]
    bf = s["bus_faults"]["plant"]
    # 28 s x 1 sample per tick x 2 frames at p = 0.3: about 84 frames.
    assert 40 < bf["injected"]["dropped"] < 130
    assert bf["seen_by_peer"]["counter_jump"] > 0
    no_ev = frecs[-1]["no_evidence_ticks"]
    assert 20 < no_ev < 100  # P(both frames pass) = 0.49: about 70 of 140 ticks
    assert any("bus fault active on plant: bus_drop GYRO p=0.3" in e
               for r in precs for e in r.get("events", []))
    # The loop still holds the craft: it reaches the target from 22.5 deg.
    assert precs[-2]["att_err_deg"] < 2.0


def test_flight_silent_for_2_s_makes_the_plant_safe_and_it_recovers(tmp_path):
    precs, frecs, s = run_pair(
        tmp_path, "faults:\n  - {kind: node_silent, node: flight, t_s: 4.0, clear_t_s: 6.0}\n",
        duration_s=12.0)
    safe = [r["t_s"] for r in precs if r.get("safe")]
    assert safe, "the plant never went safe"
    # Three missed ticks from 4.0 s make it safe; three good ticks after 6.0 s release it.
    assert 4.4 <= safe[0] <= 5.0 and 6.0 <= safe[-1] <= 7.2
    assert not precs[-2]["safe"]
    events = [e for r in precs for e in r.get("events", [])]
    assert any(e.startswith("safe: all valves and manifolds closed") for e in events)
    assert any("leaving safe state" in e for e in events)
    assert s["detections"] == []  # the unapplied commands were no evidence
    assert s["bus_faults"]["flight"]["injected"]["silenced"] >= 10 * 7  # 10 ticks x 7 frames
    # The plant said so in its samples: the flight kept those ticks out of its evidence.
    assert frecs[-1]["no_evidence_ticks"] >= 10


def test_thr_cmd_missing_hold_repeats_the_last_command(tmp_path):
    precs, _, _ = run_pair(
        tmp_path, "safety: {thr_cmd_missing: hold, thr_cmd_lost_ticks: 5}\n"
                  "faults:\n  - {kind: bus_drop, node: flight, message: THR_CMD, "
                  "pattern: [1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0], t_s: 1.0}\n",
        duration_s=4.0)
    events = [e for r in precs for e in r.get("events", [])]
    held = [e for e in events if "holding the command of tick" in e]
    assert held and "(1 in a row)" in held[0]
    assert not any(e.startswith("safe:") for e in events)


def _shells(tmp_path: Path):
    scen = tmp_path / "s.yaml"
    scen.write_text(BASE.format(d=5.0))
    sc = load_scenario(scen)
    out = tmp_path / "run"
    out.mkdir()
    channel = f"hb-{uuid.uuid4().hex[:12]}"
    shells = []
    for node, cls in (("plant", PlantShell), ("flight", FlightShell)):
        s = parse_settings([node, "--scenario", str(scen), "--out", str(out), "--interface",
                            "virtual", "--channel", channel])
        shells.append(cls(sc, open_port(s, out, node), out, s))
    return shells


def test_panel_bus_faults_go_to_the_node_named_and_clear(tmp_path):
    from bus.catalog import AckStatus
    from hil.binding import fault_spec
    from hil.panel import build_bus_command

    plant, flight = _shells(tmp_path)
    try:
        inj = build_bus_command("inject", "bus_drop", "flight", 0.3, None, None, "THR_CMD",
                                None, None, 7)
        spec = fault_spec(inj, plant.names, 0.0, node="flight")
        assert (spec.kind, spec.node, spec.probability, spec.message) == \
            ("bus_drop", "flight", 0.3, "THR_CMD")
        plant.on_fault_cmd(inj)
        flight.on_fault_cmd(inj)
        flight.on_fault_cmd(inj)  # the panel's resend: not applied twice
        assert plant.bus_faults.faults == []
        assert [(f.spec.kind, f.spec.message) for f in flight.bus_faults.faults] == \
            [("bus_drop", "THR_CMD")]
        delay = build_bus_command("inject", "bus_delay", "plant", None, 80.0, None, "GYRO",
                                  1.0, 3.0, 8)
        plant.on_fault_cmd(delay)
        (f,) = plant.bus_faults.faults
        assert (f.spec.delay_ms, f.t_on_s, f.t_off_s, f.spec.message) == \
            (80.0, 1.0, 3.0, "GYRO")
        plant.on_fault_cmd(build_bus_command("clear", "bus_delay", "plant", None, None, None,
                                             None, None, None, 9))
        assert f.t_off_s == f.t_on_s and not f.active(1.5)  # cleared before it began
        flight.on_fault_cmd(build_bus_command("clear", "bus_drop", "flight", None, None, None,
                                              None, None, None, 10))
        assert flight.bus_faults.faults[0].t_off_s == 0.0
        assert plant.last_fault[2].status == AckStatus.ACCEPTED
    finally:
        plant.port.close()
        flight.port.close()


def test_panel_bus_command_errors_are_one_line():
    import pytest

    from hil.errors import FaultCommandError
    from hil.panel import build_bus_command

    with pytest.raises(FaultCommandError, match=r"^fault: --node: expected 'plant' or "
                                                r"'flight' for bus_drop, got None$"):
        build_bus_command("inject", "bus_drop", None, 0.3, None, None, None, None, None, 1)
    with pytest.raises(FaultCommandError, match=r"^fault: --message: expected one of \["):
        build_bus_command("inject", "bus_drop", "plant", 0.3, None, None, "NOPE", None, None, 1)
    with pytest.raises(FaultCommandError, match=r"^fault: --delay-ms: expected a delay"):
        build_bus_command("inject", "bus_delay", "plant", None, None, None, None, None, None, 1)


def test_forged_fault_and_thruster_commands_change_nothing_with_secoc(tmp_path):
    """A third node with valid E2E (its own CRCs and counters) but no key: its FAULT_CMD
    ("stuck on" for X-), THR_CMD (every thruster full on), GYRO (0.05 rad/s about every
    axis) and SYNC (a tick far ahead) are refused and counted."""
    from bus.catalog import FaultAction, FaultKind
    from bus.codec import FaultCmd, Gyro, Sync, ThrCmd
    from bus.transport import BusConfig, Port, open_bus

    def attacker(channel, done):
        port = Port(open_bus(BusConfig(interface="virtual", channel=channel)))
        n = 0
        while not done.wait(0.005):  # every 5 ms: a lockstep run lasts about 0.3 s
            n += 1
            port.send(FaultCmd(n % 256, FaultAction.INJECT, FaultKind.STUCK_ON, 1, 1.0, 0.0,
                               None))
            port.send(ThrCmd(10_000 + n, (20,) * 12, 0xF, 0))
            port.send(Gyro((n * 7) & 0xFFFF, (0.05, 0.05, 0.05), 1))
            port.send(Sync(50_000 + n, 0))
        port.close()

    precs, frecs, s = run_pair(tmp_path, "", duration_s=6.0, key=True, attacker=attacker)
    assert s["faults"] == [] and s["detections"] == []
    pb = s["bus"]["plant"]
    # Every one of the flight's 30 commands is authenticated and used: a second sender on
    # THR_CMD's identifiers upsets the E2E alive counters (repeated counters and jumps are
    # counted), but for authenticated messages the counter does not gate and the set keeps
    # variants, so the authenticator picks the genuine one (9 of 30 got through while the
    # counter gated).
    assert pb["auth_ok"] == 30
    assert pb["repeated_counter"] + pb["counter_jump"] > 0
    assert pb["auth_missing"] + pb["auth_fail"] > 10  # the forged FAULT_CMD and THR_CMD
    assert s["bus"]["flight"]["auth_missing"] > 5  # the flight hears FAULT_CMD too
    # ... and refuses the forged gyro samples: it flew on the plant's alone (every one of
    # its ticks had an authentic sample, none near the forged 0.05 rad/s)
    assert s["bus"]["flight"]["auth_ok"] >= 30
    # (the craft turns about x; about y and z the genuine rate stays near 0, a forged
    # sample would read 2.86 deg/s)
    rates = [abs(r["series"]["flight/omega_meas_deg_s"][a]) for r in frecs if "series" in r
             for a in "yz"]
    assert len(rates) >= 60 and max(rates) < 0.1, max(rates, default=None)
    assert not any("fault injected" in e for r in precs for e in r.get("events", []))
    assert any("without its authenticator" in e for r in precs for e in r.get("events", []))
    used = forged_used(s, precs, frecs)  # every command applied is one the flight sent
    assert used["fault_cmd"] == used["thr_cmd"] == 0 and used["thr_cmd_applied"] >= 5
    key_text = (tmp_path / "run" / "secoc.key").read_text().strip()
    for f in (tmp_path / "run").iterdir():  # the key is in its file only
        assert f.name == "secoc.key" or key_text not in f.read_text(errors="replace")
    assert oct((tmp_path / "run" / "secoc.key").stat().st_mode & 0o777) == "0o600"


def test_realtime_plant_holds_the_last_command_through_a_gap(tmp_path):
    """``thr_cmd_missing: hold`` in real time: a fake flight commands every tick, falls
    silent (commands only, heartbeat kept) for two ticks, and comes back: the plant repeats
    its last command in the gap and never goes safe."""
    import time

    from bus.catalog import Node, NodeState
    from bus.codec import Gyro, Heartbeat, ThrCmd
    from bus.transport import BusConfig, Port, open_bus

    scen = tmp_path / "s.yaml"
    scen.write_text(BASE.format(d=2.0) + "safety: {thr_cmd_missing: hold, "
                                         "thr_cmd_lost_ticks: 4, heartbeat_lost_s: 1.0}\n")
    out = tmp_path / "plant"
    out.mkdir()
    ch = f"hb-{uuid.uuid4().hex[:12]}"
    args = parse_settings(["plant", "--scenario", str(scen), "--out", str(out), "--mode",
                           "realtime", "--interface", "virtual", "--channel", ch])
    shell = PlantShell(load_scenario(scen), open_port(args, out, "plant"), out, args)
    flight = Port(open_bus(BusConfig(interface="virtual", channel=ch)))
    done = threading.Event()

    def fake_flight():
        # Answers each gyro sample at once, as the flight does, except samples 3 and 4 (the
        # gap: two ticks without a command). Keyed on the samples, not on this thread's
        # clock, so a loaded machine cannot stretch the gap to the safe-state limit (4).
        t0, last = time.monotonic(), -1
        while not done.is_set() and time.monotonic() - t0 < 2.0:
            flight.send(Heartbeat(Node.FLIGHT, NodeState.RUN))
            for msg, _ in flight.poll(0.02):
                if isinstance(msg, Gyro) and msg.sample_seq > last:
                    last = msg.sample_seq
                    if last not in (3, 4):
                        flight.send(ThrCmd(last, (20,) * 6, 1, last))

    th = threading.Thread(target=fake_flight)
    th.start()
    try:
        assert shell.run_realtime(lambda: False) == 0
    finally:
        done.set()
        th.join()
        shell.port.close()
        flight.close()
    recs = list(read_jsonl(out / "plant.jsonl"))
    events = [e for r in recs for e in r.get("events", [])]
    assert any("holding the command of tick" in e for e in events), events
    assert not any(e.startswith("safe:") for e in events), events
    # The held command fires in the gap: thrust inside it.
    gap = [r for r in recs if 0.9 <= r["t_s"] <= 1.1 and "series" in r]
    assert gap and max(max(r["series"]["truth/thrust_n"].values()) for r in gap) > 0.01
