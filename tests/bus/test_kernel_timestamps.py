"""Receive times over socketcan vcan0 are the kernel's (SO_TIMESTAMPNS), in CLOCK_REALTIME.

``bus/transport.py``: python-can sets ``SO_TIMESTAMPNS`` on its socket;
``FastSocketcanBus.drain_frames`` (the path ``Port.poll`` takes on socketcan) reads the
``struct timespec`` from the ancillary data of ``recvmsg``. The module documents
``Port.clock == "realtime"`` and the explicit conversion
``Port.to_monotonic_s(t) = t + monotonic_offset_s``, the offset being
``time.monotonic() - time.time()`` from the narrowest of a few bracketed reads, sampled when the
port opens and again once it is ``OFFSET_RESAMPLE_S`` old.

Oracles, with no assertion on speed:

* ordering: the kernel stamps a frame after our ``send`` starts and before the receiving
  socket becomes readable (``select``), so ``t_send <= rx <= t_readable`` in CLOCK_REALTIME;
  a time taken by user space when it reads the frame would come after ``t_readable``;
* python-can's own receive path (``can.Bus(...).recv``, ``capture_message``) on a second
  socket reads the same kernel stamp of the same frame: equal floats;
* frames sent one after the other have increasing stamps;
* the candump log of the receiving port carries the same times.

Linux enables receive stamping for the first socket that asks through deferred work, so the
first frames after boot may be stamped at ``recvmsg`` instead: a warm-up exchanges frames until
the kernel stamps at arrival (bounded; a transport that never shows it fails).
"""

from __future__ import annotations

import dataclasses
import select
import time

import can
import pytest

from bus.catalog import CATALOG, Catalog
from bus.codec import Sync
from bus.receiver import Receiver
from bus.transport import CLOCK, OFFSET_RESAMPLE_S, BusConfig, BusLogger, Port, open_bus
from hil import vcan

pytestmark = [
    pytest.mark.vcan,
    pytest.mark.skipif(
        not vcan.vcan_present("vcan0"), reason="vcan0 absent; run through `hil vcan exec`"
    ),
]

N_FRAMES = 20
WARM_UP_MAX = 50
# A float near 1.8e9 s resolves 0.24 us; both sides round to it. Not a latency allowance.
FLOAT_RES_S = 1e-6
RELAXED = Catalog(tuple(dataclasses.replace(f, deadline_s=3600.0) for f in CATALOG.frames))


@pytest.fixture
def ports(tmp_path):
    tx = Port(open_bus(BusConfig()))
    r0, m0 = time.time(), time.monotonic()
    rx = Port(open_bus(BusConfig()), Receiver(RELAXED), logger=BusLogger(tmp_path / "rx.log"))
    m1, r1 = time.monotonic(), time.time()
    ref = can.Bus(interface="socketcan", channel="vcan0")  # python-can's reference receive path
    try:
        yield tx, rx, ref, (r0, m0, m1, r1)
    finally:
        for b in (tx, rx, ref):
            b.close() if isinstance(b, Port) else b.shutdown()


def exchange(tx: Port, rx: Port, ref: can.BusABC, tick: int):
    """Send SYNC(tick); return (t_send, t_readable, m_readable, [(msg, rx_s)], python-can msg)."""
    t_send = time.time()
    assert tx.send(Sync(tick, 200 * tick)) == 1
    assert select.select([rx.bus.socket], [], [], 10.0)[0], f"SYNC {tick}: nothing in 10 s"
    t_ready, m_ready = time.time(), time.monotonic()
    got = rx.poll(0.0)
    return t_send, t_ready, m_ready, got, ref.recv(10.0)


def test_rx_times_are_kernel_stamps_in_realtime_and_convert_explicitly(ports, tmp_path):
    tx, rx, ref, (r0, m0, m1, r1) = ports
    tick = 0
    for _ in range(WARM_UP_MAX):
        _, t_ready, _, got, ref_msg = exchange(tx, rx, ref, tick)
        tick += 1
        if len(got) == 1 and got[0][1] <= t_ready + FLOAT_RES_S and got[0][1] == ref_msg.timestamp:
            break
    else:
        pytest.fail(
            f"vcan0: expected receive times stamped by the kernel before the socket was "
            f"readable (SO_TIMESTAMPNS), got {got} after {WARM_UP_MAX} frames"
        )

    assert rx.clock == CLOCK == "realtime"
    offset = rx.monotonic_offset_s
    # offset = monotonic() - time() sampled inside Port(): bracketed by our samples around it
    # (unless the exchanges above took longer than OFFSET_RESAMPLE_S and it was sampled again)
    if time.monotonic() - m1 < OFFSET_RESAMPLE_S:
        assert m0 - r1 - FLOAT_RES_S <= offset <= m1 - r0 + FLOAT_RES_S
    assert 0.0 <= rx.monotonic_offset_width_s < 0.1

    rx_times = []
    for _ in range(N_FRAMES):
        t_send, t_ready, m_ready, got, ref_msg = exchange(tx, rx, ref, tick)
        assert [m for m, _ in got] == [Sync(tick, 200 * tick)]
        rx_s = got[0][1]
        assert t_send - FLOAT_RES_S <= rx_s <= t_ready + FLOAT_RES_S, (t_send, rx_s, t_ready)
        assert ref_msg.arbitration_id == CATALOG.frame("SYNC").frame_id
        assert rx_s == ref_msg.timestamp  # the kernel's stamp, as python-can reads it
        assert not rx_times or rx_s > rx_times[-1]
        # the documented conversion, and only it: rx time + the port's current offset
        m_before = time.monotonic()
        conv = rx.to_monotonic_s(rx_s)
        assert conv == rx_s + rx.monotonic_offset_s
        # the offset it used brackets the clocks' relation now (no step here)
        r_now, m_after = time.time(), time.monotonic()
        assert m_before - r_now - 0.1 <= rx.monotonic_offset_s <= m_after - r_now + 0.1
        # realtime and monotonic differ by decades here: 1 s tells the clocks apart
        assert abs(rx.to_monotonic_s(rx_s) - m_ready) < 1.0 < abs(rx_s - m_ready)
        rx_times.append(rx_s)
        tick += 1
    assert abs(rx.monotonic_offset_s - offset) < 0.1  # no wall-clock step in this test
    assert rx.counts()["ok"] == tick and rx.counts()["bad_crc"] == 0

    rx.close()
    logged = [m.timestamp for m in can.LogReader(str(tmp_path / "rx.log"))]
    assert len(logged) == tick
    assert logged[-N_FRAMES:] == pytest.approx(rx_times, abs=FLOAT_RES_S)
