"""A bus log written by our code is replayed by third-party players and decodes to the originals.

The log is written by ``BusLogger`` (candump ``-L`` format) while a ``Port`` sends one message
of every kind. It is replayed

* with python-can's player (``python -m can.player``) over ``udp_multicast`` from another OS
  process, received by a ``Port`` here (host, no CAN needed);
* with can-utils' ``canplayer`` onto ``vcan0``, received by a ``Port`` on socketcan (marker
  ``vcan``: run through ``hil vcan exec``).

Oracles: the original messages; cantools decoding the committed DBC (not our codecs) for every
received frame; the raw frames of the original log as python-can's ``LogReader`` reads them.
The receiving ports have every deadline at one hour: a replay delivers frames at the player's
pace and we read them after the player exits, so staleness would only measure this machine.
"""

from __future__ import annotations

import dataclasses
import shutil
import socket
import subprocess
import sys
import time

import can
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
    Node,
    NodeState,
)
from bus.codec import (
    FaultAck,
    FaultCmd,
    FdirStatus,
    FlightTiming,
    Gyro,
    Heartbeat,
    Sync,
    ThrCmd,
    encode,
)
from bus.dbc import DBC_PATH
from bus.receiver import CLASSES, Receiver
from bus.transport import BusConfig, BusLogger, Port, open_bus
from hil import vcan

# Scaled values are written as raw * scale, so that decoding gives back the same float.
MESSAGES = [
    Sync(321, 64_200),
    Gyro(321, (12_345 * 1e-7, -67_890 * 1e-7, 1_500_000 * 1e-7), 1),
    ThrCmd(321, tuple((20, 0, 3, 17, 9, 0)[i % 6] for i in range(30)), 0b0111, 321),
    FdirStatus(300, DetectedFault.FAIL_TO_FIRE, 12, None, 0b0100, False, 2),
    FaultCmd(9, FaultAction.INJECT, FaultKind.STUCK_ON, 4, 5000 * 1e-4, 200 * 0.01, None),
    FaultAck(9, AckStatus.ACCEPTED, AckReason.NONE, FaultKind.STUCK_ON),
    FlightTiming(321, 4_321 * 1e-6, 0),
    Heartbeat(Node.FLIGHT, NodeState.RUN, 1234, 5, 6),
]
N_FRAMES = sum(len(encode(m)) for m in MESSAGES)
RELAXED = Catalog(tuple(dataclasses.replace(f, deadline_s=3600.0) for f in CATALOG.frames))


@pytest.fixture(scope="module")
def bus_log(tmp_path_factory):
    """A candump log of MESSAGES written by our transport, channel vcan0."""
    path = tmp_path_factory.mktemp("replay") / "original.log"
    port = Port(
        open_bus(BusConfig(interface="virtual", channel="replay_writer")),
        logger=BusLogger(path, channel="vcan0"),
    )
    try:
        for msg in MESSAGES:
            assert port.send(msg) == len(encode(msg))
    finally:
        port.close()
    return path


def log_frames(path) -> list[tuple[int, bytes]]:
    return [(m.arbitration_id, bytes(m.data)) for m in can.LogReader(str(path))]


def assert_frames_match_dbc(frames: list[tuple[int, bytes]]) -> None:
    """cantools, from the DBC alone, decodes the frames to MESSAGES' signal values."""
    db = cantools.database.load_file(str(DBC_PATH))
    expected = [
        (CATALOG.frame(name), values)
        for msg in MESSAGES
        for name, values in msg.to_signals().items()
    ]
    assert [can_id for can_id, _ in frames] == [f.frame_id for f, _ in expected]
    for (can_id, data), (f, values) in zip(frames, expected, strict=True):
        got = db.decode_message(can_id, data, decode_choices=False)
        for name, value in values.items():
            scale = f.signal(name).scale
            assert got[name] == pytest.approx(float(value), abs=scale / 2), (f.name, name)


def receive(port: Port, n_messages: int, limit_s: float = 20.0) -> list:
    """Poll until ``n_messages`` arrived (``limit_s`` only bounds a hang), then drain."""
    got = []
    end = time.monotonic() + limit_s
    while len(got) < n_messages and time.monotonic() < end:
        got += port.poll(0.2)
    return got + port.poll(0.0)


def check_replay(got: list, counts: dict, rx_log, original_log) -> None:
    assert [m for m, _ in got] == MESSAGES
    counts = dict(counts)
    assert counts.pop("kernel_drops", 0) == 0  # SocketCAN reports it; nothing was dropped
    assert counts == {
        **dict.fromkeys(CLASSES, 0),
        "ok": N_FRAMES,
        "lost_frames": 0,
        "tx_frames": 0,
        "tx_errors": 0,
    }
    received = log_frames(rx_log)
    assert received == log_frames(original_log)
    assert_frames_match_dbc(received)


def test_log_written_by_us_decodes_with_cantools(bus_log):
    frames = log_frames(bus_log)
    assert len(frames) == N_FRAMES
    assert_frames_match_dbc(frames)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("", 0))
        return s.getsockname()[1]


def test_replay_with_python_can_player_over_udp_multicast(bus_log, tmp_path):
    group, udp_port = "239.74.163.2", free_udp_port()  # own port: no cross-talk with other runs
    rx_log = tmp_path / "received.log"
    rx = Port(
        open_bus(BusConfig(interface="udp_multicast", channel=group, kwargs={"port": udp_port})),
        Receiver(RELAXED),
        logger=BusLogger(rx_log, channel="udp"),
    )
    try:
        player = subprocess.run(
            [sys.executable, "-m", "can.player", "-i", "udp_multicast", "-c", group,
             "--bus-kwargs", f"port={udp_port}", "--", str(bus_log)],
            capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL,
        )  # fmt: skip
        got = receive(rx, len(MESSAGES))
    finally:
        rx.close()
    assert player.returncode == 0, player.stderr
    check_replay(got, rx.counts(), rx_log, bus_log)


@pytest.mark.vcan
@pytest.mark.skipif(
    not vcan.vcan_present("vcan0"), reason="vcan0 absent; run through `hil vcan exec`"
)
@pytest.mark.skipif(shutil.which("canplayer") is None, reason="can-utils not installed")
def test_replay_with_canplayer_onto_vcan0(bus_log, tmp_path):
    rx_log = tmp_path / "received.log"
    rx = Port(open_bus(BusConfig()), Receiver(RELAXED), logger=BusLogger(rx_log))
    try:
        player = subprocess.run(
            ["canplayer", "-I", str(bus_log)],
            capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL,
        )  # fmt: skip
        got = receive(rx, len(MESSAGES))
    finally:
        rx.close()
    assert player.returncode == 0, player.stderr
    check_replay(got, rx.counts(), rx_log, bus_log)
