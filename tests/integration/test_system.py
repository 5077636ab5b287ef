"""The running system over a real vcan0: plant, flight and panel as separate OS processes.

Marked ``vcan``: the test command runs them through ``hil vcan exec`` (natively where the
kernel has CAN, inside user-mode Linux where it has not). No assertion is about speed.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil.config import SCENARIO_DIR

pytestmark = pytest.mark.vcan
HIL = [sys.executable, "-m", "hil.cli"]
WALL_FIELDS = ("wall_s", "speed_x_realtime", "compute_ms", "release_jitter_ms", "bus",
               "bus_frames_logged", "where")


def _run(args: list[str], timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run(HIL + args, capture_output=True, text=True, timeout=timeout)


def _summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def test_lockstep_s000_stuck_detected_and_reproducible(tmp_path) -> None:
    runs = []
    for k in range(2):
        out = tmp_path / f"run{k}"
        r = _run(["run", str(SCENARIO_DIR / "S000-stuck.yaml"), "--out", str(out)])
        assert r.returncode == 0, r.stdout + r.stderr
        s = _summary(out)
        det = [d for d in s["detections"] if d["correct"]]
        assert det and det[0]["thruster"] == "X+" and det[0]["type"] == "stuck_on"
        assert det[0]["latency_s"] <= 4.6 and s["false_alarms"] == []
        assert s["ticks"] == 150 and s["bus"]["flight"]["bad_crc"] == 0
        assert (out / "run.rrd").stat().st_size > 0
        assert (out / "bus.log").read_text().count("vcan0") > 1000  # candump format
        runs.append({k: v for k, v in s.items() if k not in WALL_FIELDS})
        # The flight's view is the same tick by tick (bit for bit), timing fields aside.
        runs[-1]["flight_series"] = [
            {p: v for p, v in json.loads(line)["series"].items() if p != "flight/compute_ms"}
            for line in (out / "flight.jsonl").read_text().splitlines()
        ]
    assert runs[0] == runs[1]


def test_killing_the_flight_puts_the_plant_safe(tmp_path) -> None:
    out = tmp_path / "kill"
    r = _run(["run", str(SCENARIO_DIR / "S000-stuck.yaml"), "--out", str(out),
              "--kill-flight-at", "10"])
    assert r.returncode == 1  # the fault at 18 s can no longer be detected
    plant = [json.loads(x) for x in (out / "plant.jsonl").read_text().splitlines()]
    flight = [json.loads(x) for x in (out / "flight.jsonl").read_text().splitlines()]
    safe_ticks = [p["tick"] for p in plant if p.get("safe")]
    assert safe_ticks, "the plant never went safe"
    last_flight_tick = flight[-1]["tick"]
    # Safe within the configured 3 missed ticks after the flight's last command.
    assert 0 < safe_ticks[0] - last_flight_tick <= 4, safe_ticks[:5]
    assert any("safe: all valves and manifolds closed" in e for p in plant for e in p["events"])
    # The records keep every tick up to the kill.
    assert [f["tick"] for f in flight] == list(range(last_flight_tick + 1))
    # The plant stays safe from then on (nothing brings it back: the flight is dead).
    assert safe_ticks == list(range(safe_ticks[0], plant[-1]["tick"] + 1)), \
        [(p["tick"], p["events"]) for p in plant if p["events"]]
    # After the closure no thruster burns (the stuck-on fault at 18 s included). The decay
    # of the thrust profile is exponential: "no thrust" is below a micronewton.
    burning = [(p["tick"], {k: v for k, v in p["series"]["truth/thrust_n"].items() if v > 1e-6})
               for p in plant if p["tick"] > safe_ticks[0] + 1
               and max(p["series"]["truth/thrust_n"].values()) > 1e-6]
    assert not burning, burning[:5]


def test_realtime_run_reports_jitter_and_compute(tmp_path) -> None:
    scen = tmp_path / "rt.yaml"
    scen.write_text("name: rt\nvehicle: generic\nduration_s: 8.0\n")
    out = tmp_path / "rt"
    r = _run(["run", str(scen), "--mode", "realtime", "--out", str(out)])
    assert r.returncode == 0, r.stdout + r.stderr
    s = _summary(out)
    assert s["mode"] == "realtime" and s["flight_ticks"] >= 30
    for k in ("p50", "p99", "max"):
        assert s["compute_ms"][k] is not None and s["release_jitter_ms"][k] is not None
    assert isinstance(s["overruns"], int)


def test_fault_panel_into_running_system(tmp_path) -> None:
    out = tmp_path / "up"
    up = subprocess.Popen(HIL + ["up", "--vehicle", "generic", "--mode", "realtime",
                                 "--duration", "60", "--out", str(out)],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        t_end = time.monotonic() + 60
        while not (out / "plant.jsonl").exists() or \
                len((out / "plant.jsonl").read_text().splitlines()) < 10:
            assert up.poll() is None and time.monotonic() < t_end
            time.sleep(0.2)
        bad = _run(["fault", "inject", "--thruster", "X9", "--type", "stuck_on"])
        assert bad.returncode == 2 and "expected one of" in bad.stderr
        ok = _run(["fault", "inject", "--thruster", "X+", "--type", "stuck_on"])
        assert ok.returncode == 0 and "accepted" in ok.stdout, ok.stdout + ok.stderr
        found = None
        while found is None and time.monotonic() < t_end:
            for line in (out / "flight.jsonl").read_text().splitlines():
                d = json.loads(line).get("detection")
                if d:
                    found = d
            time.sleep(0.2)
        assert found and found["thruster"] == "X+" and found["type"] == "stuck_on"
    finally:
        up.send_signal(signal.SIGINT)
        up.wait(30)
    assert not [p for p in os.popen("ps -eo args").read().splitlines() if "hil.nodes" in p]
