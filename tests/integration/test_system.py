"""The running system over a real vcan0: plant, flight and panel as separate OS processes.

Marked ``vcan``: the test command runs them through ``hil vcan exec`` (natively where the
kernel has CAN, inside user-mode Linux where it has not). No assertion is about speed.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil.config import SCENARIO_DIR

pytestmark = pytest.mark.vcan
HIL = [sys.executable, "-m", "hil.cli"]
WALL_FIELDS = ("wall_s", "speed_x_realtime", "loop_wall_s", "startup_s",
               "end_to_end_x_realtime", "compute_ms", "release_jitter_ms", "bus",
               "bus_frames_logged", "where")


def _run(args: list[str], timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run(HIL + args, capture_output=True, text=True, timeout=timeout)


def _summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def _jsonl(path: Path) -> list[dict]:
    """Every line of a JSON lines file; only the last may be torn (a process killed with
    SIGKILL inside the write(2) of a line longer than what was left of a page: the kernel
    stops between pages), and it is dropped as ``hil.recorder.read_jsonl`` drops it."""
    lines = path.read_text().splitlines()
    out = []
    for k, x in enumerate(lines):
        try:
            out.append(json.loads(x))
        except json.JSONDecodeError:
            assert k == len(lines) - 1, f"{path}: line {k + 1} of {len(lines)} is torn"
    return out


def _rrd_rows(path: Path, entity: str) -> int:
    """Rows logged to ``entity`` in a rerun recording (``rerun rrd print``, an independent
    reader of the file)."""
    r = subprocess.run([str(Path(sys.executable).with_name("rerun")), "rrd", "print", str(path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    return sum(int(m[1]) for m in re.finditer(
        rf"with (\d+) rows \([^)]*\) - {re.escape(entity)} - data columns: \[Scalars", r.stdout))


def _figures(d: dict, where: str) -> None:
    """p50, p99 and max present, finite and non-negative."""
    for k in ("p50", "p99", "max"):
        v = d.get(k)
        assert isinstance(v, (int, float)) and math.isfinite(v) and v >= 0, (where, k, d)


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
    # A killed flight is a failed run (exit 3), not "expectations not met": the fault at 18 s
    # could no longer be detected, and nothing of the run's verdict can be believed.
    assert r.returncode == 3, r.stdout[-2000:]
    plant = [p for p in _jsonl(out / "plant.jsonl") if not p.get("final")]
    flight = _jsonl(out / "flight.jsonl")
    safe_ticks = [p["tick"] for p in plant if p.get("safe")]
    assert safe_ticks, "the plant never went safe"
    last_flight_tick = flight[-1]["tick"]
    assert last_flight_tick >= 49, last_flight_tick  # killed at 10 s (tick 50), not before
    # Safe within the configured missed ticks (scenario default 3) after the flight's last
    # command.
    lost_after = plant[0]["config"]["safety"]["thr_cmd_lost_ticks"]
    assert lost_after == 3
    assert 0 < safe_ticks[0] - last_flight_tick <= lost_after + 1, safe_ticks[:5]
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
    # The summary and the recording hold every tick up to the kill (and the plant's after).
    s = _summary(out)
    assert s["verdict"] == "run_failed" and s["expectations_met"] is False
    assert any(r.startswith("flight process killed on request (--kill-flight-at 10) at ")
               for r in s["run_failures"]), s["run_failures"]
    assert s["flight_ticks"] == len(flight) == last_flight_tick + 1
    assert s["ticks"] == len(plant) == 150  # the plant runs the whole 30 s
    assert s["safety"]["thr_cmd_lost_ticks"] == lost_after
    assert any("safe: all valves and manifolds closed" in e for e in s["safe_events"])
    rrd = out / "run.rrd"
    assert rrd.exists() and rrd.stat().st_size > 0
    assert _rrd_rows(rrd, "/flight/omega_meas_deg_s") == last_flight_tick + 1
    assert _rrd_rows(rrd, "/truth/omega_deg_s") >= len(plant)


PHASE_MS = 30.0


def test_realtime_60_s_verdict_honest_with_jitter_and_compute(tmp_path) -> None:
    """Issue 5 and 17: real time over vcan for 60 s, compute and jitter figures in the summary.

    On an idle host the flight runs every release (a 200 ms tick with a few ms of compute) and
    the run passes. A host that stalls the flight (CI virtual machines with steal time: in one
    CI run the flight's compute p99 was 125 ms and 7 releases never ran) must make the run a
    failed run that says exactly that, with the releases the flight's own records lack, and
    never a thruster detection. Which of the two happened is printed; how often the host stalls
    is the timing bench's figure (`hil bench`), not this test's."""
    scen = tmp_path / "rt.yaml"
    scen.write_text("name: rt60\nvehicle: generic\nduration_s: 60.0\nseed: 1\n"
                    "initial: {attitude: {axis: [1.0, 0.5, 0.2], angle_deg: 3.0}}\n")
    out = tmp_path / "rt"
    r = _run(["run", str(scen), "--mode", "realtime", "--out", str(out),
              "--actuation-phase-ms", str(PHASE_MS)])
    s = _summary(out)
    flight = _jsonl(out / "flight.jsonl")
    ticks = sorted({x["tick"] for x in flight})
    missed = (ticks[-1] - ticks[0] + 1) - len(ticks)
    overrun_events = [e for x in flight for e in x["events"] if e.startswith("overrun:")]
    print(f"rt60: exit {r.returncode}, {len(ticks)} flight ticks, {missed} releases never ran, "
          f"{len(overrun_events)} overruns, compute p99 {s['compute_ms']['p99']} ms")
    assert s["mode"] == "realtime" and s["missed_releases"] == missed, (s, missed)
    assert s["overruns"] == len(overrun_events), (s["overruns"], overrun_events)
    assert not [x["detection"] for x in flight if x.get("detection")], r.stdout[-3000:]
    if missed:
        assert r.returncode == 3 and s["verdict"] == "run_failed", r.stdout[-3000:]
        assert s["run_failures"] == [
            f"{missed} flight release(s) never ran (overrun skips or a stall)"], s["run_failures"]
        assert "RUN FAILED" in r.stdout and overrun_events, r.stdout[-3000:]
    else:
        assert r.returncode == 0 and s["verdict"] == "passed", r.stdout[-3000:] + r.stderr[-3000:]
        assert s["flight_ticks"] >= 290, s["flight_ticks"]
        assert s["timing"]["tick_share"]["max"] < 1.0  # no tick took longer than the tick
    _figures(s["compute_ms"], "compute_ms")
    _figures(s["release_jitter_ms"], "release_jitter_ms")
    t = s["timing"]
    _figures(t["release_jitter_ms"], "timing.release_jitter_ms")
    _figures(t["tick_share"], "timing.tick_share")  # compute as a share of the tick
    for stage in ("gyro_in", "thr_cmd_out", "fdir_tm_out"):
        _figures(t["stage_ms"][stage], f"timing.stage_ms.{stage}")
    assert len(t["stage_ms"]) >= 6, list(t["stage_ms"])  # every flight stage is timed
    for name, d in t["stage_ms"].items():
        _figures(d, f"timing.stage_ms.{name}")
    # Time-triggered actuation (--actuation-phase-ms): a command in time takes effect exactly
    # the phase after its sample went out, a late one on arrival, and is counted.
    from hil.config import load_scenario
    from hil.plant_shell import REALTIME_MAX_WAIT_S

    g_s = load_scenario(scen).vehicle.gyro.latency_ms / 1e3
    links = [c for x in _jsonl(out / "plant.jsonl") for c in x.get("chain", [])]
    assert len(links) >= 250  # 300 ticks, less the grid alignment and the last ones
    late = [c for c in links if c.get("late")]
    for c in links:
        if c.get("late"):
            # On arrival: not before it, and within the plant's own wake bound (a THR_CMD
            # wakes it at once; a host that stalls it is held to REALTIME_MAX_WAIT_S). An
            # 11 ms bound failed in CI with 11.4 ms on a virtual machine with steal time.
            assert c["received_s"] - 1e-6 <= c["applied_s"] \
                <= c["received_s"] + REALTIME_MAX_WAIT_S + 0.002, c
            assert c["applied_s"] > c["sample_s"] + g_s + PHASE_MS / 1e3
        else:
            assert c["applied_s"] - c["sample_s"] == pytest.approx(
                g_s + PHASE_MS / 1e3, abs=2e-6), c
            assert c["received_s"] <= c["applied_s"] + 1e-6, c
    assert t["late_actuations"] == len(late)


def test_rt_flag_asks_sched_fifo_and_says_what_it_got(tmp_path) -> None:
    """`hil run --rt`: flight SCHED_FIFO above the plant, memory locked, said on the terminal
    and in summary.json (as root, in CI and inside user-mode Linux, it is granted)."""
    scen = tmp_path / "rt.yaml"
    scen.write_text("name: rtprio\nvehicle: generic\nduration_s: 4.0\n")
    out = tmp_path / "rtprio"
    r = _run(["run", str(scen), "--mode", "realtime", "--out", str(out), "--rt"])
    s = _summary(out)
    # A host that stalls the whole instance (steal time) can still cost a release; the run then
    # fails for that reason alone (see the 60 s test), which is not what this test is about.
    assert r.returncode == 0 or (r.returncode == 3 and s["run_failures"] == [
        f"{s['missed_releases']} flight release(s) never ran (overrun skips or a stall)"]), \
        r.stdout[-3000:] + r.stderr[-3000:]
    sched = s["sched"]
    said = re.findall(r"(flight|plant): (--rt[^:]*): (.*)", r.stdout)
    assert {n for n, _, _ in said} == {"flight", "plant"}, r.stdout[-3000:]
    if os.geteuid() == 0:
        assert sched["flight"].startswith("SCHED_FIFO 50"), sched
        assert sched["plant"].startswith("SCHED_FIFO 40"), sched
        assert all(head == "--rt" for _, head, _ in said), said
    else:  # refused: said so, plainly
        assert all("refused" in head for _, head, _ in said), said


def test_flight_goes_safe_when_the_gyro_stops(tmp_path) -> None:
    """The plant process is SIGKILLed in real time: the flight ticks on without gyro and
    enters safe mode after the scenario's gyro_lost_ticks (no firing), in its records and on
    its terminal. Nodes started by hand (`hil run` ends the run when the plant ends)."""
    scen = tmp_path / "g.yaml"
    scen.write_text("name: gyroloss\nvehicle: generic\nduration_s: 60.0\nseed: 2\n"
                    "initial: {attitude: {axis: [1.0, 0.0, 0.0], angle_deg: 10.0}}\n"
                    "safety: {gyro_lost_ticks: 4}\n")
    out = tmp_path / "gyroloss"
    out.mkdir()
    node = [sys.executable, "-m", "hil.nodes"]
    common = ["--scenario", str(scen), "--out", str(out), "--mode", "realtime"]
    logs = {n: (out / f"{n}.log").open("w") for n in ("flight", "plant")}
    procs: dict[str, subprocess.Popen] = {}
    try:
        procs["flight"] = subprocess.Popen(node + ["flight", *common], stdout=logs["flight"],
                                           stderr=subprocess.STDOUT)
        t_end = time.monotonic() + 60
        while not (out / "flight.ready").exists():
            assert procs["flight"].poll() is None and time.monotonic() < t_end
            time.sleep(0.05)
        procs["plant"] = subprocess.Popen(node + ["plant", *common], stdout=logs["plant"],
                                          stderr=subprocess.STDOUT)
        flight_jsonl = out / "flight.jsonl"
        while not flight_jsonl.exists() or len(flight_jsonl.read_text().splitlines()) < 15:
            assert procs["flight"].poll() is None and time.monotonic() < t_end
            time.sleep(0.1)
        procs["plant"].kill()  # SIGKILL: the gyro stops
        procs["plant"].wait(10)
        while not any(r.get("safe") for r in _jsonl(flight_jsonl)[15:]):
            assert procs["flight"].poll() is None and time.monotonic() < t_end
            time.sleep(0.1)
        time.sleep(1.0)  # a few ticks in safe mode
        procs["flight"].send_signal(signal.SIGTERM)
        assert procs["flight"].wait(20) == 0
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait()
        for f in logs.values():
            f.close()
    recs = _jsonl(out / "flight.jsonl")
    k = next(i for i, r in enumerate(recs) if r["safe"])
    assert "safe mode: no valid gyro for 4 ticks: no firing" in recs[k]["events"], recs[k]
    # The 4 ticks up to the safe one saw no new sample; the one before them did.
    seqs = [r["gyro_seq"] for r in recs[k - 4:k + 1]]
    assert len(set(seqs)) == 1 and recs[k - 5]["gyro_seq"] != seqs[0], \
        [(r["tick"], r["gyro_seq"]) for r in recs[k - 6:k + 1]]
    assert all(r["safe"] and r["thr_cmd_on_ms"] == 0 for r in recs[k:]), \
        [(r["tick"], r["safe"], r["thr_cmd_on_ms"]) for r in recs[k:]]
    assert len(recs) - k >= 3
    assert sum(r["thr_cmd_on_ms"] for r in recs[:k]) > 0  # it fired while it had a gyro
    assert "[flight] safe mode: no valid gyro for 4 ticks: no firing" in \
        (out / "flight.log").read_text()


def test_fault_panel_into_running_system(tmp_path) -> None:
    out = tmp_path / "up"
    up = subprocess.Popen(HIL + ["up", "--vehicle", "generic", "--mode", "realtime",
                                 "--duration", "180", "--out", str(out)],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # Start-up inside user-mode Linux on a loaded machine can take tens of seconds.
        t_end = time.monotonic() + 120
        while not (out / "plant.jsonl").exists() or \
                len((out / "plant.jsonl").read_text().splitlines()) < 10:
            assert up.poll() is None and time.monotonic() < t_end
            time.sleep(0.2)
        # No --vehicle: the panel reads the vehicle from the run folder of `hil up`.
        run = ["--run", str(out)]
        bad = _run(["fault", "inject", "--thruster", "X9", "--type", "stuck_on", *run])
        assert bad.returncode == 2 and "expected one of" in bad.stderr, bad.stderr
        # A stalled host (CI with steal time) took longer than the panel's default 5 s to
        # acknowledge once: 30 s here; the acknowledgement itself is what is tested.
        run_ack = [*run, "--timeout", "30"]
        ok = _run(["fault", "inject", "--thruster", "X+", "--type", "stuck_on", *run_ack])
        assert ok.returncode == 0 and "accepted" in ok.stdout, ok.stdout + ok.stderr
        assert "vehicle generic" in ok.stdout
        found = None
        t_end = time.monotonic() + 30  # the stuck X+ is detected within a few seconds
        while found is None and time.monotonic() < t_end:
            for line in (out / "flight.jsonl").read_text().splitlines():
                d = json.loads(line).get("detection")
                if d:
                    found = d
            time.sleep(0.2)
        assert found and found["thruster"] == "X+" and found["type"] == "stuck_on"
        listed = _run(["fault", "list", *run])
        # The active faults as a table: thruster, type, fraction, from, until.
        assert listed.returncode == 0 and any(
            line.split()[:2] == ["X+", "stuck_on"] for line in listed.stdout.splitlines()
            if line.strip()), listed.stdout
        # A second panel process: its E2E counters start again at 0 (resent until taken).
        cleared = _run(["fault", "clear", "--thruster", "X+", *run_ack])
        assert cleared.returncode == 0 and "accepted clear X+" in cleared.stdout, \
            cleared.stdout + cleared.stderr
        t_clear = time.monotonic() + 10
        while time.monotonic() < t_clear:
            listed = _run(["fault", "list", *run])
            if "no fault active" in listed.stdout:
                break
            time.sleep(0.3)
        assert "no fault active" in listed.stdout, listed.stdout
    finally:
        up.send_signal(signal.SIGINT)
        up.wait(30)
    assert not [p for p in os.popen("ps -eo args").read().splitlines() if "hil.nodes" in p]
