"""`hil bench`: timing of the real processes over the bus, as a table, JSON and plots.

``hil bench [--duration S] [--out DIR] [--json FILE] [--stress] [--rt] [--vehicle V]``

Runs, where vcan0 exists (natively, or inside user-mode Linux which it starts by itself like
``hil run``), and prints one table (docs/design.md section 1, item 4; issue 7):

* a real-time run of a generated scenario (``--vehicle``, default ``orel``: 30 thrusters,
  firing from a 3 deg start) through ``hil.run.supervise``: tick release jitter (wake-up
  minus the scheduled release on the absolute grid) and overruns; compute time of every
  flight stage and of the whole tick, and the share of the tick; sensor-to-actuator latency
  (the plant's gyro sample time to the plant applying the THR_CMD computed from it, traced by
  ``ThrCmd.gyro_seq``) with its two parts (sample to publish, publish to command received);
  the flight's wait for its gyro sample and late samples;
* a lockstep run of the same scenario: simulated seconds per wall second of the lockstep loop
  (and end to end, with process start-up);
* bus latency between two processes over the bus: raw python-can frames ping-pong (one way
  both directions, round trip) and the lockstep exchange through the whole stack (SYNC to a
  complete, checked 30-thruster THR_CMD set);
* the allocator's LP against ``scipy.optimize.linprog`` on the same problems (speed ratio and
  the largest difference of the optimum);
* bus load from the catalog at the configured bit rate.

Every group says where it was taken (native kernel or user-mode Linux, CPUs, the scheduler
policy of each process, the clock). The first ``WARMUP_TICKS`` ticks of the real-time run
(imports, first solves) and the flight's ticks after the plant stopped are left out of the
statistics and counted. ``--stress`` adds one CPU hog process per CPU (deterministic work,
killed at the end); ``--rt`` asks for SCHED_FIFO (``hil.nodes --rt-priority``) and says when
it is refused. ``--json`` (default ``OUT/bench.json``) gets every figure; ``OUT`` gets the PNG
plots and the runs' folders. A benchmark prints figures: the goals of issue 7 are shown as
met or not, and nothing fails because a machine is slow: exit 0 when every figure was
measured, 1 when one is missing or absurd (listed under the table), 2 on a usage error.

While the runs go, this process (the supervisor: bus monitor, rerun recording) runs with
SCHED_BATCH, so on one CPU its per-frame wake-ups do not preempt the flight software in the
middle of a tick; the nodes set their own policies (``hil.process_policy.set_policy``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import platform
import signal
import subprocess
import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from hil.errors import HilError, UsageError
from hil.timing import STAGE_GROUPS, lockstep_figures, realtime_figures, stats_ms

HOST_LOAD_ENV = "HIL_BENCH_HOST_LOAD"  # the host's load average, for a run inside UML
PARTS = ("realtime", "lockstep", "bus", "allocator", "load")
GOALS = (
    # (text, key path in the report, limit): shown as met or not met, never asserted
    ("release jitter p99 < 1 ms", ("realtime", "release_jitter_ms", "p99"), 1.0),
    ("no overrun", ("realtime", "overruns"), 0),
    ("flight compute p99 < 2 ms", ("realtime", "compute_ms", "p99"), 2.0),
    ("sensor-to-actuator p99 < 5 ms + bus one-way p99", ("realtime", "s2a_ms", "p99"), None),
    ("lockstep >= 20x real time", ("lockstep", "speed_x_realtime"), 20.0),
)


# ============================================================================ pure figures


def bus_load_figures(bitrate_bps: int) -> dict[str, Any]:
    from bus.catalog import bus_load

    rows = bus_load(bitrate_bps)
    total = sum(r[1] for r in rows)
    return {"bitrate_bps": bitrate_bps, "total_bps": round(total, 1),
            "fraction": round(total / bitrate_bps, 6),
            "frames": [{"name": n, "bps": round(b, 1), "fraction": round(f, 6)}
                       for n, b, f in rows]}


def _get(d: dict, path: tuple[str, ...]) -> Any:
    for k in path:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def goals(report: dict) -> list[dict[str, Any]]:
    """Issue 7's goals against the figures (information for the reader, never a failure)."""
    out = []
    one_way = _get(report, ("bus", "one_way_ms", "a_to_b", "p99"))
    for text, path, limit in GOALS:
        value = _get(report, path)
        if limit is None:  # sensor-to-actuator: 5 ms plus the bus's one-way latency
            limit = None if one_way is None else round(5.0 + one_way, 4)
        if value is None or limit is None:
            met = None
        elif path[-1] == "overruns":
            met = value <= limit
        elif path[-1] == "speed_x_realtime":
            met = value >= limit
        else:
            met = value < limit
        out.append({"goal": text, "value": value, "limit": limit, "met": met})
    return out


