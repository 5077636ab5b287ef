"""docs/tutorial.md, followed step by step with its own commands, on this machine (`hil up`
in user-mode Linux where the kernel has no CAN): each ```sh block in order, its output checked
against the ```text block after it; the console step in Textual's pilot (no terminal here);
Ctrl-C as a terminal sends it. Prints how long the whole tutorial took."""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

from hil import uml
from hil.config import REPO_ROOT

TUTORIAL = REPO_ROOT / "docs" / "tutorial.md"
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(uml.in_uml(), reason="the tutorial is followed from the host")]


def steps() -> list[tuple[str, str | None]]:
    """(command, the text block after it or None) in the tutorial's order."""
    blocks = re.findall(r"```(sh|text)\n(.*?)```", TUTORIAL.read_text(), re.S)
    out: list[tuple[str, str | None]] = []
    for kind, body in blocks:
        if kind == "sh":
            out.append((body.strip(), None))
        elif out and out[-1][1] is None:
            out[-1] = (out[-1][0], body.rstrip("\n"))
    return out


def _pattern(expected: str, run: str) -> str:
    """A text block as a pattern: the run folder substituted, numbers that vary (request ids,
    times) free."""
    pat = re.escape(expected.replace("runs/tutorial", run))
    return re.sub(r"(?:\\ )*\d+(?:\\\.\d+)?", lambda m: r"\s*[\d.]+" if m.group(0).startswith(
        "\\ ") else r"[\d.]+", pat)


def test_the_tutorial_as_written(tmp_path):
    t0 = time.monotonic()
    run = str(tmp_path / "tutorial")
    up = None
    up_log = tmp_path / "up.txt"
    done = []
    try:
        for cmd, expected in steps():
            argv = cmd.replace("runs/tutorial", run).split()
            assert argv[0] == ".venv/bin/hil", cmd
            argv[0] = str(REPO_ROOT / ".venv" / "bin" / "hil")
            sub = argv[1]
            if sub == "up":
                up = subprocess.Popen(argv, stdout=up_log.open("w"), stderr=subprocess.STDOUT,
                                      stdin=subprocess.DEVNULL, start_new_session=True,
                                      cwd=REPO_ROOT, env=dict(os.environ, RERUN_ANALYTICS="0"))
                t_end = time.monotonic() + 120
                while not ((Path(run) / "control" / "bridge.json").exists()
                           and (Path(run) / "plant.jsonl").exists()):
                    assert time.monotonic() < t_end, up_log.read_text()
                    assert up.poll() is None, up_log.read_text()
                    time.sleep(0.2)
                time.sleep(1.0)
            elif sub == "console":
                from hil.console import _app_classes

                app_cls, _ = _app_classes()
                app = app_cls(Path(run))

                async def look(app=app) -> str:
                    async with app.run_test(size=(80, 24)) as pilot:
                        await pilot.pause(0.5)
                        return str(app.query_one("#head").render())

                assert "vehicle generic" in asyncio.run(look())
            elif sub == "report":
                os.killpg(up.pid, signal.SIGINT)  # step 4: Ctrl-C in the first terminal
                up.wait(90)
                s = json.loads((Path(run) / "summary.json").read_text())
                assert s["interrupted"] is True and s["ticks"] > 0
                r = subprocess.run(argv, capture_output=True, text=True, timeout=300,
                                   cwd=REPO_ROOT)
                assert r.returncode in (0, 1, 3), r.stderr
                md = (Path(run) / "report" / "report.md").read_text()
                assert "- detection: stuck_on X+ at" in md, md
            else:
                r = subprocess.run(argv, capture_output=True, text=True, timeout=60,
                                   cwd=REPO_ROOT)
                text = (r.stdout + r.stderr).rstrip("\n")
                if expected is not None:
                    assert re.fullmatch(_pattern(expected, run), text), (cmd, text, expected)
                assert r.returncode == (2 if text.startswith("error:") else 0), (cmd, text)
                if "inject --thruster X+" in cmd:
                    # Real time, as the tutorial runs it: on a machine loaded past its cores
                    # the detection can take longer (late gyro samples, overruns).
                    t_end = time.monotonic() + 180
                    while "flight: detection: stuck_on of X+" not in up_log.read_text():
                        assert time.monotonic() < t_end, up_log.read_text()[-3000:]
                        time.sleep(0.5)
            done.append(sub)
    finally:
        if up is not None and up.poll() is None:
            os.killpg(up.pid, signal.SIGKILL)
    assert done == ["up", "fault", "console", "fault", "fault", "report"]
    print(f"tutorial followed in {time.monotonic() - t0:.1f} s")
