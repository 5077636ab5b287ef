"""Lockstep and heartbeat machines over a fake link (no sockets, explicit times)."""

import pytest

from bus.catalog import CATALOG, Node, NodeState
from bus.codec import Frame, Gyro, ThrCmd, unpack
from bus.link import FakeLink
from bus.protocol import (
    CommandLost,
    CommandReady,
    DeadlineMissed,
    DuplicateSync,
    FlightLockstep,
    HeartbeatMonitor,
    HeartbeatSender,
    PeerBack,
    PeerLost,
    PlantLockstep,
    SyncGap,
    TickRequest,
    UnexpectedCommand,
)
from hil.errors import ConfigError

N = 30


def quanta(tick):
    return tuple((3 + (tick + i) % 15) for i in range(N))


def run(ticks, hook=None, skip=()):
    """Plant and flight in lockstep over a fake link; 1 ms latency, tick every 0.2 s."""
    link = FakeLink(latency_s=0.001, hook=hook)
    pe, fe = link.endpoint("plant"), link.endpoint("flight")
    plant, flight = PlantLockstep(N, reply_timeout_s=0.05), FlightLockstep()
    results, events = [], []
    for n in range(ticks):
        t0 = 0.2 * n
        pe.send(Gyro(10 * n, (1e-5, 0.0, -1e-5)), t0)  # the sample first, then SYNC(n)
        pe.send(plant.begin_tick(n, t0), t0)
        for msg, rx in fe.deliver(t0 + 0.002):
            for ev in flight.on_message(msg, rx):
                if isinstance(ev, TickRequest) and ev.tick not in skip:
                    fe.send(flight.reply(ev.tick, quanta(ev.tick), 0b11), t0 + 0.003)
        for msg, rx in pe.deliver(t0 + 0.005):
            events += plant.on_message(msg, rx)
        events += plant.poll(t0 + 0.06)
        results.append(plant.result)
    return results, events, pe, fe, plant


def test_fifty_ticks_lockstep():
    results, events, pe, fe, plant = run(50)
    assert [r.tick for r in results] == list(range(50))
    assert all(not r.safe for r in results)
    assert [r.command.on_quanta for r in results] == [quanta(n) for n in range(50)]
    assert all(r.command.gyro_seq == 10 * r.tick for r in results)
    ready = [e for e in events if isinstance(e, CommandReady)]
    assert len(ready) == 50 and all(e.latency_s == pytest.approx(0.004) for e in ready)
    assert pe.receiver.counts()["ok"] == 250 and fe.receiver.counts()["ok"] == 150
    assert plant.deadline_misses == 0


def test_corrupted_frame_gives_safe_action_and_is_counted():
    def corrupt(sender, fr: Frame):
        f = CATALOG.frame("THR_CMD_3")
        if (
            sender == "flight"
            and fr.arbitration_id == f.frame_id
            and unpack(f, fr.data)["tick_lo"] == 10
        ):
            return Frame(fr.arbitration_id, bytes([fr.data[0] ^ 1]) + fr.data[1:])
        return fr

    results, events, pe, _, _ = run(12, hook=corrupt)
    assert results[10].safe and results[10].reason == "deadline missed"
    assert results[10].command.on_quanta == (0,) * N
    assert results[10].command.manifold_enable == 0b11  # a single miss keeps the manifolds
    assert not results[11].safe
    c = pe.receiver.counts()
    assert c["bad_crc"] == 1 and c["incomplete_set"] == 1
    assert DeadlineMissed(10, 1) in events


def test_command_lost_closes_manifolds():
    results, events, _, _, plant = run(8, skip={3, 4, 5})
    assert [e for e in events if isinstance(e, DeadlineMissed)] == [
        DeadlineMissed(3, 1),
        DeadlineMissed(4, 2),
        DeadlineMissed(5, 3),
    ]
    assert CommandLost(5, 3) in events
    assert results[5].command.manifold_enable == 0 and results[5].safe
    assert not results[6].safe and plant.consecutive_misses == 0


