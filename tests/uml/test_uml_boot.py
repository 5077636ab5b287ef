"""Boot user-mode Linux for real (a few seconds each). Skipped where it is not installed."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from hil import uml

HIL = [sys.executable, "-m", "hil.cli"]


def _uml_available() -> bool:
    try:
        uml.find_uml_kernel()
    except uml.UmlError:
        return False
    return True


pytestmark = [
    pytest.mark.skipif(not _uml_available(), reason="user-mode-linux is not installed"),
    pytest.mark.skipif(uml.in_uml(), reason="already inside user-mode Linux"),
]


def hil(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([*HIL, *args], capture_output=True, text=True,
                          stdin=subprocess.DEVNULL, timeout=120, **kw)


def test_exit_status_and_output_come_back_without_kernel_noise():
    res = hil("uml", "--", "sh", "-c",
              "echo out-text; echo err-text >&2; printf no-newline; exit 7")
    assert res.returncode == 7, res.stderr
    assert res.stdout == "out-text\nno-newline"
    assert res.stderr == "err-text\n"


def test_runs_in_the_callers_folder_with_its_environment(tmp_path):
    folder = tmp_path / "a folder with 'quotes'"
    folder.mkdir()
    (folder / "input.txt").write_text("from the host\n")
    out = io.BytesIO()
    env = {"PATH": os.environ["PATH"], "HIL_TEST_VALUE": "x y \"z\" $HOME"}
    code = (
        "import os, socket, pathlib;"
        "print(os.getcwd());"
        "print(os.environ['HIL_TEST_VALUE']);"
        "print(os.environ['HIL_UML']);"
        "print(pathlib.Path('input.txt').read_text(), end='');"
        "pathlib.Path('output.txt').write_text('from UML');"
        "print(socket.if_nametoindex('vcan0') > 0)"
    )
    rc = uml.run_in_uml([sys.executable, "-c", code], cwd=folder, env=env, stdout=out,
                        stderr=io.BytesIO())
    assert rc == 0
    assert out.getvalue().decode().splitlines() == [
        str(folder), env["HIL_TEST_VALUE"], "1", "from the host", "True"]
    assert (folder / "output.txt").read_text() == "from UML"


def test_two_runs_at_once_do_not_collide_one_with_stdin_closed():
    closed = ["sh", "-c", 'exec "$@" <&-', "sh"]
    runs = [[*closed, *HIL, "uml", "--", "sh", "-c", "sleep 1; echo run3; exit 3"],
            [*HIL, "uml", "--", "no-such-command-hil"]]
    procs = [subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              stdin=subprocess.DEVNULL, text=True) for argv in runs]
    (out3, err3), (out127, err127) = (p.communicate(timeout=120) for p in procs)
    assert (procs[0].returncode, out3) == (3, "run3\n"), err3
    assert (procs[1].returncode, out127) == (127, ""), err127
    assert "no-such-command-hil" in err127


def _uml_processes(parent_pid: int) -> list[int]:
    """linux.uml processes (with their guard and helpers) started by process ``parent_pid``."""
    mark = f"umid=hil-{parent_pid}-".encode()
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if mark in (d / "cmdline").read_bytes():
                    pids.append(int(d.name))
            except OSError:
                pass
    return pids


def test_timeout_stops_the_run_and_leaves_nothing_behind():
    t0 = time.monotonic()
    with pytest.raises(uml.UmlError, match=r"timed out after 6 s \("):
        uml.run_in_uml(["sleep", "60"], timeout_s=6, stdout=io.BytesIO(), stderr=io.BytesIO())
    assert time.monotonic() - t0 < 20
    time.sleep(0.5)
    assert _uml_processes(os.getpid()) == []


def test_killed_caller_leaves_nothing_behind():
    proc = subprocess.Popen([*HIL, "uml", "--", "sh", "-c", "echo started; sleep 61"],
                            stdout=subprocess.PIPE, stdin=subprocess.DEVNULL,
                            start_new_session=True,
                            env={k: v for k, v in os.environ.items() if k != "HIL_UML_KEEP"})
    try:
        assert proc.stdout.readline() == b"started\n"
        assert _uml_processes(proc.pid)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        deadline = time.monotonic() + 10
        while _uml_processes(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert _uml_processes(proc.pid) == []
        left = [p for p in Path(tempfile.gettempdir()).glob("hil-uml-*/init")
                if "echo started; sleep 61" in p.read_text()]
        assert left == []  # the control folder went too
    finally:
        proc.kill()


def test_setup_failure_names_the_step_and_shows_the_kernel_log(monkeypatch):
    real_plan = uml._module_plan
    monkeypatch.setattr(uml, "_module_plan",
                        lambda k: [*real_plan(k)[:3], ("vcan", "/nonexistent/vcan.ko", True)])
    with pytest.raises(uml.UmlError) as err:
        uml.run_in_uml(["true"], stdout=io.BytesIO(), stderr=io.BytesIO(), timeout_s=60)
    text = str(err.value)
    assert text.startswith("hil uml: set-up inside user-mode Linux failed: insmod vcan\n")
    assert "can't insert '/nonexistent/vcan.ko'" in text
    assert "kernel log (tail):" in text


def test_the_guard_passes_the_status_and_keeps_the_shells_job_report_out(tmp_path):
    """linux.uml dying by SIGABRT at power-off made the guard's shell print "Aborted" on the
    caller's stderr (a CI run under load); the status still comes back, the report does not."""
    from hil.uml import _GUARD

    ctl = tmp_path / "ctl"
    ctl.mkdir()
    res = subprocess.run(["/bin/sh", "-c", _GUARD, "guard", str(ctl), "/bin/sh", "-c",
                          "echo child-err >&2; kill -ABRT $$"],
                         capture_output=True, text=True, timeout=30)
    assert res.returncode == 128 + 6
    assert res.stderr == "child-err\n"
