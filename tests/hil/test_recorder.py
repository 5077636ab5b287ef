"""Recorder: JSON lines survive a torn last line; run.rrd holds both sources on one timeline."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from hil.recorder import JsonlWriter, build_rrd, merge_by_tick, read_jsonl


def _write(path: Path, source: str, n: int) -> None:
    w = JsonlWriter(path)
    for k in range(n):
        w.write({"tick": k, "t_s": 0.2 * k,
                 "series": {f"{source}/omega_deg_s": {"x": float(k), "y": 0.0, "z": -1.0}},
                 "events": [f"{source} event {k}"] if k == 2 else []})
    w.close()


def test_torn_last_line_is_ignored(tmp_path) -> None:
    p = tmp_path / "plant.jsonl"
    _write(p, "truth", 3)
    with p.open("a") as f:
        f.write('{"tick": 3, "t_s"')  # killed mid-write
    assert [r["tick"] for r in read_jsonl(p)] == [0, 1, 2]


def test_merge_orders_by_tick_then_source() -> None:
    a = [{"tick": 0}, {"tick": 1}]
    b = [{"tick": 0}, {"tick": 2}]
    got = [(s, r["tick"]) for s, r in merge_by_tick(("plant", a), ("flight", b))]
    assert got == [("plant", 0), ("flight", 0), ("plant", 1), ("flight", 2)]


def test_build_rrd_contains_both_sources(tmp_path) -> None:
    _write(tmp_path / "plant.jsonl", "truth", 5)
    _write(tmp_path / "flight.jsonl", "flight", 4)
    out = build_rrd(tmp_path)
    rerun = Path(sys.executable).parent / "rerun"
    env = dict(os.environ, RERUN_ANALYTICS="0")
    text = subprocess.run([str(rerun), "rrd", "print", "-vvv", str(out)], capture_output=True,
                          text=True, check=True, env=env).stdout
    assert "with 5 rows" in text and "/truth/omega_deg_s" in text
    assert "with 4 rows" in text and "/flight/omega_deg_s" in text
    assert "/events/plant" in text and "/events/flight" in text
    # One row per tick holding the three labels, on both timelines (tick 3 at 0.6 s).
    rows = [ln for ln in text.splitlines() if "[3.0, 0.0, -1.0]" in ln]
    assert len(rows) == 2 and all("PT0.6S" in ln and "┆ 3 " in ln for ln in rows)