def test_late_and_wrong_tick_commands():
    plant = PlantLockstep(2, reply_timeout_s=0.05)
    plant.begin_tick(1, 0.0)
    assert plant.on_message(ThrCmd(0, (3, 3), 1, 0), 0.01) == [UnexpectedCommand(1, 0)]
    evs = plant.on_message(ThrCmd(1, (3, 3), 1, 0), 0.07)  # after the deadline
    assert evs == [DeadlineMissed(1, 1)] and plant.result.safe
    plant.begin_tick(2, 0.2)
    plant.begin_tick(3, 0.4)  # tick 2 never answered: missed when the next one starts
    assert plant.deadline_misses == 2
    with pytest.raises(ConfigError) as err:
        PlantLockstep(0)
    assert str(err.value) == "PlantLockstep: n_thrusters: expected > 0, got 0"


def test_flight_sync_gaps_and_duplicates():
    from bus.codec import Sync

    fl = FlightLockstep()
    assert fl.on_message(Sync(0, 0), 0.0) == [TickRequest(0, 0, 0.0)]
    assert fl.on_message(Sync(0, 0), 0.1) == [DuplicateSync(0)]
    assert fl.on_message(Sync(3, 600), 0.6) == [SyncGap(1, 3), TickRequest(3, 600, 0.6)]
    assert fl.reply(2, (3,), 1) is None
    assert fl.reply(3, (3,), 1) == ThrCmd(3, (3,), 1, 0)
    assert fl.reply(3, (3,), 1) is None


def test_heartbeats_lost_and_back():
    link = FakeLink()
    pe, fe = link.endpoint("plant"), link.endpoint("flight")
    sender = HeartbeatSender(Node.FLIGHT, start_s=0.0, period_s=0.5)
    mon = HeartbeatMonitor(Node.FLIGHT, start_s=0.0, period_s=0.5, missed_limit=3)
    events = []
    silent = (3.0, 5.0)
    for k in range(0, 161):
        t = k * 0.05
        hb = sender.poll(t, NodeState.RUN, rx_ok=k)
        if hb and not silent[0] <= t < silent[1]:
            fe.send(hb, t)
        for msg, rx in pe.deliver(t):
            events += mon.on_message(msg, rx)
        events += mon.poll(t)
    assert sender.sent == 17  # 0.0, 0.5, ..., 8.0: on the grid
    kinds = [type(e) for e in events]
    assert kinds == [PeerLost, PeerBack]
    assert events[0].at_s == pytest.approx(4.05) and events[1].at_s == pytest.approx(5.0)
    assert mon.alive and mon.lost_count == 1


def test_heartbeat_never_seen_is_lost():
    mon = HeartbeatMonitor(Node.PLANT, start_s=10.0, period_s=0.5, missed_limit=3)
    assert mon.poll(11.5) == []
    assert mon.poll(11.6) == [PeerLost(Node.PLANT, 11.6, pytest.approx(1.6))]
    assert mon.poll(12.0) == []


def test_heartbeat_sender_skips_missed_slots():
    s = HeartbeatSender(Node.PLANT, start_s=0.0, period_s=0.5)
    assert s.poll(0.0, NodeState.RUN) is not None
    assert s.poll(0.2, NodeState.RUN) is None
    assert s.poll(1.7, NodeState.RUN) is not None and s.next_s == 2.0
    hb = s.poll(2.0, NodeState.SAFE, rx_ok=70000, rx_bad=3, deadline_miss=5000)
    assert (hb.rx_ok, hb.deadline_miss, hb.state) == (70000 - 65536, 5000 - 4096, NodeState.SAFE)


def test_a_lost_peer_is_waited_for_briefly_until_it_answers_again():
    plant = PlantLockstep(2, reply_timeout_s=2.0, lost_after_misses=3, lost_reply_timeout_s=0.05)
    t = 0.0
    for n in range(3):
        plant.begin_tick(n, t)
        assert plant.deadline_s == pytest.approx(t + 2.0)
        t = plant.deadline_s
        plant.poll(t)
    assert plant.lost and plant.result.command.manifold_enable == 0
    plant.begin_tick(3, t)
    assert plant.deadline_s == pytest.approx(t + 0.05)  # the short wait once lost
    evs = plant.on_message(ThrCmd(3, (1, 0), 1, 0), t + 0.01)
    assert isinstance(evs[0], CommandReady) and not plant.lost
    plant.begin_tick(4, t + 0.2)
    assert plant.deadline_s == pytest.approx(t + 2.2)  # the full wait is back
