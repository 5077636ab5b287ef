"""`hil run` and `hil up` on the command line, before anything starts: usage and config errors
(the scenario's ``safety:`` block included) exit 2 with one line, before user-mode Linux boots
or a process starts; and ``--rt`` (SCHED_FIFO and locked memory, plant below flight) reaches
the nodes, which say plainly what was granted or refused.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import subprocess
import sys
import time
from dataclasses import replace

import pytest

import hil.run
from hil import node_settings, node_shell, process_policy
from hil.cli import main


@pytest.fixture
def no_start(monkeypatch):
    """Booting user-mode Linux or starting the processes fails the test."""
    def boom(*_a, **_k):
        raise AssertionError("started although the command line or the scenario is bad")

    monkeypatch.setattr(hil.run, "maybe_in_uml", boom)
    monkeypatch.setattr(hil.run, "supervise", boom)


def _scenario(tmp_path, body: str):
    p = tmp_path / "s.yaml"
    p.write_text("name: s\nvehicle: generic\n" + body)
    return p


@pytest.mark.parametrize(("body", "message"), [
    ("duration_s: -1\n", "duration_s: expected > 0, got -1"),
    ("duration_s: 5\nsafety: {gyro_lost_ticks: 0}\n",
     "safety.gyro_lost_ticks: expected >= 1, got 0"),
    ("duration_s: 5\nsafety: {thr_cmd_lost_ticks: 2.5}\n",
     "safety.thr_cmd_lost_ticks: expected an integer, got 2.5"),
    ("duration_s: 5\nsafety: {heartbeat_lost_s: 0.2}\n",
     "safety.heartbeat_lost_s: expected > the heartbeat period 0.5 s, got 0.2"),
    ("duration_s: 5\nsafety: {gyro_lost: 3}\n",
     "safety.gyro_lost: expected no such field (unknown key), got 3"),
    ("duration_s: 5\nfaults: [{kind: stuck_on, thruster: Q, t_s: 1}]\n",
     "faults[0].thruster: expected a thruster of vehicle generic, got 'Q'"),
])
def test_run_with_a_bad_scenario_field_exits_2_before_starting(tmp_path, capsys, no_start,
                                                                body, message) -> None:
    path = _scenario(tmp_path, body)
    assert main(["run", str(path)]) == 2
    assert capsys.readouterr().err == f"error: {path}: {message}\n"


def test_run_with_a_missing_scenario_exits_2_before_starting(tmp_path, capsys,
                                                              no_start) -> None:
    missing = tmp_path / "nope.yaml"
    assert main(["run", str(missing)]) == 2
    assert capsys.readouterr().err == (f"error: {missing}: expected an existing file, "
                                       f"got no such file\n")


@pytest.mark.parametrize("argv", [
    ["run"],                                             # no scenario
    ["run", "x.yaml", "--mode", "fast"],
    ["up", "--mode", "fast"],
    ["run", "x.yaml", "--kill-flight-at", "soon"],
])
def test_usage_errors_exit_2(capsys, no_start, argv) -> None:
    assert main(argv) == 2  # argparse's SystemExit(2) becomes the exit code
    assert "error: " in capsys.readouterr().err


def test_up_with_an_unknown_vehicle_exits_2_before_starting(capsys, no_start) -> None:
    assert main(["up", "--vehicle", "nope"]) == 2
    assert capsys.readouterr().err.startswith("error: hil up: --vehicle: expected one of [")


def test_the_real_command_exits_2_at_once(tmp_path) -> None:
    """The installed entry point, as a user runs it: exit 2, one line, no boot (fast)."""
    path = _scenario(tmp_path, "duration_s: 5\nsafety: {gyro_lost_ticks: 0}\n")
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "hil.cli", "run", str(path)],
                       capture_output=True, text=True, timeout=60,
                       env={k: v for k, v in os.environ.items() if k != "HIL_INSIDE_UML"})
    assert r.returncode == 2, r.stdout + r.stderr
    assert r.stderr == f"error: {path}: safety.gyro_lost_ticks: expected >= 1, got 0\n"
    assert "user-mode Linux" not in r.stdout and time.monotonic() - t0 < 30


# ----------------------------------------------------------------------------- --rt


def test_rt_reaches_the_node_command_lines(tmp_path) -> None:
    args = argparse.Namespace(mode="realtime", interface="socketcan", channel="vcan0",
                              rt_priority=True)
    for node in ("flight", "plant"):
        cmd = hil.run._node_cmd(node, tmp_path / "s.yaml", tmp_path, args)
        assert cmd[-1] == "--rt-priority"
        assert node_settings.parse_settings(cmd[3:]).rt_priority  # after `-m hil.nodes`


@pytest.mark.parametrize(("note", "event"), [
    ("SCHED_FIFO 50, memory locked", "--rt: SCHED_FIFO 50, memory locked"),
    ("SCHED_FIFO 40, memory not locked (errno 12)",
     "--rt partly refused: SCHED_FIFO 40, memory not locked (errno 12)"),
    ("SCHED_OTHER, SCHED_FIFO refused (PermissionError: Operation not permitted), "
     "memory not locked (errno 1)",
     "--rt refused: SCHED_OTHER, SCHED_FIFO refused (PermissionError: Operation not "
     "permitted), memory not locked (errno 1)"),
])
def test_the_rt_event_says_what_was_refused(note, event) -> None:
    assert process_policy.realtime_event(note) == event


def test_a_refused_sched_fifo_is_said(monkeypatch) -> None:
    def refuse(*_a):
        raise PermissionError(1, "Operation not permitted")

    class _Libc:  # never lock this test process's memory for real
        @staticmethod
        def mlockall(flags: int) -> int:
            asked.append(("mlockall", flags))
            return -1

    asked: list[tuple] = []
    monkeypatch.setattr(process_policy.os, "sched_setscheduler",
                        lambda *a: asked.append(a) or refuse())
    monkeypatch.setattr(ctypes, "CDLL", lambda *a, **k: _Libc())
    monkeypatch.setattr(ctypes, "get_errno", lambda: 1)
    note = process_policy.try_realtime_priority("plant")
    assert asked[0][1] == os.SCHED_FIFO and asked[0][2].sched_priority == 40
    assert asked[1] == ("mlockall", 3)  # MCL_CURRENT | MCL_FUTURE
    assert note.endswith(", SCHED_FIFO refused (PermissionError: Operation not permitted), "
                         "memory not locked (errno 1)")
    assert process_policy.realtime_event(note).startswith("--rt refused: ")
    assert process_policy.RT_PRIORITY["flight"] > process_policy.RT_PRIORITY["plant"]


def test_the_rt_event_is_in_the_first_record(tmp_path) -> None:
    from hil.config import load_scenario

    scen = _scenario(tmp_path, "duration_s: 5\n")
    args = node_settings.parse_settings(
        ["flight", "--scenario", str(scen), "--out", str(tmp_path), "--interface", "virtual",
         "--channel", "rt-first-record", "--rt-priority"])
    note = "SCHED_OTHER, SCHED_FIFO refused (PermissionError: x), memory locked"
    args = replace(args, sched_note=note, rt_event=process_policy.realtime_event(note))
    first = node_shell.first_record(load_scenario(scen), args, {"gyro_lost_ticks": 3})
    assert first["sched"] == args.sched_note
    assert first["events"] == ["--rt partly refused: " + args.sched_note]
    assert first["config"]["vehicle"] == "generic"
    assert first["config"]["bus"] == "virtual rt-first-record"


def test_start_after_waits_for_the_file_or_a_stop(tmp_path) -> None:
    from hil.nodes import wait_for_file

    flag = tmp_path / "flight.ready"
    stops = iter([False, False, True])
    assert not wait_for_file(flag, lambda: next(stops), poll_s=0.0)
    flag.write_text("1")
    assert wait_for_file(flag, lambda: True)  # present: no wait, whatever the stop flag says
    args = argparse.Namespace(mode="lockstep", interface="virtual", channel="x",
                              rt_priority=False)
    cmd = hil.run._node_cmd("plant", tmp_path / "s.yaml", tmp_path, args, start_after=flag)
    assert node_settings.parse_settings(cmd[3:]).start_after == str(flag)


def test_the_speed_figure_leaves_start_up_out() -> None:
    # Oracle: hand arithmetic. 240 s simulated, the plant's loop took 10 s from its first tick
    # (at monotonic 103 s); the supervisor started at 100 s and the whole run took 16 s.
    recs = [{"tick": 0, "t_s": 0.2}, {"tick": 1200, "t_s": 240.0, "final": True,
                                       "wall_s": 10.0, "loop_t0_monotonic_s": 103.0}]
    f = hil.run.speed_figures(recs, 240.0, 16.0, 100.0)
    assert f["speed_x_realtime"] == 24.0 and f["loop_wall_s"] == 10.0
    assert f["startup_s"] == 3.0 and f["end_to_end_x_realtime"] == 15.0
    assert "start-up" in f["speed_basis"] and "excluded" in f["speed_basis"]
