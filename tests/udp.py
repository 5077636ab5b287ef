"""A udp_multicast channel of its own for a test that starts a system on the host.

python-can binds every udp_multicast socket to one UDP port and Linux hands a datagram for a
group joined on the host to every socket bound to that port, so runs side by side (the unit
tests run in two workers) keep apart by their ports: ``GROUP:PORT`` (``bus.transport``)."""

from __future__ import annotations

import random
import socket


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("", 0))
        return s.getsockname()[1]


def private_udp_channel(first_octets: str = "239.74") -> str:
    """``GROUP:PORT`` with a random group under ``first_octets`` and a port free right now."""
    return (f"{first_octets}.{random.randrange(1, 255)}.{random.randrange(1, 255)}:"
            f"{free_udp_port()}")
