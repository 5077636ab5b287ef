"""`hil fault` against a running plant, in one process: the plant shell (``hil.plant_shell``) on
python-can's ``virtual`` bus answers FAULT_CMD with FAULT_ACK from a thread and writes its
records into a run folder, as ``hil up`` does; the panel learns the vehicle from that folder.
"""

from __future__ import annotations

import json
import re
import threading
import time
import uuid
from pathlib import Path

import pytest

from bus.codec import FaultCmd
from hil.cli import main
from hil.config import load_scenario
from hil.node_settings import parse_settings
from hil.node_shell import open_port
from hil.panel import active_faults
from hil.plant_shell import PlantShell


class _RunningPlant:
    """An orel plant shell serving the panel until closed; one record per handled command."""

    def __init__(self, tmp_path: Path) -> None:
        self.channel = f"panel-{uuid.uuid4().hex[:12]}"
        self.run = tmp_path / "up"
        self.run.mkdir()
        scen = tmp_path / "up.yaml"
        scen.write_text("name: up-orel\nvehicle: orel\nduration_s: 60.0\n")
        args = parse_settings(
            ["plant", "--scenario", str(scen), "--out", str(self.run), "--mode", "realtime",
             "--interface", "virtual", "--channel", self.channel])
        self.shell = PlantShell(load_scenario(scen), open_port(args, self.run, "plant"),
                                self.run, args)
        self.tick = 0
        self.shell.record(self.tick)  # the first record: config (vehicle) for the panel
        self._halt = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._halt.is_set():
            for msg, _ in self.shell.port.poll(0.02):
                if isinstance(msg, FaultCmd):
                    self.shell.on_fault_cmd(msg)
                    self.shell.record(self.tick + 1)
                    self.tick += 1  # after the record: settle() waits on it

    def settle(self, commands: int, timeout_s: float = 5.0) -> None:
        """Wait until the record after the ``commands``-th command is written (the ACK goes
        out before it, so the panel can be faster than the record)."""
        t_end = time.monotonic() + timeout_s
        while self.tick < commands and time.monotonic() < t_end:
            time.sleep(0.01)
        assert self.tick >= commands

    def stop_serving(self) -> None:
        self._halt.set()
        self._thread.join(5)

    def close(self) -> None:
        self.stop_serving()
        self.shell.rec.close()
        self.shell.port.close()

    def fault(self, *args: str) -> list[str]:
        return ["fault", *args, "--run", str(self.run), "--interface", "virtual",
                "--channel", self.channel, "--timeout", "3"]


@pytest.fixture
def plant(tmp_path):
    p = _RunningPlant(tmp_path)
    yield p
    p.close()


def test_inject_list_clear_list_with_the_vehicle_learned_from_the_run(plant, capsys) -> None:
    # No --vehicle: orel's names are accepted, the generic craft's are not.
    assert main(plant.fault("inject", "--thruster", "X+", "--type", "stuck_on")) == 2
    assert "fault: --thruster: expected one of ['1', '2'," in capsys.readouterr().err
    assert main(plant.fault("inject", "--thruster", "17", "--type", "degraded",
                            "--fraction", "0.4")) == 0
    assert re.fullmatch(r"ok: plant accepted inject degraded 17 \(request \d+, vehicle orel\)\n",
                        capsys.readouterr().out)

    plant.settle(1)
    assert main(plant.fault("list")) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"vehicle orel (the plant in {plant.run}): thrusters " + ", ".join(
        str(k) for k in range(1, 31))
    assert out[1:] == [f"faults active at plant time 0.0 s in {plant.run}:",
                       "thruster  type      fraction  from [s]  until [s]",
                       "17        degraded  0.4       0.00      -"]

    assert main(plant.fault("clear", "--thruster", "17")) == 0
    assert re.fullmatch(r"ok: plant accepted clear 17 \(request \d+, vehicle orel\)\n",
                        capsys.readouterr().out)
    plant.settle(2)
    assert main(plant.fault("list")) == 0
    assert capsys.readouterr().out.splitlines()[1:] == [
        f"no fault active in the run at {plant.run} (plant time 0.0 s)"]

    # Nothing left to clear: the plant rejects it and the panel exits 1.
    assert main(plant.fault("clear")) == 1
    assert re.fullmatch(r"error: plant rejected clear all \(request \d+\): not_active\n",
                        capsys.readouterr().out)


def _records(plant: _RunningPlant) -> list[dict]:
    return [json.loads(x) for x in (plant.run / "plant.jsonl").read_text().splitlines()]


def test_clear_every_fault_and_the_records_say_when(plant, capsys) -> None:
    for thr in ("3", "4"):
        assert main(plant.fault("inject", "--thruster", thr, "--type", "fail_to_fire")) == 0
    assert main(plant.fault("clear")) == 0
    assert capsys.readouterr().out.splitlines()[-1].startswith(
        "ok: plant accepted clear all (request ")
    plant.settle(3)
    recs = _records(plant)
    cleared = [c for r in recs for c in r.get("faults_cleared", [])]
    assert [(c["thruster"], c["type"]) for c in cleared] == [("3", "fail_to_fire"),
                                                             ("4", "fail_to_fire")]
    assert any("fault cleared: all (request" in e for r in recs for e in r["events"])
    assert active_faults(recs) == ([], 0.0)


def test_active_faults_leaves_out_ended_ones() -> None:
    recs = [
        {"t_s": 0.0, "faults_injected": [
            {"t_s": 0.0, "thruster": "A", "type": "stuck_on", "clear_t_s": 2.0},
            {"t_s": 0.0, "thruster": "B", "type": "stuck_on", "clear_t_s": None},
            {"t_s": 0.0, "thruster": "C", "type": "degraded", "clear_t_s": None}]},
        {"t_s": 1.0, "faults_cleared": [
            {"thruster": "B", "type": "stuck_on", "t_on_s": 0.0, "t_s": 1.0}]},
        {"t_s": 3.0},
    ]
    active, now = active_faults(recs)
    assert now == 3.0 and [f["thruster"] for f in active] == ["C"]
    assert active_faults(recs[:1])[0][0]["thruster"] == "A"
    assert active_faults([]) == ([], None)


def test_a_repeated_request_is_acknowledged_again_and_applied_once(plant) -> None:
    from bus.codec import FaultAck
    from bus.transport import BusConfig, Port, open_bus
    from hil.panel import build_command

    plant.stop_serving()  # drive the shell by hand
    listener = Port(open_bus(BusConfig(interface="virtual", channel=plant.channel)))
    try:
        cmd = build_command("orel", "inject", "5", "stuck_on", None, None, None, 77)
        plant.shell.on_fault_cmd(cmd)
        plant.shell.on_fault_cmd(cmd)
        acks = [m for m, _ in listener.poll(0.1) if isinstance(m, FaultAck)]
    finally:
        listener.close()
    assert [(a.request_id, a.status.name) for a in acks] == [(77, "ACCEPTED")] * 2
    assert len(plant.shell.plant.faults.entries) == 1
    assert plant.shell.events[-1] == ("FAULT_CMD request 77 repeated: acknowledged again, "
                                      "not applied again")
