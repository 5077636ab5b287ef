"""Every single bit flip of every protected frame is rejected and counted, never raised.

Every frame of the catalog carries the E2E header (``bus/catalog.py``), so the messages below
cover every catalog frame (a test fails if a frame is added without a sample here).

Bit-level reasoning, checked per flip by an oracle written here (not ``bus.e2e``): byte 0 is
CRC-8/SAE-J1850 over (data ID, bytes 1..7). A flip in byte 0 changes the stored CRC and not
the computed one; a flip in bytes 1..7 changes the computed CRC and not the stored one (a CRC
whose generator has the x^0 term detects every single-bit error). Either way the CRC check
fails, so the receiver's class must be ``bad_crc`` (it checks the CRC before the counter), and
a flipped frame must not disturb the counter state or a frame set in progress.

A flip of an identifier bit gives an unknown id or another catalog frame, whose data ID
differs; the oracle decides which class is expected.

Two paths: the sans-IO ``Receiver.classify`` and the receive loop the nodes use
(``Port.poll``) over python-can's in-process ``virtual`` bus. The second receiver has every
deadline at one hour: staleness is a clock property tested in test_bus_receiver.py; here it
would only make the counts depend on how fast this machine schedules the test.
"""

from __future__ import annotations

import dataclasses
import itertools

import cantools
import pytest

from bus.catalog import (
    CATALOG,
    AckReason,
    AckStatus,
    Catalog,
    DetectedFault,
    FaultAction,
    FaultKind,
    GyroStatus,
    Node,
    NodeState,
)
from bus.codec import (
    FaultAck,
    FaultCmd,
    FaultCmdMac,
    FdirStatus,
    FlightTiming,
    Frame,
    Gyro,
    GyroMac,
    Heartbeat,
    HeartbeatMac,
    Sync,
    SyncMac,
    ThrCmd,
    ThrCmdMac,
    encode,
)
from bus.dbc import DBC_PATH
from bus.e2e import Protector
from bus.receiver import CLASSES, Receiver
from bus.transport import BusConfig, Port, open_bus

NOW = 5000.0

# Scaled values are written as raw * scale, so that decoding gives back the same float.
SAMPLES = {
    "SYNC": Sync(123_456, 24_691_200),
    "GYRO": Gyro(
        0xBEEF, (123_456 * 1e-7, -456_789 * 1e-7, -1_999_999 * 1e-7), GyroStatus.VALID | 2
    ),
    "THR_CMD": ThrCmd(4242, tuple((0, 3, 9, 17, 20)[i % 5] for i in range(30)), 0b1011, 777),
    "FDIR_STATUS": FdirStatus(4100, DetectedFault.STUCK_ON, 5, 17, 0b0010, True, 3),
    "FAULT_CMD": FaultCmd(
        42, FaultAction.INJECT, FaultKind.DEGRADED, 7, 2500 * 1e-4, 1250 * 0.01, 3025 * 0.01
    ),
    "THR_CMD_MAC": ThrCmdMac(0x92, 4242, 0xA5C3E1),
    "FAULT_CMD_MAC": FaultCmdMac(42, 0xBEEF, 0x123456),
    "GYRO_MAC": GyroMac(0xEF, 0x3A5C, 0x654321),
    "SYNC_MAC": SyncMac(0x40, 0xE240, 0x0F1E2D),
    "FAULT_ACK": FaultAck(42, AckStatus.REJECTED, AckReason.BAD_FRACTION, FaultKind.DEGRADED),
    "FLIGHT_TIMING": FlightTiming(4242, 12_345 * 1e-6, 3),
    **{f"HEARTBEAT_{n.name}": Heartbeat(n, NodeState.RUN, 1000 + n, 7 * n, 11 * n) for n in Node},
    **{f"HEARTBEAT_{n.name}_MAC": HeartbeatMac(int(n), 0x1234 + n, 0xABCDE0 + n) for n in Node},
}

RELAXED = Catalog(tuple(dataclasses.replace(f, deadline_s=3600.0) for f in CATALOG.frames))


def crc8_j1850_bitwise(data: bytes) -> int:
    """Oracle: bit-at-a-time CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, xorout 0xFF)."""
    crc = 0xFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def oracle_crc_ok(data_id: int, data: bytes) -> bool:
    return data[0] == crc8_j1850_bitwise(bytes((data_id & 0xFF, data_id >> 8)) + data[1:])


def protect_all(msg, protector: Protector) -> list[Frame]:
    out = []
    for fr in encode(msg):
        data_id = CATALOG.by_id[fr.arbitration_id].data_id
        out.append(Frame(fr.arbitration_id, protector.protect(data_id, fr.data), timestamp_s=NOW))
    return out


