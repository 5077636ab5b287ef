"""The operator's bench for real, as a user drives it from a shell on this machine.

* ``hil up`` in the background (inside user-mode Linux where the kernel has no CAN, which
  is where CI runs it; natively on a kernel with vcan0), ``hil fault inject`` from the host:
  the plant's acknowledgement comes back and the flight's detection is in the summary.
* Ctrl-C (SIGINT to the process group, as a terminal sends it), SIGTERM and ``timeout`` of
  ``hil up`` and ``hil run``, natively (udp_multicast: no CAN needed) and inside user-mode
  Linux: each leaves a whole ``summary.json`` marked interrupted with the ticks done, a
  ``run.rrd`` that ``rerun rrd verify`` reads, no process of the run left, and a folder that
  ``hil report`` accepts.

Each case boots processes (and UML) for real: 15-60 s each. The cases that check which
thruster the flight names run `hil up --mode lockstep`: the plumbing under test is the same
in both modes, and a real-time run on a machine loaded past its cores (late gyro samples,
overruns) may name a gyro fault first, which says nothing about the bench.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil import uml
from hil.config import REPO_ROOT
from tests.udp import private_udp_channel

HIL = [sys.executable, "-m", "hil.cli"]
RERUN = Path(sys.executable).parent / "rerun"
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(uml.in_uml(), reason="drives hil up/run from the host")]


def _uml_ok() -> bool:
    try:
        uml.find_uml_kernel()
    except uml.UmlError:
        return False
    return True


def _udp() -> list[str]:
    group = private_udp_channel("239.74")
    return ["--interface", "udp_multicast", "--channel", group]


def _start(args: list[str], log: Path) -> subprocess.Popen:
    # Own process group: a signal to the group is what a terminal's Ctrl-C does.
    return subprocess.Popen([*HIL, *args], stdout=log.open("w"), stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, start_new_session=True, cwd=REPO_ROOT,
                            env=dict(os.environ, RERUN_ANALYTICS="0"))


def _wait_for(pred, timeout_s: float, what: str, log: Path) -> None:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if pred():
            return
        time.sleep(0.2)
    raise AssertionError(f"{what} not within {timeout_s} s; log:\n{log.read_text()[-3000:]}")


def _ticks(path: Path) -> int:
    try:
        return sum(1 for _ in path.open())
    except OSError:
        return 0


def _left_behind(out: Path) -> list[str]:
    """Processes whose command line names the run folder (nodes, bridge, UML)."""
    left = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if str(out) in cmd and not cmd.startswith(("tmux", "sh -c", "env ")):
            left.append(f"{pid}: {cmd}")  # (the test's own terminal is not the run's)
    return left


def _check_kept(out: Path, proc: subprocess.Popen, log: Path, by: str) -> dict:
    rc = proc.wait(90)
    s = json.loads((out / "summary.json").read_text())
    assert s["interrupted"] is True, log.read_text()[-2000:]
    assert by in s["interrupted_by"]
    recs = [json.loads(x) for x in (out / "plant.jsonl").read_text().splitlines()]
    assert s["ticks"] == len([r for r in recs if not r.get("final")]) > 0  # every tick done
    verify = subprocess.run([str(RERUN), "rrd", "verify", str(out / "run.rrd")],
                            capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr[-2000:]
    assert _left_behind(out) == []
    rep = subprocess.run([*HIL, "report", str(out), "--out", str(out / "report")],
                         capture_output=True, text=True, timeout=300, cwd=REPO_ROOT)
    # 1 / 3: the run did not pass / failed; either way it is in the report, with its ticks.
    assert rep.returncode in (0, 1, 3), rep.stderr
    md = (out / "report" / "report.md").read_text()
    assert f"{s['ticks']} ticks" in md
    s["_rc"] = rc
    return s


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_hil_run_natively_interrupted_keeps_its_result(tmp_path, sig):
    out, log = tmp_path / "run", tmp_path / "log.txt"
    proc = _start(["run", "configs/scenarios/S000-stuck.yaml", "--out", str(out),
                   "--mode", "realtime", *_udp()], log)
    _wait_for(lambda: _ticks(out / "plant.jsonl") > 10, 60, "10 plant ticks", log)
    os.killpg(proc.pid, sig)
    s = _check_kept(out, proc, log, sig.name)
    # A run that did not reach its end is a failed run, whatever its expectations say.
    assert s["_rc"] == 3 and s["verdict"] == "run_failed"
    assert "interrupted before the end (Ctrl-C or a signal)" in s["run_failures"]
    assert s["where"] == "native"


def test_hil_up_natively_under_timeout_keeps_its_result(tmp_path):
    out, log = tmp_path / "up", tmp_path / "log.txt"
    proc = subprocess.Popen(["timeout", "25", *HIL, "up", "--out", str(out), *_udp()],
                            stdout=log.open("w"), stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, cwd=REPO_ROOT,
                            env=dict(os.environ, RERUN_ANALYTICS="0"))
    s = _check_kept(out, proc, log, "SIGTERM")
    assert s["_rc"] == 124  # what `timeout` says when it had to stop the command


@pytest.mark.skipif(not _uml_ok(), reason="user-mode-linux is not installed")
def test_hil_up_by_default_takes_a_fault_from_the_host_and_keeps_the_detection(tmp_path):
    """The issue's case: `hil up`, then `hil fault inject` in another terminal, then Ctrl-C."""
    out, log = tmp_path / "up", tmp_path / "log.txt"
    proc = _start(["up", "--vehicle", "generic", "--mode", "lockstep", "--out", str(out)], log)
    _wait_for(lambda: _ticks(out / "plant.jsonl") > 5
              and (out / "control" / "bridge.json").exists(), 240, "hil up running", log)
    t0 = time.monotonic()
    inj = subprocess.run([*HIL, "fault", "inject", "--thruster", "X+", "--type", "stuck_on",
                          "--run", str(out)], capture_output=True, text=True, timeout=60,
                         cwd=REPO_ROOT)
    took = time.monotonic() - t0
    assert inj.returncode == 0, inj.stderr
    assert inj.stdout.startswith("ok: plant accepted inject stuck_on X+ (request ")
    print(f"hil fault inject to its exit (FAULT_ACK through the run folder): {took:.2f} s")
    bad = subprocess.run([*HIL, "fault", "inject", "--thruster", "X+", "--type", "stuck_on",
                          "--fraction", "1.5", "--run", str(out)], capture_output=True,
                         text=True, timeout=60, cwd=REPO_ROOT)
    assert bad.returncode == 2 and bad.stderr.startswith("error: hil fault: argument --fraction")
    _wait_for(lambda: any(json.loads(x).get("detection") for x in
                          (out / "flight.jsonl").read_text().splitlines()), 60,
              "the flight's detection", log)
    os.killpg(proc.pid, signal.SIGINT)
    s = _check_kept(out, proc, log, "SIGINT")
    kernel_has_can = subprocess.run(["ip", "link", "show", "vcan0"],
                                    capture_output=True).returncode == 0
    assert s["where"] == ("native" if kernel_has_can else "user-mode Linux")
    assert [(f["thruster"], f["type"]) for f in s["faults"]] == [("X+", "stuck_on")]
    first = s["detections"][0]
    assert (first["thruster"], first["type"], first["correct"]) == ("X+", "stuck_on", True)


