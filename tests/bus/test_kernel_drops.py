"""Frames the kernel drops for a socket whose receive queue is full are counted (SO_RXQ_OVFL).

Under a flood, ``bus.log`` once kept 80,008 of 116,355 frames and the rest were counted
nowhere. ``FastSocketcanBus`` asks for ``SO_RXQ_OVFL``: every received frame then carries the
socket's cumulative drop count, which ``Port.counts()["kernel_drops"]`` reports (and the
records' ``bus`` block with it). Oracle: a receiver with a small queue that reads nothing
while N frames are sent; afterwards frames read plus frames the kernel says it dropped equal
the frames sent.
"""

from __future__ import annotations

import socket

import pytest

from bus.codec import Frame
from bus.transport import BusConfig, Port, open_bus
from hil import vcan

pytestmark = [
    pytest.mark.vcan,
    pytest.mark.skipif(
        not vcan.vcan_present("vcan0"), reason="vcan0 absent; run through `hil vcan exec`"
    ),
]

N_FRAMES = 3000


def test_kernel_drops_are_counted_and_account_for_every_frame_sent() -> None:
    tx = Port(open_bus(BusConfig()))
    rx_bus = open_bus(BusConfig())
    rx_bus.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # a short queue
    rx = Port(rx_bus)
    try:
        assert rx.counts()["kernel_drops"] == 0
        frame = Frame(0x7F0, bytes(8), False, False, 0.0)  # an id no node of ours uses
        sent = 0
        for _ in range(N_FRAMES):
            sent += tx.bus.send_frames([frame])  # nobody reads rx meanwhile
        got: list = []
        rx.bus.drain_frames(0.0, got)
        # The count rides on the frames that were queued; one more frame, sent once the queue
        # has room, carries the count of every drop before it.
        sent += tx.bus.send_frames([frame])
        rx.bus.drain_frames(1.0, got)
        drops = rx.counts()["kernel_drops"]
    finally:
        tx.close()
        rx.close()
    assert sent == N_FRAMES + 1
    assert drops > 0 and len(got) < sent
    assert len(got) + drops == sent, (len(got), drops, sent)