def flip(fr: Frame, bit: int) -> Frame:
    data = bytearray(fr.data)
    data[bit // 8] ^= 1 << (bit % 8)
    return Frame(fr.arbitration_id, bytes(data), timestamp_s=fr.timestamp_s)


def test_samples_cover_every_catalog_frame_and_are_valid():
    """The samples are the whole catalog, and each frame is valid by the DBC alone."""
    db = cantools.database.load_file(str(DBC_PATH))
    seen = []
    p = Protector()
    for msg in SAMPLES.values():
        expected = msg.to_signals()
        for fr in protect_all(msg, p):
            f = CATALOG.by_id[fr.arbitration_id]
            seen.append(f.name)
            assert oracle_crc_ok(f.data_id, fr.data), f.name
            got = db.decode_message(fr.arbitration_id, fr.data, decode_choices=False)
            for name, value in expected[f.name].items():
                scale = f.signal(name).scale
                assert got[name] == pytest.approx(float(value), abs=scale / 2), (f.name, name)
    assert sorted(seen) == sorted(f.name for f in CATALOG.frames)


@pytest.mark.parametrize("name", SAMPLES)
def test_every_data_bit_flip_rejected_by_classify(name):
    """Each flipped frame arrives inside its set, just before the intact copy."""
    msg = SAMPLES[name]
    rx = Receiver()
    p = Protector()
    n_frames = len(encode(msg))
    delivered = []
    for i, bit in itertools.product(range(n_frames), range(64)):
        frames = protect_all(msg, p)
        bad = flip(frames[i], bit)
        f = CATALOG.by_id[bad.arbitration_id]
        assert not oracle_crc_ok(f.data_id, bad.data), (f.name, bit)
        verdicts = [rx.classify(fr, NOW) for fr in frames[:i]]
        v = rx.classify(bad, NOW)
        assert (v.kind, v.usable, v.message) == ("bad_crc", False, None), (f.name, bit, v)
        verdicts += [rx.classify(fr, NOW) for fr in frames[i:]]
        assert [x.kind for x in verdicts] == ["ok"] * n_frames, (f.name, bit, verdicts)
        delivered += [x.message for x in verdicts if x.message is not None]
    n_flips = 64 * n_frames
    assert delivered == [msg] * n_flips
    assert rx.counts() == {
        **dict.fromkeys(CLASSES, 0),
        "ok": n_flips * n_frames,
        "bad_crc": n_flips,
        "lost_frames": 0,
    }
    assert len(rx.events) == n_flips and {e.kind for e in rx.events} == {"bad_crc"}


@pytest.mark.parametrize("name", SAMPLES)
def test_every_identifier_bit_flip_rejected(name):
    """A flipped id is unknown, or another frame whose data ID the CRC does not match."""
    rx = Receiver()
    expected = dict.fromkeys(CLASSES, 0)
    for fr in protect_all(SAMPLES[name], Protector()):
        for bit in range(11):
            can_id = fr.arbitration_id ^ (1 << bit)
            other = CATALOG.by_id.get(can_id)
            if other is None:
                kind = "unknown_id"
            else:
                assert not oracle_crc_ok(other.data_id, fr.data), (hex(can_id), "masquerade")
                kind = "bad_crc"
            expected[kind] += 1
            v = rx.classify(Frame(can_id, fr.data, timestamp_s=NOW), NOW)
            assert (v.kind, v.usable, v.message) == (kind, False, None), hex(can_id)
    assert rx.counts() == {**expected, "lost_frames": 0}


def test_every_bit_flip_through_port_poll_over_virtual():
    """The same flips through the nodes' receive loop: python-can virtual bus, Port.poll."""
    channel = f"bit_flips_{id(RELAXED):x}"
    tx = Port(open_bus(BusConfig(interface="virtual", channel=channel)))
    rx = Port(open_bus(BusConfig(interface="virtual", channel=channel)), Receiver(RELAXED))
    sent_frames = 0
    n_flips = 0
    try:
        for name, msg in SAMPLES.items():
            n_frames = len(encode(msg))
            for i, bit in itertools.product(range(n_frames), range(64)):
                frames = tx.protect(msg)
                for fr in [*frames[:i], flip(frames[i], bit), *frames[i:]]:
                    assert tx.send_frame(fr)
                    sent_frames += 1
            # virtual sends are synchronous: everything is queued before this poll
            got = rx.poll(0.0)
            assert [m for m, _ in got] == [msg] * (64 * n_frames), name
            n_flips += 64 * n_frames
            assert rx.counts()["bad_crc"] == n_flips, name
        assert rx.poll(0.0) == []
    finally:
        tx.close()
        rx.close()
    c = rx.counts()
    assert c == {
        **dict.fromkeys(CLASSES, 0),
        "ok": sent_frames - n_flips,
        "bad_crc": n_flips,
        "lost_frames": 0,
        "tx_frames": 0,
        "tx_errors": 0,
    }
    assert tx.counts()["tx_frames"] == sent_frames and tx.counts()["tx_errors"] == 0