@pytest.mark.skipif(not _uml_ok(), reason="user-mode-linux is not installed")
def test_hil_run_by_default_sigterm_keeps_its_result(tmp_path):
    out, log = tmp_path / "run", tmp_path / "log.txt"
    proc = _start(["run", "configs/scenarios/S000-stuck.yaml", "--out", str(out),
                   "--mode", "realtime"], log)
    _wait_for(lambda: _ticks(out / "plant.jsonl") > 10, 120, "10 plant ticks", log)
    os.killpg(proc.pid, signal.SIGTERM)
    s = _check_kept(out, proc, log, "SIGTERM")
    assert s["_rc"] == 3 and "interrupted before the end (Ctrl-C or a signal)" in \
        s["run_failures"]


def test_hil_up_web_serves_the_viewer_and_says_where(tmp_path):
    import urllib.request

    out, log = tmp_path / "up", tmp_path / "log.txt"
    proc = _start(["up", "--web", "--out", str(out), *_udp()], log)
    try:
        _wait_for(lambda: "web viewer at http://127.0.0.1:" in log.read_text(), 60,
                  "the viewer's URL", log)
        url = log.read_text().split("web viewer at ")[1].split()[0]
        _wait_for(lambda: _ticks(out / "plant.jsonl") > 3, 60, "ticks", log)
        with urllib.request.urlopen(url.split("?")[0], timeout=10) as page:
            assert page.status == 200 and b"rerun" in page.read().lower()
    finally:
        os.killpg(proc.pid, signal.SIGINT)
    _check_kept(out, proc, log, "SIGINT")


