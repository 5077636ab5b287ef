"""CI smoke run of `hil bench` over a real vcan0 (natively or inside user-mode Linux).

Runs the command as a user does, briefly, and checks that every figure is present, finite,
non-negative and ordered (p50 <= p99 <= max, the median share of the tick in [0, 1]), that
each group says where it was taken, that the JSON and the plots are written, and that
``--stress`` leaves no process behind. No figure is compared with a time limit: a slow or
loaded machine is not a failure.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hil.bench import DEFAULT_PARTS, check_figures

pytestmark = pytest.mark.vcan
BENCH = [sys.executable, "-m", "hil.bench", "bench"]


def _bench(out: Path, *extra: str) -> tuple[subprocess.CompletedProcess, dict]:
    r = subprocess.run(BENCH + ["--out", str(out), *extra], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return r, json.loads((out / "bench.json").read_text())


def _numbers(d, path=""):
    if isinstance(d, dict):
        for k, v in d.items():
            yield from _numbers(v, f"{path}.{k}")
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield from _numbers(v, f"{path}[{i}]")
    elif isinstance(d, int | float) and not isinstance(d, bool):
        yield path, d


def test_bench_smoke_every_figure_present_and_sane(tmp_path) -> None:
    out = tmp_path / "bench"
    r, rep = _bench(out, "--duration", "5", "--lockstep-duration", "10", "--pings", "200",
                    "--alloc-ticks", "100")
    assert check_figures(rep, DEFAULT_PARTS) == [] and rep["problems"] == []
    for path, x in _numbers(rep):
        assert math.isfinite(x), path
    for sec in ("realtime", "lockstep", "bus", "allocator"):
        assert rep[sec]["where"]["kernel"] in ("native kernel", "user-mode Linux"), sec
    rt = rep["realtime"]
    assert rt["where"]["sched"]["flight"] and rt["where"]["sched"]["plant"]
    assert rt["where"]["clock"].startswith("CLOCK_MONOTONIC")
    assert set(("observer", "detector", "controller", "allocator", "I/O")) <= set(rt["stage_ms"])
    # A tick stalled by the host can take longer than the tick (share > 1): an honest figure.
    assert 0.0 <= rt["tick_share"]["p50"] <= min(1.0, rt["tick_share"]["max"])
    assert rt["s2a_ms"]["n"] > 0 and rt["ticks_used"] > 0
    assert rep["bus"]["clock"] and rep["bus"]["lost"] >= 0
    assert 0.0 < rep["bus_load"]["fraction"] < 1.0
    assert {g["goal"] for g in rep["goals"]} and all(
        g["met"] in (True, False) for g in rep["goals"])  # every goal could be judged
    for png in ("jitter_hist.png", "latency_hist.png", "compute_stages.png"):
        assert (out / png).stat().st_size > 1000, png
    for needle in ("tick release jitter", "sensor-to-actuator", "lockstep speed", "round trip",
                   "linprog /", "bus load", rep["realtime"]["where"]["kernel"]):
        assert needle in r.stdout, needle
    # The per-tick latency chain is in the real-time run's own records and recording.
    plant = [json.loads(x) for x in (out / "realtime" / "plant.jsonl").read_text().splitlines()]
    chains = [c for p in plant for c in p.get("chain", [])]
    assert chains and all(c["sample_s"] <= c["received_s"] <= c["applied_s"] for c in chains)
    assert (out / "realtime" / "run.rrd").stat().st_size > 0


def test_bench_stress_reports_and_leaves_no_process(tmp_path) -> None:
    out = tmp_path / "stress"
    json_path = tmp_path / "report.json"
    r = subprocess.run(BENCH + ["--out", str(out), "--json", str(json_path), "--stress",
                                "--parts", "realtime,load", "--duration", "4", "--no-plots"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    rep = json.loads(json_path.read_text())
    assert rep["host"]["stress"] is True and rep["host"]["stress_procs"] >= 1
    assert check_figures(rep, ("realtime", "load")) == []
    assert "stress on" in r.stdout
    for pid in rep["host"]["stress_pids"]:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)  # killed and reaped by the bench
    left = [p for p in os.popen("ps -eo args").read().splitlines() if "hil.nodes" in p]
    assert not left, left


def test_bench_usage_error_exits_2() -> None:
    r = subprocess.run(BENCH + ["--parts", "warp"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "error: hil bench: --parts" in r.stderr
