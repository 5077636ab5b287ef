"""Issue 17 over a real vcan0: a process that dies during `hil run` makes a failed run.

Before, SIGKILL of the plant at 13.8 s of a 40 s run gave ``expectations_met: true`` and exit
0. Here the test itself kills a node (the supervisor does not know it is coming) and asserts
the failed-run exit code (3), the verdict and the reason in ``summary.json``.
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

pytestmark = pytest.mark.vcan
HIL = [sys.executable, "-m", "hil.cli"]


def _kill_mid_run(tmp_path: Path, node: str, sig: int) -> tuple[int, dict, str]:
    scen = tmp_path / "long.yaml"
    scen.write_text("name: long\nvehicle: generic\nduration_s: 120.0\nseed: 3\n"
                    "initial: {attitude: {axis: [1, 0, 0], angle_deg: 10.0}}\n"
                    "expect: {no_false_alarm: true}\n")
    out = tmp_path / "out"
    proc = subprocess.Popen([*HIL, "run", str(scen), "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        t_end = time.monotonic() + 120
        records = out / "plant.jsonl"
        while time.monotonic() < t_end:  # some ticks done, far from the end (600 ticks)
            if records.exists() and records.read_text().count("\n") >= 40:
                break
            assert proc.poll() is None, proc.stdout.read()
            time.sleep(0.05)
        os.kill(int((out / f"{node}.ready").read_text()), sig)
        stdout, _ = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, json.loads((out / "summary.json").read_text()), stdout


def test_a_plant_sigkill_gives_the_failed_run_exit_code(tmp_path) -> None:
    rc, s, stdout = _kill_mid_run(tmp_path, "plant", signal.SIGKILL)
    assert rc == 3, stdout[-2000:]
    assert s["verdict"] == "run_failed" and s["expectations_met"] is False
    assert "plant process died (signal 9); see plant.log" in s["run_failures"]
    assert any(r.startswith("stopped early: the plant ran ") for r in s["run_failures"])
    assert s["ticks"] < 600
    assert "RUN FAILED: plant process died (signal 9)" in stdout


def test_a_flight_crash_gives_the_failed_run_exit_code(tmp_path) -> None:
    # SIGSEGV: what a crash of the flight process looks like from outside.
    rc, s, stdout = _kill_mid_run(tmp_path, "flight", signal.SIGSEGV)
    assert rc == 3, stdout[-2000:]
    assert s["verdict"] == "run_failed"
    assert any(r.startswith("flight process died (") for r in s["run_failures"]), s
    assert any(r.startswith("the flight stopped at tick ") for r in s["run_failures"])
