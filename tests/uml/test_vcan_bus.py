"""Real SocketCAN over vcan0: run through `hil vcan exec -- .venv/bin/pytest -m vcan tests/uml`.

Natively where the kernel has CAN, otherwise inside user-mode Linux; the code path is the
same (python-can's socketcan interface). Skipped when vcan0 is absent.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import time

import pytest

from hil import vcan

can = pytest.importorskip("can")

pytestmark = [
    pytest.mark.vcan,
    pytest.mark.skipif(not vcan.vcan_present("vcan0"),
                       reason="vcan0 absent; run through `hil vcan exec`"),
]
needs_can_utils = pytest.mark.skipif(
    not (shutil.which("cansend") and shutil.which("candump")),
    reason="can-utils is not installed")

RECEIVER = r"""
import sys, can
bus = can.Bus(interface="socketcan", channel="vcan0",
              can_filters=[{"can_id": 0x2A5, "can_mask": 0x7FF, "extended": False}])
print("ready", flush=True)
msg = bus.recv(timeout=20)
print("none" if msg is None else f"{msg.arbitration_id:03X}#{msg.data.hex().upper()}", flush=True)
bus.shutdown()
"""


def test_vcan0_exists_is_up_and_takes_can_fd():
    assert vcan.vcan_present("vcan0")
    assert vcan.vcan_up("vcan0")
    assert vcan.vcan_mtu("vcan0") == 72


def test_frame_from_python_can_reaches_another_process():
    rx = subprocess.Popen([sys.executable, "-c", RECEIVER], stdout=subprocess.PIPE, text=True)
    try:
        assert rx.stdout.readline().strip() == "ready"
        with can.Bus(interface="socketcan", channel="vcan0") as bus:
            bus.send(can.Message(arbitration_id=0x2A4, data=b"\x00", is_extended_id=False))
            bus.send(can.Message(arbitration_id=0x2A5, data=b"\x01\x02\x03",
                                 is_extended_id=False))
        out, _ = rx.communicate(timeout=30)
    finally:
        rx.kill()
    assert out.strip() == "2A5#010203"


@needs_can_utils
def test_cansend_frame_is_received_by_python_can():
    with can.Bus(interface="socketcan", channel="vcan0",
                 can_filters=[{"can_id": 0x123, "can_mask": 0x7FF, "extended": False}]) as bus:
        subprocess.run(["cansend", "vcan0", "123#DEADBEEF"], check=True, timeout=10)
        msg = bus.recv(timeout=10)
    assert msg is not None
    assert (msg.arbitration_id, bytes(msg.data), msg.is_extended_id) == (
        0x123, b"\xde\xad\xbe\xef", False)


@needs_can_utils
def test_python_can_frame_appears_in_candump():
    dump = subprocess.Popen(["candump", "-n", "1", "vcan0,321:7FF"], stdout=subprocess.PIPE,
                            text=True)
    try:
        # candump says nothing when it is listening: send until it has seen one frame.
        with can.Bus(interface="socketcan", channel="vcan0") as bus:
            deadline = time.monotonic() + 20
            while dump.poll() is None and time.monotonic() < deadline:
                bus.send(can.Message(arbitration_id=0x321, data=b"\x01\x02\x03\x04",
                                     is_extended_id=False))
                time.sleep(0.05)
        out, _ = dump.communicate(timeout=5)
    finally:
        dump.kill()
    assert re.search(r"vcan0\s+321\s+\[4\]\s+01 02 03 04", out), out


def test_can_fd_frame_round_trips():
    with can.Bus(interface="socketcan", channel="vcan0", fd=True) as a, \
            can.Bus(interface="socketcan", channel="vcan0", fd=True) as b:
        a.send(can.Message(arbitration_id=0x7E0, data=bytes(range(64)), is_fd=True,
                           bitrate_switch=True, is_extended_id=False))
        msg = b.recv(timeout=5)
    assert msg is not None and msg.is_fd and bytes(msg.data) == bytes(range(64))
