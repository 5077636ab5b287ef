"""`hil run-all` progress: k/N as the summaries appear, and the time left from the simulated
seconds still to run."""

from __future__ import annotations

import time

from hil import runall
from hil.config import SCENARIO_DIR, load_scenario


def test_progress_counts_fresh_summaries_and_estimates_the_time_left(tmp_path, monkeypatch):
    files = [SCENARIO_DIR / "S000-stuck.yaml", SCENARIO_DIR / "S000-nofire.yaml"]
    d = {p.stem: load_scenario(p).cfg.duration_s for p in files}
    clock = [100.0]
    monkeypatch.setattr(runall.time, "monotonic", lambda: clock[0])
    # A summary left by an earlier run-all in the same folder is not progress.
    (tmp_path / "S000-nofire").mkdir()
    (tmp_path / "S000-nofire" / "summary.json").write_text("{}")
    old = time.time() - 3600
    import os

    os.utime(tmp_path / "S000-nofire" / "summary.json", (old, old))
    prog = runall.Progress(files, tmp_path, t0_wall=100.0)
    assert prog.poll() == []
    clock[0] = 110.0
    (tmp_path / "S000-stuck").mkdir()
    (tmp_path / "S000-stuck" / "summary.json").write_text("{}")
    [line] = prog.poll()
    left = 10.0 * d["S000-nofire"] / d["S000-stuck"]
    assert line == f"run-all: 1/2 done (S000-stuck), 10 s wall, about {left:.0f} s left"
    assert prog.poll() == []
    clock[0] = 120.0
    (tmp_path / "S000-nofire" / "summary.json").write_text("{}")
    assert prog.poll() == ["run-all: 2/2 done (S000-nofire), 20 s wall"]