def check_figures(report: dict, parts: Iterable[str] = PARTS) -> list[str]:
    """Every figure present, finite, non-negative and ordered; one line per problem.

    What the CI smoke run asserts: the bench measured everything and nothing is absurd. No
    figure is compared with a time limit (a slow machine is not a failure).
    """
    problems: list[str] = []

    def num(path: str, x: Any, *, lo: float = 0.0, hi: float | None = None) -> None:
        if not isinstance(x, int | float) or isinstance(x, bool) or not math.isfinite(x):
            problems.append(f"{path}: expected a finite number, got {x!r}")
        elif x < lo or (hi is not None and x > hi):
            problems.append(f"{path}: expected {lo} <= value{f' <= {hi}' if hi else ''}, "
                            f"got {x}")

    def triple(path: str, d: Any) -> None:
        if not isinstance(d, dict):
            problems.append(f"{path}: expected p50/p99/max, got {d!r}")
            return
        for k in ("p50", "p99", "max"):
            num(f"{path}.{k}", d.get(k))
        if all(isinstance(d.get(k), int | float) for k in ("p50", "p99", "max")) and not (
                d["p50"] <= d["p99"] + 1e-9 <= d["max"] + 2e-9):
            problems.append(f"{path}: expected p50 <= p99 <= max, got "
                            f"{d['p50']}, {d['p99']}, {d['max']}")

    def where(path: str, sec: Any) -> None:
        w = sec.get("where") if isinstance(sec, dict) else None
        if not isinstance(w, dict) or not w.get("kernel"):
            problems.append(f"{path}.where: expected the kernel it ran on, got {w!r}")

    parts = tuple(parts)
    if "realtime" in parts:
        rt = report.get("realtime") or {}
        where("realtime", rt)
        for k in ("release_jitter_ms", "compute_ms", "s2a_ms", "gyro_wait_ms",
                  "gyro_publish_ms", "flight_turnaround_ms"):
            triple(f"realtime.{k}", rt.get(k))
        stages = rt.get("stage_ms") or {}
        for k in ("observer", "detector", "controller", "allocator", "I/O"):
            triple(f"realtime.stage_ms.{k}", stages.get(k))
        share = rt.get("tick_share") or {}
        # The median tick inside its tick; p99 and max may pass 1 (an overrun is counted).
        for k in ("p50", "p99", "max"):
            num(f"realtime.tick_share.{k}", share.get(k), hi=1.0 if k == "p50" else None)
        num("realtime.overruns", rt.get("overruns"))
        num("realtime.ticks_used", rt.get("ticks_used"), lo=1)
        sched = (rt.get("where") or {}).get("sched") or {}
        for node in ("flight", "plant"):
            if not sched.get(node):
                problems.append(f"realtime.where.sched.{node}: expected a policy, got nothing")
    if "lockstep" in parts:
        ls = report.get("lockstep") or {}
        where("lockstep", ls)
        num("lockstep.speed_x_realtime", ls.get("speed_x_realtime"), lo=1e-9)
        num("lockstep.sim_s", ls.get("sim_s"), lo=1e-9)
    if "bus" in parts:
        bus = report.get("bus") or {}
        where("bus", bus)
        if not bus.get("clock"):
            problems.append("bus.clock: expected the clock's name, got nothing")
        triple("bus.round_trip_ms", bus.get("round_trip_ms"))
        for k in ("a_to_b", "b_to_a"):
            triple(f"bus.one_way_ms.{k}", (bus.get("one_way_ms") or {}).get(k))
        triple("bus.stack_round_trip_ms", bus.get("stack_round_trip_ms"))
    if "allocator" in parts:
        al = report.get("allocator") or {}
        where("allocator", al)
        for k, d in (al.get("per_solve_us") or {"missing": None}).items():
            triple(f"allocator.per_solve_us.{k}", d)
        for k, v in (al.get("ratio_linprog_over") or {"missing": None}).items():
            num(f"allocator.ratio_linprog_over.{k}", v, lo=1e-9)
        num("allocator.max_cost_rel_diff", al.get("max_cost_rel_diff"))
    if "load" in parts:
        ld = report.get("bus_load") or {}
        num("bus_load.fraction", ld.get("fraction"), hi=1.0)
        num("bus_load.bitrate_bps", ld.get("bitrate_bps"), lo=1)
    return problems


# ============================================================================ the table


def _f(x: Any, nd: int = 3) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.{nd}f}"
    return str(x)


def _where_text(w: dict | None) -> str:
    if not w:
        return ""
    bits = [w.get("kernel", "?")]
    sched = w.get("sched")
    if isinstance(sched, dict):
        bits.append(", ".join(f"{k} {v}" for k, v in sched.items()))
    elif sched:
        bits.append(str(sched))
    if w.get("clock"):
        bits.append(w["clock"])
    return "; ".join(bits)


