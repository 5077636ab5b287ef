"""The flood's kernel sender over a real vcan0 (the CAN broadcast manager inside user-mode
Linux): what it says it sent is what the interface sent (oracle: the kernel's own interface
statistics), by identifier what a listening socket received."""

from __future__ import annotations

import threading
from collections import Counter
from pathlib import Path

import can
import pytest

from hil.flood import flood

pytestmark = pytest.mark.vcan


def _tx_packets(channel: str) -> int:
    return int(Path(f"/sys/class/net/{channel}/statistics/tx_packets").read_text())


@pytest.mark.parametrize("kind", ["foreign", "catalog-bad-crc"])
def test_kernel_flood_sends_what_it_reports(kind):
    seen: Counter[int] = Counter()
    stop = threading.Event()
    bus = can.Bus(interface="socketcan", channel="vcan0", receive_own_messages=False)

    def listen() -> None:
        while not stop.is_set():
            m = bus.recv(0.05)
            if m is not None:
                seen[m.arbitration_id] += 1

    t = threading.Thread(target=listen)
    t.start()
    try:
        before = _tx_packets("vcan0")
        res = flood(kind, 1200, 1.0, "socketcan", "vcan0", seed=5, sender="kernel")
        after = _tx_packets("vcan0")
        stop.set()
        t.join()
    finally:
        bus.shutdown()
    assert res["sender"] == "kernel" and res["timers"] == 3
    assert after - before == res["sent"] > 0  # nothing else sends during this test
    assert res["sent"] <= 3 * 400  # each timer stops at its count: 400 frames per second
    by_id = {int(k): v for k, v in res["by_id"].items()}
    assert sum(by_id.values()) == res["sent"]
    # a Python listener may lose frames to its socket buffer, never receive extra ones
    assert all(seen[i] <= n for i, n in by_id.items()) and set(seen) <= set(by_id)
    assert sum(seen.values()) >= 0.5 * res["sent"]