def test_viewer_is_found_beside_python_or_refused_in_one_line(monkeypatch, tmp_path):
    from hil.errors import UsageError
    from hil.live_viewer import find_viewer

    assert find_viewer() == Path(sys.executable).parent / "rerun"
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python"))
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(UsageError) as e:
        find_viewer()
    assert str(e.value) == (f"hil up: --viewer: expected the rerun viewer (the `rerun` "
                            f"executable of rerun-sdk) in {tmp_path} or on PATH, got none: "
                            f"install rerun-sdk (bash scripts/setup.sh) or use --web")


@pytest.mark.skipif(not _uml_ok(), reason="user-mode-linux is not installed")
def test_console_on_hil_up_injects_and_shows_the_detection(tmp_path):
    """`hil up` (user-mode Linux here), `hil console` attached from the host in Textual's
    pilot at 80x24: a stuck-on injected from its fault panel is acknowledged and detected on
    its screen; `hil fault` from a second terminal clears it; Ctrl-C keeps the summary."""
    import asyncio

    from hil.console import _app_classes

    out, log = tmp_path / "up", tmp_path / "log.txt"
    proc = _start(["up", "--vehicle", "generic", "--mode", "lockstep", "--out", str(out)], log)
    try:
        _wait_for(lambda: _ticks(out / "plant.jsonl") > 5
                  and (out / "control" / "bridge.json").exists(), 240, "hil up running", log)
        ConsoleApp, _ = _app_classes()
        app = ConsoleApp(out)

        async def drive() -> tuple[str, str, float]:
            async with app.run_test(size=(80, 24)) as pilot:
                await pilot.pause(0.5)
                await pilot.press("f")
                await pilot.click("#thruster")
                await pilot.press("X", "+")
                t0 = time.monotonic()
                await pilot.click("#inject")
                while not app.acks and time.monotonic() < t0 + 30:
                    await pilot.pause(0.02)
                took = time.monotonic() - t0
                await pilot.press("escape")
                t_end = time.monotonic() + 60
                while not app.model.detections and time.monotonic() < t_end:
                    await pilot.pause(0.2)
                await pilot.pause(0.5)
                app.save_screenshot("console.svg", str(tmp_path))
                return app.acks[0], str(app.query_one("#fdir").render()), took

        ack, fdir_pane, took = asyncio.run(drive())
        assert re.fullmatch(r"ok: plant accepted inject stuck_on X\+ \(request \d+, vehicle "
                            r"generic\)", ack)
        assert "detected stuck_on X+" in fdir_pane, fdir_pane
        assert "faults active: stuck_on X+" in fdir_pane
        ms = sorted(app.render_ms)
        print(f"console: FAULT_ACK {took:.3f} s after Inject; refresh cost per update p50 "
              f"{ms[len(ms) // 2]:.2f} ms, max {ms[-1]:.2f} ms over {len(ms)} updates")
        clr = subprocess.run([*HIL, "fault", "clear", "--run", str(out)], capture_output=True,
                             text=True, timeout=60, cwd=REPO_ROOT)
        assert clr.returncode == 0 and clr.stdout.startswith("ok: plant accepted clear all")
    finally:
        os.killpg(proc.pid, signal.SIGINT)
    s = _check_kept(out, proc, log, "SIGINT")
    assert [(f["thruster"], f["type"]) for f in s["faults"]] == [("X+", "stuck_on")]
    assert s["faults"][0]["clear_t_s"] is not None
    assert s["detections"][0]["thruster"] == "X+" and s["detections"][0]["correct"]