def format_table(report: dict) -> str:
    """The printed table: one line per figure, p50 / p99 / max, and where it was taken."""
    head = report.get("host", {})
    lines = [
        f"hil bench: {head.get('kernel', '?')}, {head.get('cpus', '?')} CPU(s), host load "
        f"{head.get('load_avg_1m', '?')} before, stress "
        f"{'on (' + str(head.get('stress_procs')) + ' hogs)' if head.get('stress') else 'off'}, "
        f"python {head.get('python', '?')}",
        f"{'figure':<44}{'p50':>10}{'p99':>10}{'max':>10}",
    ]

    def row(name: str, d: dict | None, unit: str = "ms") -> None:
        d = d or {}
        lines.append(f"  {name + ' [' + unit + ']':<42}{_f(d.get('p50')):>10}"
                     f"{_f(d.get('p99')):>10}{_f(d.get('max')):>10}")

    def text(name: str, value: str) -> None:
        lines.append(f"  {name:<42}{value}")

    rt = report.get("realtime")
    if rt:
        lines.append(f"real time: {rt.get('vehicle')}, {rt.get('duration_s')} s, "
                     f"{rt.get('ticks_used')} ticks used ({rt.get('warmup_ticks')} warm-up, "
                     f"{rt.get('ticks_after_plant_end')} after the plant's end left out)")
        lines.append(f"  where: {_where_text(rt.get('where'))}")
        row("tick release jitter", rt.get("release_jitter_ms"))
        text("overruns", f"{rt.get('overruns')} in {rt.get('ticks_used')} ticks "
                         f"({rt.get('overruns_all_ticks')} in all {rt.get('ticks')})")
        for k, d in (rt.get("stage_ms") or {}).items():
            row(f"compute {k}", d)
        row("compute whole tick", rt.get("compute_ms"))
        sh = rt.get("tick_share") or {}
        lines.append(f"  {'share of the ' + _f(rt.get('tick_ms'), 0) + ' ms tick':<42}"
                     + "".join(f"{_f(None if sh.get(k) is None else 100 * sh[k], 2) + ' %':>10}"
                               for k in ("p50", "p99", "max")))
        row("sensor-to-actuator (sample->applied)", rt.get("s2a_ms"))
        row("  of which sample->published", rt.get("gyro_publish_ms"))
        row("  of which published->THR_CMD rx", rt.get("flight_turnaround_ms"))
        row("flight's wait for its gyro sample", rt.get("gyro_wait_ms"))
        text("late gyro samples (wait bound hit)", str(rt.get("late_gyro")))
        text("ticks firing / FDIR false alarms",
             f"{rt.get('firing_ticks')} / {rt.get('false_alarms')}")
    ls = report.get("lockstep")
    if ls:
        lines.append(f"lockstep: {ls.get('sim_s')} s simulated")
        lines.append(f"  where: {_where_text(ls.get('where'))}")
        text("lockstep speed (loop) [x real time]", _f(ls.get("speed_x_realtime"), 2))
        text("lockstep speed (start-up incl.) [x]",
             _f(ls.get("end_to_end_x_realtime"), 2))
        row("SYNC sent to THR_CMD complete", ls.get("sync_to_cmd_ms"))
    bus = report.get("bus")
    if bus:
        lines.append(f"bus: {bus.get('frames')} frames ping-pong, {bus.get('lost')} lost")
        lines.append(f"  where: {_where_text(bus.get('where'))}")
        ow = bus.get("one_way_ms") or {}
        row("one way A->B (send->recv)", ow.get("a_to_b"))
        row("one way B->A", ow.get("b_to_a"))
        row("round trip A->B->A", bus.get("round_trip_ms"))
        row("SYNC->THR_CMD set (Port, 30 thr.)", bus.get("stack_round_trip_ms"))
    al = report.get("allocator")
    if al:
        lines.append(f"allocator: {al.get('vehicle')}, {al.get('problems')} LPs, flight uses "
                     f"{al.get('solver_configured')}")
        lines.append(f"  where: {_where_text(al.get('where'))}")
        for k, d in (al.get("per_solve_us") or {}).items():
            row(f"LP solve {k}", d, "us")
        for k, r in (al.get("ratio_linprog_over") or {}).items():
            text(f"linprog / {k} (total time)", f"{_f(r, 1)}x")
        text("largest optimum difference vs linprog", _f(al.get("max_cost_rel_diff"), 6))
    ld = report.get("bus_load")
    if ld:
        text("bus load from the catalog",
             f"{ld['total_bps']:.0f} bit/s = {100 * ld['fraction']:.2f} % of "
             f"{ld['bitrate_bps'] / 1e6:g} Mbit/s")
    gl = report.get("goals")
    if gl:
        lines.append("goals of issue 7 (information, not a verdict):")
        for g in gl:
            state = {True: "met", False: "NOT met", None: "-"}[g["met"]]
            lines.append(f"  {g['goal']:<52}{_f(g['value']):>10}  {state}")
    return "\n".join(lines)


# ============================================================================ measurements


def where_here() -> dict[str, Any]:
    from hil.uml import in_uml

    return {"kernel": "user-mode Linux" if in_uml() else "native kernel",
            "cpus": os.cpu_count()}


def _policy_name() -> str:
    from hil.process_policy import sched_policy

    return sched_policy()


@contextlib.contextmanager
def own_policy(policy: int) -> Iterator[str]:
    """Run the block with this process's scheduler policy set (restored after)."""
    try:
        old = os.sched_getscheduler(0), os.sched_getparam(0)
    except (OSError, AttributeError):
        yield _policy_name()
        return
    try:
        os.sched_setscheduler(0, policy, os.sched_param(0))
    except (PermissionError, OSError):
        pass
    try:
        yield _policy_name()
    finally:
        with contextlib.suppress(PermissionError, OSError):
            os.sched_setscheduler(0, old[0], old[1])


def _die_with_parent() -> None:
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


