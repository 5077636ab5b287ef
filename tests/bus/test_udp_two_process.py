"""The two-process lockstep suite over python-can ``udp_multicast``: two OS processes, no CAN.

``tests/bus/test_two_process.py::test_lockstep_fifty_ticks`` runs over ``virtual`` (peer in a
thread) and over vcan0 (peer process). Here the same test function runs with its
``ProcessPeer`` (``python -m bus.echo_peer`` in another process) over ``udp_multicast``.

The interface is chosen by configuration alone: ``BusConfig(interface="udp_multicast",
channel=<group>)`` on both sides, and the UDP port through python-can's own ``CAN_CONFIG``
environment variable, which the peer process inherits (``echo_peer`` has no option for it).
Each run takes a free port, so concurrent runs on one host do not hear each other.
"""

from __future__ import annotations

import importlib.util
import json
import socket
from pathlib import Path

import can
import pytest

from bus.transport import BusConfig


def _load_suite():
    path = Path(__file__).with_name("test_two_process.py")
    spec = importlib.util.spec_from_file_location("_two_process_suite", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


suite = _load_suite()
GROUP = "239.74.163.2"  # python-can's default group; the port keeps runs apart


@pytest.fixture
def udp_cfg(monkeypatch):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv("CAN_CONFIG", json.dumps({"port": port}))
    return BusConfig(interface="udp_multicast", channel=GROUP)


def test_lockstep_fifty_ticks_udp_multicast(udp_cfg):
    """The vcan/virtual suite, unchanged, between two processes over udp_multicast (each
    port drops its own frames looped back by the multicast socket; the counts are exact)."""
    suite.test_lockstep_fifty_ticks((udp_cfg, suite.ProcessPeer(udp_cfg)))


def test_group_port_channels_keep_two_runs_on_one_host_apart():
    """``GROUP:PORT``: two buses on one group but different ports never hear each other (on
    one port they do, whatever group each joined: the reason for the port form); a bad port is
    a one-line BusError."""
    from bus.errors import BusError
    from bus.transport import open_bus, udp_channel
    from tests.udp import free_udp_port

    assert udp_channel("239.74.1.2") == ("239.74.1.2", None)
    assert udp_channel("239.74.1.2:45000") == ("239.74.1.2", 45000)
    with pytest.raises(BusError, match="expected GROUP or GROUP:PORT"):
        open_bus(BusConfig(interface="udp_multicast", channel="239.74.1.2:70000"))
    p1, p2 = free_udp_port(), free_udp_port()
    while p2 == p1:
        p2 = free_udp_port()

    def heard(tx_channel: str, rx_channel: str) -> bool:
        tx = open_bus(BusConfig(interface="udp_multicast", channel=tx_channel))
        rx = open_bus(BusConfig(interface="udp_multicast", channel=rx_channel))
        try:
            tx.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
            return rx.recv(timeout=0.5) is not None
        finally:
            tx.shutdown()
            rx.shutdown()

    assert heard(f"239.74.9.9:{p1}", f"239.74.9.9:{p1}")
    assert not heard(f"239.74.9.9:{p1}", f"239.74.9.9:{p2}")
