"""The panel bridge (``hil.panel_bridge``): `hil fault` through the run folder gives the same
acknowledgement, the same lines and the same exit codes as `hil fault` on the bus.

The plant is the real plant shell on python-can's ``virtual`` bus (``test_panel_running``'s
fixture); the bridge serves the run folder from a thread, on the same bus, as ``hil up`` runs
it beside the plant.
"""

from __future__ import annotations

import json
import os
import re
import threading
import time

import pytest

from bus.catalog import FaultAction, FaultKind
from bus.codec import FaultCmd
from hil import panel_bridge
from hil.cli import main
from hil.errors import BusError
from hil.panel import send_and_wait
from tests.hil.test_panel_running import _RunningPlant


class _Bridge:
    def __init__(self, plant: _RunningPlant) -> None:
        self.halt = threading.Event()
        self.thread = threading.Thread(
            target=panel_bridge.serve, daemon=True,
            args=(plant.run, "virtual", plant.channel, self.halt.is_set, send_and_wait))
        self.thread.start()
        t_end = time.monotonic() + 5
        while panel_bridge.bridge_info(plant.run) is None and time.monotonic() < t_end:
            time.sleep(0.01)

    def close(self) -> None:
        self.halt.set()
        self.thread.join(5)


@pytest.fixture
def plant(tmp_path):
    p = _RunningPlant(tmp_path)
    yield p
    p.close()


def _fault(plant: _RunningPlant, via: str, *args: str) -> list[str]:
    # The bus options point nowhere useful for --via run: the request must not use them.
    bus = ["--interface", "virtual", "--channel",
           plant.channel if via == "bus" else "nobody-listens-here"]
    return ["fault", *args, "--run", str(plant.run), "--via", via, *bus, "--timeout", "3"]


def _norm(text: str) -> str:
    return re.sub(r"request \d+", "request N", text)


def test_same_lines_and_exit_codes_through_the_run_folder_as_on_the_bus(plant, capsys):
    bridge = _Bridge(plant)
    try:
        info = panel_bridge.bridge_info(plant.run)
        assert info is not None and info["interface"] == "virtual"
        seen = {}
        for via in ("bus", "run"):
            codes = [
                main(_fault(plant, via, "inject", "--thruster", "17", "--type", "degraded",
                            "--fraction", "0.4")),
                main(_fault(plant, via, "clear", "--thruster", "17")),
                main(_fault(plant, via, "clear", "--thruster", "17")),  # nothing active: rejected
                main(_fault(plant, via, "inject", "--thruster", "99", "--type", "stuck_on")),
            ]
            cap = capsys.readouterr()
            seen[via] = (codes, _norm(cap.out), _norm(cap.err))
        assert seen["bus"] == seen["run"]
        codes, out, err = seen["run"]
        assert codes == [0, 0, 1, 2]
        assert out.splitlines() == [
            "ok: plant accepted inject degraded 17 (request N, vehicle orel)",
            "ok: plant accepted clear 17 (request N, vehicle orel)",
            "error: plant rejected clear 17 (request N): not_active"]
        assert "fault: --thruster: expected one of ['1', '2'," in err
        # The plant applied what came through the bridge: its records say so.
        plant.settle(6)
        recs = [json.loads(x) for x in (plant.run / "plant.jsonl").read_text().splitlines()]
        injected = [f for r in recs for f in r.get("faults_injected", [])]
        assert [(f["thruster"], f["type"], f["fraction"]) for f in injected] == \
            [("17", "degraded", 0.4)] * 2
        # The bridge leaves nothing behind but its own heartbeat.
        assert sorted(p.name for p in panel_bridge.control_dir(plant.run).iterdir()) == \
            ["bridge.json"]
    finally:
        bridge.close()
    # Once stopped, it says so: no bridge.json.
    assert not (panel_bridge.control_dir(plant.run) / "bridge.json").exists()