def _tmux(*args: str) -> str:
    return subprocess.run(["tmux", *args], capture_output=True, text=True, timeout=30).stdout


@pytest.mark.skipif(not _uml_ok(), reason="user-mode-linux is not installed")
def test_hil_up_console_in_a_real_80x24_terminal(tmp_path):
    """`hil up --console` in a tmux terminal of 80x24 (user-mode Linux here): the fault panel
    by keyboard injects a stuck-on, the acknowledgement and the detection are read off the
    screen, `hil fault clear` from a second terminal is acknowledged, q stops the run and its
    verdict is printed, the summary kept."""
    out = tmp_path / "up"
    sock = str(tmp_path / "tmux.sock")
    hil = str(REPO_ROOT / ".venv" / "bin" / "hil")
    cmd = (f"cd {REPO_ROOT} && {hil} up --console --mode lockstep --out {out}; echo EXIT=$?; "
           "sleep 30")

    def screen() -> str:
        return _tmux("-S", sock, "capture-pane", "-p", "-t", "op")

    def wait_screen(text: str, timeout_s: float) -> str:
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            s = screen()
            if text in s:
                return s
            time.sleep(0.3)
        raise AssertionError(f"{text!r} not on screen:\n{screen()}")

    _tmux("-S", sock, "new-session", "-d", "-s", "op", "-x", "80", "-y", "24",
          "env", "TERM=xterm-256color", "RERUN_ANALYTICS=0", "sh", "-c", cmd)
    try:
        wait_screen("vehicle generic", 240)
        t_end = time.monotonic() + 60
        while not (out / "control" / "bridge.json").exists():
            assert time.monotonic() < t_end
            time.sleep(0.3)
        _tmux("-S", sock, "send-keys", "-t", "op", "f")
        wait_screen("FAULT PANEL", 10)
        _tmux("-S", sock, "send-keys", "-t", "op", "X+")
        # thruster -> type -> fraction -> at -> Inject
        for _ in range(4):
            _tmux("-S", sock, "send-keys", "-t", "op", "Tab")
            time.sleep(0.2)
        _tmux("-S", sock, "send-keys", "-t", "op", "Enter")
        ack = wait_screen("ok: plant accepted inject stuck_on X+", 30)
        assert "vehicle generic" in ack
        _tmux("-S", sock, "send-keys", "-t", "op", "Escape")
        wait_screen("detected stuck_on X+", 60)
        clr = subprocess.run([*HIL, "fault", "clear", "--run", str(out)], capture_output=True,
                             text=True, timeout=60, cwd=REPO_ROOT)
        assert clr.stdout.startswith("ok: plant accepted clear all"), clr.stderr
        _tmux("-S", sock, "send-keys", "-t", "op", "q")
        end = wait_screen("EXIT=", 120)
        assert "EXIT=0" in end and "detection: stuck_on X+" in end, end
    finally:
        _tmux("-S", sock, "kill-server")
    s = json.loads((out / "summary.json").read_text())
    assert s["interrupted"] is True
    assert s["detections"][0]["thruster"] == "X+" and s["detections"][0]["correct"]
    assert _left_behind(out) == []
