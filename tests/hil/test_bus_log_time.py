"""``bus.log`` as other tools read it: frames heard by the monitor are received (``R``), and a
lockstep log is in simulated time, so its span is the run's simulated duration.

Oracles: python-can's ``LogReader`` (what ``can.player`` and ``cantools plot`` read), the SYNC
frames' own ``sim_time_ms``, the scenario's duration; the README's replay commands run as
written onto vcan0 (marker ``vcan``).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
import uuid
from pathlib import Path

import can
import pytest

from bus.catalog import AckStatus
from bus.codec import FaultAck, Gyro, Sync
from bus.transport import BusConfig, Port, open_bus
from hil.config import REPO_ROOT, load_scenario
from hil.run import BusMonitor
from tests.udp import private_udp_channel

README = REPO_ROOT / "README.md"


def _monitored(tmp_path: Path, sim_time: bool, interface: str = "virtual",
               channel: str | None = None) -> list[can.Message]:
    chan = channel or f"mon-{uuid.uuid4().hex[:10]}"
    path = tmp_path / "bus.log"
    mon = BusMonitor(interface, chan, path, sim_time=sim_time)
    mon.start()
    port = Port(open_bus(BusConfig(interface=interface, channel=chan)))
    try:
        for n in range(5):
            port.send(Sync(n, n * 200))
            port.send(Gyro(n, (0.001, -0.002, 0.0), 1))
            port.send(FaultAck(n, AckStatus.ACCEPTED))
        time.sleep(0.3)
    finally:
        port.close()
        mon.stop()
    return list(can.LogReader(str(path)))


def test_lockstep_stamps_are_simulated_time_from_the_syncs_and_every_frame_is_received(
        tmp_path):
    msgs = _monitored(tmp_path, sim_time=True)
    assert msgs and all(m.is_rx for m in msgs)
    stamps = [m.timestamp for m in msgs]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
    # Each SYNC carries tick n at n * 200 ms; the frames after it are 1 us apart.
    syncs = [m for m in msgs if m.arbitration_id == msgs[0].arbitration_id]
    assert [round(m.timestamp, 6) for m in syncs] == [0.0, 0.2, 0.4, 0.6, 0.8]
    after_last_sync = len(msgs) - 1 - msgs.index(syncs[-1])
    assert max(stamps) - min(stamps) == pytest.approx(0.8 + after_last_sync * 1e-6, abs=1e-9)


def test_real_time_stamps_stay_the_kernels_and_are_received(tmp_path):
    t0 = time.time()
    msgs = _monitored(tmp_path, sim_time=False)
    assert msgs and all(m.is_rx for m in msgs)
    assert all(t0 - 1 < m.timestamp < time.time() + 1 for m in msgs)


@pytest.mark.slow
def test_a_lockstep_run_log_spans_the_simulated_duration(tmp_path):
    """A whole lockstep run between OS processes (udp_multicast: no CAN needed here)."""
    scen = REPO_ROOT / "configs/scenarios/S000-nofire.yaml"
    sc = load_scenario(scen)
    group = private_udp_channel("239.75")
    r = subprocess.run([sys.executable, "-m", "hil.cli", "run", str(scen), "--out",
                        str(tmp_path), "--interface", "udp_multicast", "--channel", group],
                       capture_output=True, text=True, timeout=600, cwd=REPO_ROOT,
                       env=dict(os.environ, RERUN_ANALYTICS="0"))
    assert r.returncode in (0, 1), r.stdout + r.stderr
    msgs = list(can.LogReader(str(tmp_path / "bus.log")))
    tick = sc.vehicle.timing.tick_s
    span = msgs[-1].timestamp - msgs[0].timestamp
    # SYNC(0) at 0 s to the frames of the last tick, which starts one tick before the end.
    assert sc.cfg.duration_s - tick <= span < sc.cfg.duration_s
    assert all(m.is_rx for m in msgs)


def readme_replay_commands() -> list[str]:
    """The replay commands the README gives for bus.log, as written."""
    text = README.read_text()
    cmds = re.findall(r"`((?:canplayer|python -m can\.player)[^`]*bus\.log[^`]*)`", text)
    assert len(cmds) >= 2, cmds
    return cmds


def test_the_readme_names_its_replay_commands():
    cmds = readme_replay_commands()
    assert any(c.startswith("canplayer ") for c in cmds)
    assert any(c.startswith("python -m can.player ") for c in cmds)


@pytest.mark.vcan
def test_the_readme_replay_commands_work_as_written(tmp_path):
    """Each command, in a folder holding a bus.log, replays every frame onto vcan0."""
    from hil import vcan

    vcan.ensure_vcan("vcan0")
    src = _monitored(tmp_path, sim_time=True, interface="socketcan", channel="vcan0")
    for cmd in readme_replay_commands():
        rx = can.Bus(interface="socketcan", channel="vcan0")
        try:
            argv = cmd.split()
            if argv[0] == "python":
                argv[0] = sys.executable
            r = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=60)
            assert r.returncode == 0, f"{cmd}: {r.stderr}"
            got = []
            while (m := rx.recv(0.5)) is not None:
                got.append((m.arbitration_id, bytes(m.data)))
        finally:
            rx.shutdown()
        assert got == [(m.arbitration_id, bytes(m.data)) for m in src], cmd