def test_auto_takes_the_bridge_when_one_is_live_else_the_bus(plant, capsys):
    args = ["fault", "inject", "--thruster", "3", "--type", "stuck_on", "--run", str(plant.run),
            "--interface", "virtual", "--channel", "nobody-listens-here", "--timeout", "0.5"]
    assert main(args) == 2  # no bridge: the bus, where nobody answers
    assert "no FAULT_ACK for request" in capsys.readouterr().err
    bridge = _Bridge(plant)
    try:
        # The bridge is on the plant's bus; the panel's own bus options are not used.
        assert main(args) == 0
        assert capsys.readouterr().out.startswith("ok: plant accepted inject stuck_on 3 ")
    finally:
        bridge.close()


def test_a_bridge_that_is_gone_or_silent_is_a_one_line_error(tmp_path):
    cmd = FaultCmd(7, FaultAction.INJECT, FaultKind.STUCK_ON, 0, 1.0, 0.0, None)
    with pytest.raises(BusError, match=r"^fault: no panel bridge serving .* is `hil up --out"):
        panel_bridge.send_via_run(cmd, tmp_path, 0.2)
    # A heartbeat older than STALE_S: the bridge stopped without removing it (killed).
    d = panel_bridge.control_dir(tmp_path)
    d.mkdir()
    (d / "bridge.json").write_text("{}")
    old = time.time() - panel_bridge.STALE_S - 1
    os.utime(d / "bridge.json", (old, old))
    assert panel_bridge.bridge_info(tmp_path) is None
    # Fresh but nobody serving: the request is not taken, and the panel says so.
    os.utime(d / "bridge.json")
    with pytest.raises(BusError, match=r"^fault: no FAULT_ACK for request 7 within 0.1 s: the "
                                       r"panel bridge of .* did not take the request"):
        panel_bridge.send_via_run(cmd, tmp_path, 0.1)
    assert [p.name for p in d.iterdir()] == ["bridge.json"]  # its request was taken back


def test_a_bad_request_file_is_answered_not_fatal(tmp_path):
    halt = threading.Event()
    t = threading.Thread(target=panel_bridge.serve, daemon=True,
                         args=(tmp_path, "virtual", "bridge-bad-req", halt.is_set,
                               send_and_wait))
    t.start()
    try:
        d = panel_bridge.control_dir(tmp_path)
        t_end = time.monotonic() + 5
        while panel_bridge.bridge_info(tmp_path) is None and time.monotonic() < t_end:
            time.sleep(0.01)
        (d / "req-x.json").write_text("{not json")
        while not (d / "ack-x.json").exists() and time.monotonic() < t_end:
            time.sleep(0.01)
        answer = json.loads((d / "ack-x.json").read_text())
        assert answer["error"].startswith("fault: request req-x.json: expected a panel request")
        assert t.is_alive()
    finally:
        halt.set()
        t.join(5)


def test_request_round_trip_keeps_every_field():
    cmd = FaultCmd(201, FaultAction.INJECT, FaultKind.DEGRADED, 5, 0.25, 12.5, 30.0)
    assert panel_bridge.cmd_from_json(json.loads(json.dumps(panel_bridge.cmd_to_json(cmd)))) \
        == cmd


def test_an_at_in_the_past_is_warned_with_the_plant_time(plant, capsys):
    with (plant.run / "plant.jsonl").open("a") as f:  # the plant's clock has moved on
        f.write(json.dumps({"tick": 40, "t_s": 8.0, "events": []}) + "\n")
    t_now = 8.0
    assert main(_fault(plant, "bus", "inject", "--thruster", "3", "--type", "stuck_on",
                       "--at", "5")) == 0
    err = capsys.readouterr().err
    assert err == (f"warning: fault: --at 5 s is in the past (plant time {t_now:.1f} s in "
                   f"{plant.run}): the plant applies it at once\n")
    assert main(_fault(plant, "bus", "inject", "--thruster", "3", "--type", "stuck_on",
                       "--at", f"{t_now + 10:g}")) == 0
    assert capsys.readouterr().err == ""
