"""The python-can internals ``bus/socketcan_fast.py`` relies on, pinned; its batch frame I/O
over a socket pair (no vcan needed); its registration by name; ``Port.send_hook``.

Oracles: python-can's own ``build_can_frame``/``dissect_can_frame`` (the kernel's ``struct
can_frame`` layout as python-can writes it), the kernel's ``CMSG_SPACE`` for the time stamp,
and the receiver's counters for frames a send hook drops or corrupts.
"""

from __future__ import annotations

import inspect
import socket

import can
import pytest
from can.interfaces.socketcan import constants
from can.interfaces.socketcan import socketcan as sc

from bus.codec import Frame, Sync, ThrCmd, encode
from bus.socketcan_fast import INTERFACE_NAME, FastSocketcanBus, _wire
from bus.transport import BACKENDS, BusConfig, FrameBus, Port, open_bus, to_can_message


def test_the_internals_it_uses_are_there_with_the_layout_it_assumes() -> None:
    assert sc.CAN_FRAME_HEADER_STRUCT.size == 8  # can_id u32, len u8, flags u8, pad, len8_dlc
    assert sc.RECEIVED_TIMESTAMP_STRUCT.format == "@ll"
    assert sc.RECEIVED_ANCILLARY_BUFFER_SIZE >= socket.CMSG_SPACE(
        sc.RECEIVED_TIMESTAMP_STRUCT.size)
    assert constants.CANFD_MTU == 72 and constants.CAN_EFF_FLAG == 0x80000000
    assert constants.CAN_RTR_FLAG == 0x40000000 and constants.CAN_ERR_FLAG == 0x20000000
    assert "self.socket = " in inspect.getsource(sc.SocketcanBus.__init__)
    assert issubclass(FastSocketcanBus, sc.SocketcanBus) and issubclass(FastSocketcanBus,
                                                                        can.BusABC)


@pytest.mark.parametrize("fr", [
    Frame(0x0A1, bytes([1, 2, 3, 4, 5, 6, 7, 8])),
    Frame(0x123, b"\x09\x08"),
    Frame(0x1ABCDE, bytes(8), False, True),
])
def test_the_wire_format_is_python_cans(fr) -> None:
    wire = _wire(fr)
    assert wire == sc.build_can_frame(to_can_message(fr))
    can_id, dlc, _flags, data = sc.dissect_can_frame(wire)
    assert dlc == len(fr.data) and bytes(data) == fr.data
    assert can_id & 0x1FFFFFFF == fr.arbitration_id
    assert bool(can_id & constants.CAN_EFF_FLAG) == fr.is_extended_id


def test_it_is_registered_with_python_can_by_name_and_opened_for_socketcan() -> None:
    from can.interface import _get_class_for_interface

    assert can.interfaces.BACKENDS[INTERFACE_NAME] == ("bus.socketcan_fast", "FastSocketcanBus")
    assert _get_class_for_interface(INTERFACE_NAME) is FastSocketcanBus
    assert BACKENDS["socketcan"] == INTERFACE_NAME


def _pair_bus() -> tuple[FastSocketcanBus, socket.socket]:
    """The backend's frame I/O on one end of a datagram socket pair (no vcan, no bind)."""
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    bus = object.__new__(FastSocketcanBus)
    bus.socket = a
    bus._mm = False
    return bus, b


def test_batch_send_and_drain_over_a_socket_pair() -> None:
    tx, peer = _pair_bus()
    rx = object.__new__(FastSocketcanBus)
    rx.socket, rx._mm = peer, False
    try:
        frames = encode(ThrCmd(3, (3, 20, 0) * 10, 1, 30))
        assert isinstance(tx, FrameBus)
        assert tx.send_frames(frames) == len(frames)  # one sendmmsg
        assert tx.send_frame(frames[0])
        got: list = []
        rx.drain_frames(0.5, got, with_messages=True)
        assert [f.arbitration_id for f, _ in got] == [f.arbitration_id for f in frames] + [
            frames[0].arbitration_id]
        assert [f.data for f, _ in got] == [f.data for f in frames] + [frames[0].data]
        assert all(m.arbitration_id == f.arbitration_id for f, m in got)
        more: list = []
        rx.drain_frames(0.0, more)
        assert more == []  # drained: nothing left, no wait
    finally:
        tx.socket.close()
        peer.close()


def test_every_sent_frame_passes_the_send_hook() -> None:
    seen: list[int] = []

    def hostile(frames: list[Frame]) -> list[Frame]:
        # Drop SYNC, corrupt the first byte of THR_CMD's first frame: what bus faults will do.
        seen.extend(f.arbitration_id for f in frames)
        out = [f for f in frames if f.arbitration_id != encode(Sync(0, 0))[0].arbitration_id]
        if out:
            out[0] = Frame(out[0].arbitration_id, bytes([out[0].data[0] ^ 0xFF]) + out[0].data[1:])
        return out

    a = Port(open_bus(BusConfig(interface="virtual", channel="t_hook")), send_hook=hostile)
    b = Port(open_bus(BusConfig(interface="virtual", channel="t_hook")))
    try:
        assert a.send(Sync(1, 200)) == 0
        assert a.send(ThrCmd(1, (3, 20, 0), 1, 7)) == len(encode(ThrCmd(1, (3, 20, 0), 1, 7)))
        assert not a.send_frame(a.protect(Sync(2, 400))[0])
        got = []
        for _ in range(20):
            got += b.poll(0.1)
            if b.counts()["bad_crc"]:
                break
        assert got == [] and b.counts()["bad_crc"] == 1
        assert len(seen) == 1 + len(encode(ThrCmd(1, (3, 20, 0), 1, 7))) + 1
    finally:
        a.close()
        b.close()
