"""Bus faults on the send path (bus.faults.SendFaults) over python-can's virtual bus: each
fault does what it says, the receiver classifies what it sees, and a seed reproduces it."""

import time

import pytest

from bus.codec import Frame, Gyro, Sync, ThrCmd
from bus.faults import SendFaults, corrupt
from bus.transport import BusConfig, Port, open_bus
from common.scenario import FaultSpec
from hil.errors import BusError


class FakeClock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def pair(name: str, hook=None):
    a = Port(open_bus(BusConfig(interface="virtual", channel=name)), send_hook=hook)
    b = Port(open_bus(BusConfig(interface="virtual", channel=name)))
    return a, b


def drain(port: Port, wait_s: float = 0.3) -> list:
    got, t_end = [], time.monotonic() + wait_s
    while time.monotonic() < t_end:
        got += port.poll(0.02)
    return got


def spec(kind, **kw):
    return FaultSpec(kind=kind, t_s=kw.pop("t_s", 0.0), node="plant", **kw)


def gyros(n):
    return [Gyro(k, (1e-3, -2e-3, 3e-3)) for k in range(n)]


def test_drop_probability_is_counted_on_both_sides_and_reproducible():
    def run(seed):
        f = SendFaults(seed, "plant")
        f.add(spec("bus_drop", probability=0.3, message="GYRO"))
        a, b = pair(f"t_drop_{seed}", f)
        try:
            for g in gyros(200):
                a.send(g, Sync(g.sample_seq, 0))
            got = drain(b)
        finally:
            a.close()
            b.close()
        return f.counts["dropped"], [m for m, _ in got if isinstance(m, Gyro)], b.counts(), \
            a.counts()

    dropped, gyro_seen, rx, tx = run(7)
    assert sum(rx[k] for k in ("bad_crc", "wrong_length", "unknown_id")) == 0
    # 400 GYRO frames at p = 0.3: the count is binomial (mean 120, sd 9.2).
    assert 80 < dropped < 160
    assert tx["injected_dropped"] == dropped and tx["tx_frames"] == 600 - dropped
    # A GYRO set arrives only when both its frames did; SYNC is never touched.
    assert 0 < len(gyro_seen) < 200
    # Every frame that went out was checked: intact ones "ok", those after a gap
    # "counter_jump" (used when the jump is small, refused when large), or "stale" when the
    # test's burst left them in the queue beyond the frame's deadline.
    assert rx["ok"] + rx["counter_jump"] + rx["stale"] == 600 - dropped
    assert rx["counter_jump"] > 0
    assert rx["lost_frames"] > 0  # the alive counter tells the receiver frames went missing
    assert run(7)[0] == dropped
    assert run(8)[0] != dropped


def test_same_seed_drops_the_same_frames():
    frames = [Frame(0x110 + (k % 2), bytes([k % 256] * 8)) for k in range(500)]

    def passed(seed):
        f = SendFaults(seed, "plant", clock=FakeClock())
        f.add(spec("bus_drop", probability=0.3, message="GYRO"))
        return [fr.data for fr in f(frames)]

    a = passed(11)
    assert a == passed(11) and a != passed(12)
    assert 300 < len(a) < 400


def test_drop_pattern_is_exact():
    f = SendFaults(1, "plant")
    f.add(spec("bus_drop", pattern=[1, 0, 0], message="SYNC"))
    a, b = pair("t_pattern", f)
    try:
        for n in range(9):
            a.send(Sync(n, n * 200))
        got = [m.tick for m, _ in drain(b)]
    finally:
        a.close()
        b.close()
    assert got == [1, 2, 4, 5, 7, 8]
    assert f.counts["dropped"] == 3


def test_delay_holds_frames_for_the_given_time_and_keeps_their_order():
    f = SendFaults(1, "plant")
    f.add(spec("bus_delay", delay_ms=80, delay_max_ms=150, message="SYNC"))
    a, b = pair("t_delay", f)
    try:
        t_sent = {}
        for n in range(5):
            t_sent[n] = time.time()
            a.send(Sync(n, 0))
            a.poll(0.01)
        assert f.held >= 1
        got, t_end = [], time.monotonic() + 1.0
        while time.monotonic() < t_end:
            a.poll(0.005)  # the sender's poll releases what is due
            got += [(m.tick, time.time()) for m, _ in b.poll(0.0)]
    finally:
        a.close()
        b.close()
    assert [n for n, _ in got] == [0, 1, 2, 3, 4]  # order kept
    delays = [t - t_sent[n] for n, t in got]
    assert all(0.075 < d < 0.25 for d in delays), delays
    assert f.counts["delayed"] == 5


