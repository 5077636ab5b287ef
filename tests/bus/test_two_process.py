"""Lockstep SYNC/THR_CMD exchange between two endpoints over a real python-can bus.

``virtual``: the echo peer runs in a thread of this process (python-can's in-process bus).
``socketcan``: the echo peer is a separate OS process (``python -m bus.echo_peer``) on vcan0
(run through ``hil vcan exec -- .venv/bin/pytest -m vcan tests/bus``).
No assertion depends on speed: the reply timeout is generous.
"""

import json
import shutil
import subprocess
import sys
import threading
import time

import can
import cantools
import pytest

from bus.catalog import CATALOG
from bus.codec import Frame, Sync, ThrCmd, decode, encode
from bus.dbc import DBC_PATH
from bus.echo_peer import N_THRUSTERS, expected_command, run_lockstep
from bus.protocol import CommandReady, PlantLockstep
from bus.transport import BusConfig, Port, from_can_message, open_bus
from hil import vcan

needs_vcan = [
    pytest.mark.vcan,
    pytest.mark.skipif(
        not vcan.vcan_present("vcan0"), reason="vcan0 absent; run through `hil vcan exec`"
    ),
]

TICKS = 50
CORRUPT_TICK = 25
BAD_SYNC_TICK = 10


class ThreadPeer:
    def __init__(self, cfg):
        self.port = Port(open_bus(cfg))
        self.result = None
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        self.result = run_lockstep(self.port, TICKS, CORRUPT_TICK, idle_s=5.0)

    def start(self):
        self.thread.start()

    def finish(self):
        self.thread.join(30)
        self.port.close()
        return self.result


class ProcessPeer:
    def __init__(self, cfg):
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "bus.echo_peer",
                "--interface",
                cfg.interface,
                "--channel",
                cfg.channel,
                "--ticks",
                str(TICKS),
                "--corrupt-tick",
                str(CORRUPT_TICK),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )

    def start(self):
        line = self.proc.stdout.readline()
        assert line.strip() == "ready", self.proc.stderr.read()

    def finish(self):
        out, err = self.proc.communicate(timeout=30)
        assert self.proc.returncode == 0, err
        return json.loads(out.strip().splitlines()[-1])


@pytest.fixture(params=["virtual", pytest.param("socketcan", marks=needs_vcan)])
def setup(request):
    if request.param == "virtual":
        cfg = BusConfig(interface="virtual", channel="two_process")
        return cfg, ThreadPeer(cfg)
    cfg = BusConfig(interface="socketcan", channel="vcan0")
    return cfg, ProcessPeer(cfg)


def test_lockstep_fifty_ticks(setup):
    cfg, peer = setup
    port = Port(open_bus(cfg))
    peer.start()
    plant = PlantLockstep(N_THRUSTERS, reply_timeout_s=5.0)
    got = []
    try:
        for n in range(TICKS):
            sync = plant.begin_tick(n, port.now_s())
            if n == BAD_SYNC_TICK:  # a corrupted copy first: the peer must count and drop it
                fr = port.protect(sync)[0]
                port.send_frame(
                    Frame(fr.arbitration_id, fr.data[:3] + bytes([fr.data[3] ^ 4]) + fr.data[4:])
                )
                port.protector.counters[CATALOG.frame("SYNC").data_id] = (
                    port.protector.counters[CATALOG.frame("SYNC").data_id] - 1
                ) % 16
            port.send(sync)
            while plant.result is None:
                for msg, rx_s in port.poll(0.1):
                    for ev in plant.on_message(msg, rx_s):
                        if isinstance(ev, CommandReady):
                            got.append(ev.command)
                plant.poll(port.now_s())
            assert not plant.result.safe, f"tick {n}: {plant.result.reason}"
    finally:
        peer_counts = peer.finish()
        port.close()
    for n, cmd in enumerate(got):
        q, mask, seq = expected_command(n)
        assert cmd == ThrCmd(n, q, mask, seq)
    assert len(got) == TICKS
    c = port.counts()
    assert c["ok"] == 5 * TICKS and c["bad_crc"] == 1  # the peer's corrupted THR_CMD frame
    assert c["incomplete_set"] == 0 and c["lost_frames"] == 0
    assert peer_counts["replied"] == TICKS and peer_counts["bad_crc"] == 1
    assert peer_counts["ok"] == TICKS and peer_counts["repeated_counter"] == 0


@needs_vcan[0]
@needs_vcan[1]
@pytest.mark.skipif(shutil.which("cansend") is None, reason="can-utils not installed")
def test_can_utils_interop(tmp_path):
    port = Port(open_bus(BusConfig(interface="socketcan", channel="vcan0")))
    dump = subprocess.Popen(["candump", "-L", "vcan0"], stdout=subprocess.PIPE, text=True)
    try:
        time.sleep(0.3)  # let candump bind before we send (not a speed assertion)
        fr = port.protect(Sync(5, 1000))[0]
        subprocess.run(
            ["cansend", "vcan0", f"{fr.arbitration_id:03X}#{fr.data.hex().upper()}"], check=True
        )
        got = []
        deadline = time.monotonic() + 5
        while not got and time.monotonic() < deadline:
            got = port.poll(0.2)
        assert [m for m, _ in got] == [Sync(5, 1000)]
        cmd = ThrCmd(9, tuple(range(3, 18)) + (20, 0, 3), 0b101, 90)
        port.send(cmd)
        time.sleep(0.3)
    finally:
        dump.terminate()
        out, _ = dump.communicate(timeout=5)
        port.close()
    lines = [ln for ln in out.splitlines() if ln.strip()]
    log = tmp_path / "dump.log"
    log.write_text("\n".join(lines) + "\n")
    frames = [from_can_message(m) for m in can.LogReader(str(log))]
    ids = [fr.arbitration_id for fr in encode(cmd)]
    ours = [f for f in frames if f.arbitration_id in ids]
    assert decode(ours) == cmd
    db = cantools.database.load_file(str(DBC_PATH))
    header = db.decode_message(ours[0].arbitration_id, ours[0].data, decode_choices=False)
    assert (header["tick"], header["manifold_enable"], header["gyro_seq"]) == (9, 5, 90)