HOG_CODE = """
import sys
x, a = int(sys.argv[1]) * 2654435761 + 1, 6364136223846793005
while True:  # a deterministic LCG: pure CPU, no memory growth, no I/O
    for _ in range(100000):
        x = (a * x + 1442695040888963407) & 0xFFFFFFFFFFFFFFFF
"""


class CpuHogs:
    """``n`` CPU-bound processes (seeded, deterministic work) for ``--stress``.

    Started with PR_SET_PDEATHSIG, so they die with this process even if it is killed;
    ``stop`` kills each one by its pid and reaps it: no orphan is left.
    """

    def __init__(self, n: int) -> None:
        self.n = n
        self.procs: list[subprocess.Popen] = []

    def __enter__(self) -> CpuHogs:
        for k in range(self.n):
            self.procs.append(subprocess.Popen(
                [sys.executable, "-c", HOG_CODE, str(k)], stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                preexec_fn=_die_with_parent))
        return self

    @property
    def pids(self) -> list[int]:
        return [p.pid for p in self.procs]

    def stop(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.kill()
        for p in self.procs:
            p.wait()
        self.procs = []

    def __exit__(self, *exc: object) -> None:
        self.stop()


def bench_scenario(vehicle: str, duration_s: float, name: str) -> dict[str, Any]:
    """A scenario that fires: a 3 deg attitude error and a small rate (seeded)."""
    return {"name": name, "description": "hil bench: attitude hold after a 3 deg offset",
            "vehicle": vehicle, "duration_s": float(duration_s), "seed": 1,
            "initial": {"attitude": {"axis": [1.0, 0.5, 0.2], "angle_deg": 3.0},
                        "rate_B_deg_s": [0.02, -0.01, 0.01]}}


def _run_scenario(mode: str, scenario: dict, out: Path, args) -> tuple[dict, list, list]:
    import yaml

    from hil.recorder import read_jsonl
    from hil.run import supervise

    out.mkdir(parents=True, exist_ok=True)
    path = out / "scenario.yaml"
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    ns = argparse.Namespace(mode=mode, interface=args.interface, channel=args.channel,
                            rt_priority=args.rt)
    summary = supervise(path, out, ns, quiet=True)
    return (summary, list(read_jsonl(out / "plant.jsonl")),
            list(read_jsonl(out / "flight.jsonl")))


def _node_sched(plant: list[dict], flight: list[dict]) -> dict[str, str]:
    first = {"plant": next((r.get("sched") for r in plant if r.get("sched")), None),
             "flight": next((r.get("sched") for r in flight if r.get("sched")), None)}
    return {k: v or "unknown" for k, v in first.items()}


def measure_realtime(args, out: Path) -> dict[str, Any]:
    from hil.config import load_vehicle

    sc = bench_scenario(args.vehicle, args.duration, "bench-realtime")
    with own_policy(os.SCHED_BATCH) as sup:
        summary, plant, flight = _run_scenario("realtime", sc, out, args)
    tick_s = load_vehicle(args.vehicle).timing.tick_s
    fig = realtime_figures(plant, flight, tick_s)
    fig.update(vehicle=args.vehicle, duration_s=args.duration,
               false_alarms=len(summary.get("false_alarms", [])),
               where={**where_here(), "sched": {**_node_sched(plant, flight),
                                                "supervisor": sup},
                      "clock": "CLOCK_MONOTONIC (kernel rx stamps converted from "
                               "CLOCK_REALTIME)"},
               run_dir=str(out))
    fig["_series"] = _series(flight, plant, fig)
    return fig


def _series(flight: list[dict], plant: list[dict], fig: dict) -> dict[str, Any]:
    """Per-tick values of the ticks the statistics use, for the plots (not in the JSON)."""
    kept = set(fig.get("_kept_ticks", []))
    fl = [r for r in flight if r.get("tick") in kept]
    first = min(kept) if kept else 0
    return {
        "tick": [r["tick"] for r in fl],
        "jitter_ms": [r["jitter_s"] * 1e3 for r in fl],
        "stage_ms": {k: [r["stage_s"].get(k, 0.0) * 1e3 for r in fl]
                     for k in (fig.get("stage_ms") or {}) if k not in STAGE_GROUPS},
        "s2a_ms": [(c["applied_s"] - c["sample_s"]) * 1e3 for r in plant
                   for c in r.get("chain", []) if c.get("tick", 0) >= first],
    }


def measure_lockstep(args, out: Path) -> dict[str, Any]:
    sc = bench_scenario(args.vehicle, args.lockstep_duration, "bench-lockstep")
    with own_policy(os.SCHED_BATCH) as sup:
        summary, plant, flight = _run_scenario("lockstep", sc, out, args)
    fig = lockstep_figures(plant, summary)
    fig.update(vehicle=args.vehicle,
               where={**where_here(), "sched": {**_node_sched(plant, flight),
                                                "supervisor": sup},
                      "clock": "CLOCK_MONOTONIC"},
               run_dir=str(out))
    return fig


# -- bus latency: raw frames ping-pong between two processes (was bench_vcan_latency.py)

PING_ID, ECHO_ID = 0x100, 0x101
_TS_MASK = (1 << 48) - 1  # 6 payload bytes of nanoseconds (wraps after 78 h: handled)


def pack(seq: int, t_ns: int) -> bytes:
    """8-byte payload: seq (2 bytes) and the low 48 bits of a monotonic time in ns (6 bytes)."""
    return (seq & 0xFFFF).to_bytes(2, "big") + (t_ns & _TS_MASK).to_bytes(6, "big")


def unpack(data: bytes) -> tuple[int, int]:
    return int.from_bytes(data[:2], "big"), int.from_bytes(data[2:8], "big")


def since(t_now_ns: int, t48_ns: int) -> int:
    """Nanoseconds from a 48-bit timestamp to now, across a wrap."""
    return (t_now_ns - t48_ns) & _TS_MASK


def _set_fifo(rt: bool) -> str:
    if rt:
        with contextlib.suppress(PermissionError, OSError, AttributeError):
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
    return _policy_name()


def echo(channel: str, n: int, rt: bool = False) -> None:
    """Process B: echo every ping with B's send time; print A->B one-way times as JSON."""
    import can

    pol = _set_fifo(rt)
    bus = can.Bus(interface="socketcan", channel=channel, receive_own_messages=False,
                  can_filters=[{"can_id": PING_ID, "can_mask": 0x7FF, "extended": False}])
    print("ready", flush=True)
    a_to_b = []
    try:
        while len(a_to_b) < n:
            msg = bus.recv(timeout=10)
            if msg is None:
                break
            t_rx = time.monotonic_ns()
            seq, t_tx_a = unpack(msg.data)
            a_to_b.append(since(t_rx, t_tx_a))
            bus.send(can.Message(arbitration_id=ECHO_ID, is_extended_id=False,
                                 data=pack(seq, time.monotonic_ns())))
    finally:
        bus.shutdown()
    print(json.dumps({"a_to_b_ns": a_to_b, "sched": pol}), flush=True)


def ping_pong(channel: str = "vcan0", n: int = 1000, warmup: int = 50,
              rt: bool = False) -> dict[str, Any]:
    """Round trip and one-way times (ns lists) of ``n`` frames between two processes.

    Process A (this one) sends a frame with its CLOCK_MONOTONIC send time; process B echoes
    it with its own. One kernel, so both processes read the same CLOCK_MONOTONIC: A->B is B's
    receive minus A's send, B->A the reverse, round trip A's receive of the echo minus its
    send. User space to user space (python-can ``send`` to the return of ``recv``).
    """
    import can

    total = n + warmup
    peer = subprocess.Popen([sys.executable, "-m", "hil.bench", "_echo", channel, str(total)]
                            + (["--rt"] if rt else []), stdout=subprocess.PIPE, text=True)
    try:
        if peer.stdout.readline().strip() != "ready":
            raise HilError("bench: the echo process did not start")
        old = os.sched_getscheduler(0), os.sched_getparam(0)
        pol = _set_fifo(rt)
        bus = can.Bus(interface="socketcan", channel=channel,
                      can_filters=[{"can_id": ECHO_ID, "can_mask": 0x7FF, "extended": False}])
        rtt, b_to_a, lost = [], [], 0
        try:
            for seq in range(total):
                t_tx = time.monotonic_ns()
                bus.send(can.Message(arbitration_id=PING_ID, is_extended_id=False,
                                     data=pack(seq, t_tx)))
                msg = bus.recv(timeout=2)
                t_rx = time.monotonic_ns()
                if msg is None or unpack(msg.data)[0] != seq & 0xFFFF:
                    lost += 1
                    continue
                if seq >= warmup:
                    rtt.append(t_rx - t_tx)
                    b_to_a.append(since(t_rx, unpack(msg.data)[1]))
        finally:
            bus.shutdown()
            with contextlib.suppress(PermissionError, OSError):
                os.sched_setscheduler(0, old[0], old[1])
        out, _ = peer.communicate(timeout=30)
    finally:
        if peer.poll() is None:
            peer.kill()
            peer.wait()
    res = json.loads(out.strip().splitlines()[-1])
    return {"rtt_ns": rtt, "a_to_b_ns": res["a_to_b_ns"][warmup:], "b_to_a_ns": b_to_a,
            "lost": lost, "sched": {"A": pol, "B": res["sched"]}}


def stack_round_trip(channel: str = "vcan0", n: int = 300) -> list[int]:
    """SYNC(n) sent -> a complete, checked 30-thruster THR_CMD(n) set back through ``Port``
    on both sides (encode, E2E, classify, assemble), ns, CLOCK_MONOTONIC (was bench_bus)."""
    from bus.codec import ThrCmd
    from bus.protocol import PlantLockstep
    from bus.transport import BusConfig, Port, open_bus

    cfg = BusConfig(interface="socketcan", channel=channel)
    peer = subprocess.Popen([sys.executable, "-m", "bus.echo_peer", "--channel", channel,
                             "--mode", "lockstep", "--ticks", str(n), "--idle-s", "3"],
                            stdout=subprocess.PIPE, text=True)
    rtt: list[int] = []
    try:
        if peer.stdout.readline().strip() != "ready":
            raise HilError("bench: the lockstep echo peer did not start")
        port = Port(open_bus(cfg))
        plant = PlantLockstep(30, reply_timeout_s=2.0)
        try:
            for k in range(n):
                t0 = time.monotonic_ns()
                port.send(plant.begin_tick(k, port.now_s()))
                while plant.result is None:
                    for msg, rx_s in port.poll(0.05):
                        if isinstance(msg, ThrCmd):
                            plant.on_message(msg, rx_s)
                    plant.poll(port.now_s())
                if not plant.result.safe:
                    rtt.append(time.monotonic_ns() - t0)
        finally:
            port.close()
        peer.communicate(timeout=30)
    finally:
        if peer.poll() is None:
            peer.kill()
            peer.wait()
    return rtt


def measure_bus(args) -> dict[str, Any]:
    pp = ping_pong(args.channel, args.pings, warmup=50, rt=args.rt)
    stack = stack_round_trip(args.channel, max(50, args.pings // 4))
    ns = 1e-9
    return {
        "frames": args.pings, "lost": pp["lost"],
        "one_way_ms": {"a_to_b": stats_ms(x * ns for x in pp["a_to_b_ns"]),
                       "b_to_a": stats_ms(x * ns for x in pp["b_to_a_ns"])},
        "round_trip_ms": stats_ms(x * ns for x in pp["rtt_ns"]),
        "stack_round_trip_ms": stats_ms(x * ns for x in stack),
        "clock": "CLOCK_MONOTONIC, one kernel, two processes (user space to user space)",
        "where": {**where_here(), "sched": pp["sched"],
                  "clock": "CLOCK_MONOTONIC"},
        "_series": {"one_way_ms": [x / 1e6 for x in pp["a_to_b_ns"]],
                    "round_trip_ms": [x / 1e6 for x in pp["rtt_ns"]]},
    }


# -- allocator against linprog (was bench_allocator.py)


def demand_stream(ticks: int, seed: int = 1) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Phase-plane-like bounds: a slowly varying rate error, dead-zone bands, some large steps."""
    rng = np.random.default_rng(seed)
    dz = np.radians(0.12)
    e = np.zeros(3)
    for k in range(ticks):
        e = 0.95 * e + rng.normal(size=3) * dz * 0.4
        if k % 97 == 0:
            e += rng.normal(size=3) * dz * 8  # a slew start or disturbance
        lo, hi = -dz - e, dz - e
        out = np.abs(e) > dz
        lo = np.where(out, -0.83 * dz - e, lo)
        hi = np.where(out, 0.83 * dz - e, hi)
        yield lo, hi


def compare_allocator(vehicle_name: str, ticks: int = 1000) -> dict[str, Any]:
    """The allocator's LP (dedicated dual simplex, and HiGHS through highspy with warm start)
    against ``scipy.optimize.linprog`` on the same scaled LPs of a demand stream.

    Per-solve times (one clock read pair per solve) and the speed ratio from the total time
    of each solver over all problems (one clock read pair per solver, so the cost of reading
    the clock, a system call under user-mode Linux, does not bias the ratio). Also the
    largest relative difference of the optimal cost between each solver and linprog.
    """
    from flight.allocator import Allocator
    from flight.lp import linprog_solve
    from hil.config import load_vehicle

    vehicle = load_vehicle(vehicle_name)
    problems = list(demand_stream(ticks))
    per: dict[str, list[float]] = {}
    totals: dict[str, float] = {}
    costs: dict[str, list[float]] = {}
    for solver in ("simplex", "highs", "linprog"):
        alloc = Allocator(vehicle, solver="simplex" if solver == "linprog" else solver)
        cols = np.arange(alloc.n)
        rs = alloc._row_scale6[:3]
        A, c = alloc._A6[:3], alloc._c
        ub = np.full(alloc.n, alloc.tau_max_s / alloc.h_s)
        scaled = [(lo / rs, hi / rs) for lo, hi in problems]

        def solve(lo, hi, solver=solver, alloc=alloc, A=A, c=c, ub=ub, cols=cols):
            if solver == "linprog":
                return linprog_solve(A, c, lo, hi, ub)
            return alloc._solve_main(3, lo, hi, ub, cols)

        for lo, hi in scaled[:5]:  # warm-up: imports, first factorisations
            solve(lo, hi)
        ts, cs = [], []
        for lo, hi in scaled:
            t0 = time.perf_counter()
            res = solve(lo, hi)
            ts.append(time.perf_counter() - t0)
            cs.append(float(c @ res[1]) if res[0] == 0 else math.nan)
        t0 = time.perf_counter()
        for lo, hi in scaled:
            solve(lo, hi)
        totals[solver] = time.perf_counter() - t0
        per[solver], costs[solver] = ts, cs
    ref = np.asarray(costs["linprog"])
    diffs = []
    for solver in ("simplex", "highs"):
        mine = np.asarray(costs[solver])
        ok = np.isfinite(ref) & np.isfinite(mine)
        diffs.extend(np.abs(mine[ok] - ref[ok]) / np.maximum(np.abs(ref[ok]), 1e-12))
    return {
        "vehicle": vehicle.name, "thrusters": len(vehicle.thrusters), "problems": ticks,
        "solver_configured": vehicle.flight.allocator.solver,
        "per_solve_us": {k: {kk: (None if vv is None else round(vv * 1e3, 2))
                             for kk, vv in stats_ms(v).items() if kk != "n"}
                         for k, v in per.items()},
        "ratio_linprog_over": {k: round(totals["linprog"] / totals[k], 2)
                               for k in ("simplex", "highs")},
        "max_cost_rel_diff": round(float(max(diffs)) if diffs else 0.0, 9),
        "infeasible_or_failed": {k: int(np.sum(~np.isfinite(np.asarray(v))))
                                 for k, v in costs.items()},
    }


# ============================================================================ plots


def write_plots(report: dict, out: Path) -> list[str]:
    """PNG histograms of jitter and latencies, and compute time per stage over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    where = report.get("host", {}).get("kernel", "")
    made: list[str] = []
    rt = (report.get("realtime") or {}).get("_series")
    bus = (report.get("bus") or {}).get("_series")
    if rt and rt["jitter_ms"]:
        fig, ax = plt.subplots(figsize=(7, 4))
        ax.hist(rt["jitter_ms"], bins=60, color="tab:blue")
        ax.set_yscale("log")
        ax.set_xlabel("release jitter: wake-up minus scheduled release [ms]")
        ax.set_ylabel("ticks")
        ax.set_title(f"flight tick release jitter ({where})")
        fig.tight_layout()
        fig.savefig(out / "jitter_hist.png", dpi=110)
        plt.close(fig)
        made.append("jitter_hist.png")
    panels = []
    if rt and rt["s2a_ms"]:
        panels.append(("sensor-to-actuator: gyro sample to THR_CMD applied [ms]", rt["s2a_ms"]))
    if bus:
        panels.append(("bus one way A->B [ms]", bus["one_way_ms"]))
        panels.append(("bus round trip [ms]", bus["round_trip_ms"]))
    if panels:
        fig, axes = plt.subplots(len(panels), 1, figsize=(7, 2.6 * len(panels)))
        for ax, (label, vals) in zip(np.atleast_1d(axes), panels, strict=True):
            ax.hist(vals, bins=60, color="tab:orange")
            ax.set_yscale("log")
            ax.set_xlabel(label)
            ax.set_ylabel("count")
        fig.suptitle(f"latency ({where})")
        fig.tight_layout()
        fig.savefig(out / "latency_hist.png", dpi=110)
        plt.close(fig)
        made.append("latency_hist.png")
    if rt and rt["stage_ms"]:
        fig, ax = plt.subplots(figsize=(9, 4.5))
        t = rt["tick"]
        for k, vals in rt["stage_ms"].items():
            ax.plot(t, vals, lw=0.8, label=k)
        ax.set_yscale("log")
        ax.set_xlabel("flight tick")
        ax.set_ylabel("compute time [ms]")
        ax.set_title(f"flight compute per stage ({where})")
        ax.legend(fontsize=7, ncol=4)
        fig.tight_layout()
        fig.savefig(out / "compute_stages.png", dpi=110)
        plt.close(fig)
        made.append("compute_stages.png")
    return made


# ============================================================================ command


def run_bench(args) -> dict[str, Any]:
    """Measure every part asked for; returns the report (with ``_series`` for the plots)."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    parts = args.parts
    host_load = os.environ.get(HOST_LOAD_ENV)  # set by the host when re-run inside UML
    host = {**where_here(),
            "load_avg_1m": float(host_load) if host_load else round(os.getloadavg()[0], 2),
            "python": platform.python_version(), "machine": platform.machine(),
            "stress": bool(args.stress), "stress_procs": 0, "rt_requested": bool(args.rt)}
    report: dict[str, Any] = {"host": host, "parts": list(parts),
                              "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    steps = [("realtime", lambda: measure_realtime(args, out / "realtime")),
             ("lockstep", lambda: measure_lockstep(args, out / "lockstep")),
             ("bus", lambda: measure_bus(args)),
             ("allocator", lambda: {**compare_allocator(args.vehicle, args.alloc_ticks),
                                    "where": {**where_here(), "sched": _policy_name(),
                                              "clock": "CLOCK_MONOTONIC (perf_counter)"}}),
             ("load", lambda: bus_load_figures(args.bitrate))]
    hogs = CpuHogs((os.cpu_count() or 1) if args.stress else 0)
    with hogs:
        host["stress_procs"], host["stress_pids"] = len(hogs.procs), hogs.pids
        for name, fn in steps:
            if name not in parts:
                continue
            print(f"hil bench: {name} ...", flush=True)
            t0 = time.monotonic()
            report["bus_load" if name == "load" else name] = fn()
            print(f"hil bench: {name} done in {time.monotonic() - t0:.1f} s", flush=True)
    report["goals"] = goals(report)
    return report


def _public(report: dict) -> dict:
    """The report without the per-tick series (those go to the plots)."""
    return {k: (_public(v) if isinstance(v, dict) else v)
            for k, v in report.items() if not k.startswith("_")}


def _parse_parts(text: str) -> tuple[str, ...]:
    parts = tuple(p.strip() for p in text.split(",") if p.strip())
    bad = [p for p in parts if p not in PARTS]
    if bad or not parts:
        raise UsageError(f"hil bench: --parts: expected a comma list of {', '.join(PARTS)}, "
                         f"got {text!r}")
    return parts


def _check_args(args) -> None:
    if args.bitrate is None:
        from bus.catalog import BITRATE_BPS

        args.bitrate = BITRATE_BPS
    for name, value, lo in (("--duration", args.duration, 2.0),
                            ("--lockstep-duration", args.lockstep_duration, 1.0),
                            ("--pings", args.pings, 10), ("--alloc-ticks", args.alloc_ticks, 10),
                            ("--bitrate", args.bitrate, 1)):
        if not value >= lo:
            raise UsageError(f"hil bench: {name}: expected >= {lo:g}, got {value:g}")
    from hil.config import VEHICLE_DIR

    if not (VEHICLE_DIR / f"{args.vehicle}.yaml").exists():
        raise UsageError(f"hil bench: --vehicle: expected one of "
                         f"{sorted(p.stem for p in VEHICLE_DIR.glob('*.yaml'))}, "
                         f"got {args.vehicle!r}")
    if args.interface != "socketcan":
        raise UsageError(f"hil bench: --interface: expected socketcan (the bench measures "
                         f"SocketCAN between processes), got {args.interface!r}")


def _maybe_in_uml(args, argv: list[str]) -> int | None:
    """``hil.run.maybe_in_uml`` for this module: re-run ``python -m hil.bench`` inside UML."""
    from hil.run import INSIDE_UML_ENV, _vcan_ready

    if os.environ.get(INSIDE_UML_ENV) or _vcan_ready(args.channel):
        return None
    from hil.uml import run_in_uml

    print("hil: this kernel has no CAN; running inside user-mode Linux (real vcan0 there)",
          flush=True)
    env = dict(os.environ, **{INSIDE_UML_ENV: "1",
                              HOST_LOAD_ENV: f"{os.getloadavg()[0]:.2f}"})
    return run_in_uml([sys.executable, "-m", "hil.bench", *argv], env=env, cwd=os.getcwd())


def _cmd_bench(args) -> int:
    args.parts = _parse_parts(args.parts)
    _check_args(args)
    out = Path(args.out).resolve()
    json_path = Path(args.json).resolve() if args.json else out / "bench.json"
    argv = ["bench", "--out", str(out), "--json", str(json_path), "--duration",
            str(args.duration), "--lockstep-duration", str(args.lockstep_duration),
            "--vehicle", args.vehicle, "--pings", str(args.pings), "--alloc-ticks",
            str(args.alloc_ticks), "--bitrate", str(args.bitrate), "--parts",
            ",".join(args.parts), "--channel", args.channel]
    argv += ["--stress"] * bool(args.stress) + ["--rt"] * bool(args.rt) + \
        ["--no-plots"] * bool(args.no_plots)
    rc = _maybe_in_uml(args, argv)
    if rc is not None:
        return rc
    args.out = str(out)
    report = run_bench(args)
    plots = [] if args.no_plots else write_plots(report, out)
    public = _public(report)
    public["plots"] = [str(out / p) for p in plots]
    public["problems"] = check_figures(public, args.parts)
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(public, indent=2, allow_nan=False) + "\n")
    print(format_table(public))
    for p in public["problems"]:
        print(f"  missing or odd figure: {p}")
    print(f"JSON: {json_path}" + (f"; plots: {', '.join(plots)} in {out}" if plots else ""))
    return 1 if public["problems"] else 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=float, default=60.0,
                   help="seconds of the real-time run (default 60)")
    p.add_argument("--lockstep-duration", type=float, default=60.0,
                   help="simulated seconds of the lockstep run (default 60)")
    p.add_argument("--vehicle", default="orel", help="vehicle of the generated scenario")
    p.add_argument("--out", default="runs/bench", metavar="DIR",
                   help="folder for the runs and plots (default runs/bench)")
    p.add_argument("--json", metavar="FILE", help="JSON report (default DIR/bench.json)")
    p.add_argument("--stress", action="store_true",
                   help="add one CPU hog process per CPU while measuring")
    p.add_argument("--rt", action="store_true",
                   help="ask for SCHED_FIFO for the processes (reported when refused)")
    p.add_argument("--pings", type=int, default=1000, help="frames of the bus ping-pong")
    p.add_argument("--alloc-ticks", type=int, default=1000,
                   help="LP problems for the allocator comparison")
    p.add_argument("--bitrate", type=int, default=None,
                   help="bit rate for the bus load (default the catalog's)")
    p.add_argument("--parts", default=",".join(PARTS),
                   help=f"comma list of the parts to measure (default {','.join(PARTS)})")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--interface", default="socketcan", help=argparse.SUPPRESS)
    p.add_argument("--channel", default="vcan0", help="SocketCAN channel (default vcan0)")
    p.set_defaults(func=_cmd_bench)


def register(sub) -> None:
    p = sub.add_parser("bench", help="timing figures over the bus: jitter, compute, latency, "
                                     "lockstep speed, allocator, bus load")
    add_arguments(p)


def main(argv: list[str] | None = None) -> int:
    """``python -m hil.bench bench ...`` (what ``hil bench`` runs; also the UML re-run)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["_echo"]:  # the peer process of ping_pong
        echo(argv[1], int(argv[2]), rt="--rt" in argv)
        return 0
    from hil.cli import main as cli_main

    return cli_main(argv)

if __name__ == "__main__":
    sys.exit(main())