def test_delay_with_reorder_lets_frames_overtake():
    f = SendFaults(3, "plant", clock=FakeClock())
    f.add(spec("bus_delay", delay_ms=0, delay_max_ms=100, reorder=True, message="SYNC"))
    frames = [Frame(0x080, bytes([k] * 8)) for k in range(50)]
    assert f(frames) == []
    f.clock.t += 1.0
    out = [fr.data[0] for fr in f.due()]
    assert sorted(out) == list(range(50)) and out != list(range(50))
    g = SendFaults(3, "plant", clock=FakeClock())
    g.add(spec("bus_delay", delay_ms=0, delay_max_ms=100, message="SYNC"))
    g(frames)
    g.clock.t += 1.0
    assert [fr.data[0] for fr in g.due()] == list(range(50))


@pytest.mark.parametrize("what, klass", [("data", "bad_crc"), ("length", "wrong_length")])
def test_corrupt_is_rejected_with_its_class(what, klass):
    f = SendFaults(2, "plant")
    f.add(spec("bus_corrupt", corrupt=what, message="SYNC"))
    a, b = pair(f"t_corrupt_{what}", f)
    try:
        for n in range(20):
            a.send(Sync(n, 0))
        assert drain(b) == []
        assert b.counts()[klass] == 20
        assert f.counts["corrupted"] == 20
    finally:
        a.close()
        b.close()


def test_corrupt_identifier_flips_one_bit_and_nothing_is_used():
    f = SendFaults(2, "plant")
    f.add(spec("bus_corrupt", corrupt="id"))
    a, b = pair("t_corrupt_id", f)
    try:
        for n in range(30):
            a.send(ThrCmd(n, (3, 0, 20), 1, n))
        assert drain(b) == []
        c = b.counts()
        assert c["ok"] == 0 and c["unknown_id"] + c["bad_crc"] + c["wrong_length"] == 150
    finally:
        a.close()
        b.close()
    fr = Frame(0x0A0, bytes(8))
    import numpy as np
    rng = np.random.default_rng(0)
    for _ in range(20):
        x = corrupt(fr, "id", 1, rng).arbitration_id ^ 0x0A0
        assert x and x & (x - 1) == 0 and x < 0x800  # exactly one of the 11 bits


def test_node_silent_window_follows_scenario_time():
    f = SendFaults(1, "flight")
    f.add(FaultSpec(kind="node_silent", t_s=1.0, clear_t_s=2.0, node="flight"))
    a, b = pair("t_silent", f)
    try:
        seen = []
        for n in range(15):
            f.t_s = n * 0.2
            a.send(Sync(n, 0))
            seen += [m.tick for m, _ in b.poll(0.05)]
        seen += [m.tick for m, _ in drain(b, 0.1)]
    finally:
        a.close()
        b.close()
    # The first frame after the silence jumps the alive counter by 6: refused (it could be an
    # old frame replayed), and the receiver follows the counter from it.
    assert seen == [0, 1, 2, 3, 4, 11, 12, 13, 14]
    assert f.counts["silenced"] == 5
    assert b.counts()["counter_jump"] == 1
    assert [e["type"] for e in f.newly_active()] == ["node_silent"]


def test_babble_floods_at_its_rate_and_every_frame_is_rejected():
    f = SendFaults(1, "plant")
    f.add(spec("bus_babble", rate_hz=2000, message="THR_CMD"))
    a, b = pair("t_babble", f)
    try:
        t_end = time.monotonic() + 0.5
        while time.monotonic() < t_end:
            a.poll(0.01)
        f.clear("bus_babble", 1.0)
        f.t_s = 1.0
        got = drain(b, 0.2)
    finally:
        a.close()
        b.close()
    n = f.counts["babbled"]
    assert 600 < n <= 1100  # 2,000/s for a little over 0.5 s
    assert got == []
    c = b.counts()
    assert c["bad_crc"] + c["repeated_counter"] + c["counter_jump"] + c["out_of_range"] >= n - 5


def test_clear_ends_a_fault_and_unknown_message_is_one_line():
    f = SendFaults(1, "plant", clock=FakeClock())
    f.add(spec("bus_drop"))
    assert f([Frame(0x080, bytes(8))]) == []
    f.clear(None, 0.0)
    assert len(f([Frame(0x080, bytes(8))])) == 1
    with pytest.raises(BusError) as err:
        f.add(spec("bus_drop", message="NOPE"))
    assert str(err.value).startswith("bus fault: message: expected a catalog message or frame (")
    assert str(err.value).endswith("got 'NOPE'")
