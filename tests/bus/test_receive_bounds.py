"""Receive paths that hold their tick: catalog receive filters and bounded work per poll
(over python-can's virtual bus here; the same ``can_filters`` go to the kernel on SocketCAN,
measured over vcan in docs/hostile-bus.md)."""

from bus.catalog import CATALOG, Node, consumed_ids
from bus.codec import Frame, Gyro, Sync, ThrCmd
from bus.transport import BusConfig, Port, node_filters, open_bus


def test_consumed_ids_follow_the_catalog_receivers():
    assert consumed_ids(Node.PLANT) == tuple(sorted(
        f.frame_id for f in CATALOG.frames if Node.PLANT in f.receivers))
    flight = consumed_ids(Node.FLIGHT)
    assert CATALOG.frame("GYRO_1").frame_id in flight
    assert CATALOG.frame("THR_CMD_0").frame_id not in flight  # its own output
    assert CATALOG.frame("FLIGHT_TIMING").frame_id not in consumed_ids(Node.PLANT)


def test_a_filtered_port_never_sees_foreign_or_unconsumed_frames():
    tx = Port(open_bus(BusConfig(interface="virtual", channel="t_filter")))
    rx = Port(open_bus(BusConfig(interface="virtual", channel="t_filter",
                                 kwargs={"can_filters": node_filters(Node.FLIGHT)})))
    try:
        for k in range(50):
            tx.send_frame(Frame(0x7FF - k, bytes(8)))  # foreign identifiers
        tx.send(ThrCmd(1, (3, 0, 0), 1, 1))  # the flight's own output: not consumed
        tx.send(Gyro(5, (0.0, 0.0, 0.0)), Sync(1, 200))
        got = []
        for _ in range(20):
            got += rx.poll(0.02)
        assert sorted(type(m).__name__ for m, _ in got) == ["Gyro", "Sync"]
        assert rx.counts()["unknown_id"] == 0  # nothing foreign reached the receiver
    finally:
        tx.close()
        rx.close()


def test_poll_takes_at_most_its_bound_and_the_rest_waits():
    tx = Port(open_bus(BusConfig(interface="virtual", channel="t_cap")))
    rx = Port(open_bus(BusConfig(interface="virtual", channel="t_cap")), max_frames_per_poll=10)
    try:
        for n in range(35):
            tx.send(Sync(n, 0))
        sizes = []
        for _ in range(5):
            before = rx.counts()["ok"] + rx.counts()["stale"]
            rx.poll(0.05)
            sizes.append(rx.counts()["ok"] + rx.counts()["stale"] - before)
        assert sizes == [10, 10, 10, 5, 0]
        assert rx.counts()["polls_capped"] == 3
    finally:
        tx.close()
        rx.close()
