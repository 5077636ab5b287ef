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
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from hil.bench_bus import measure_bus
from hil.bench_plots import write_plots
from hil.bench_table import DEFAULT_PARTS, PARTS, check_figures, format_table, goals
from hil.errors import UsageError
from hil.flood import CLASSES as FLOOD_CLASSES
from hil.hostile import DEFAULT_LOADS as DEFAULT_HOSTILE_LOADS
from hil.process_policy import sched_policy, where_here
from hil.timing import STAGE_GROUPS, lockstep_figures, realtime_figures, stats_ms

HOST_LOAD_ENV = "HIL_BENCH_HOST_LOAD"  # the host's load average, for a run inside UML
DEFAULT_PINGS = 1000
# ============================================================================ pure figures


def bus_load_figures(bitrate_bps: int) -> dict[str, Any]:
    from bus.catalog import bus_load

    rows = bus_load(bitrate_bps)
    total = sum(r[1] for r in rows)
    return {"bitrate_bps": bitrate_bps, "total_bps": round(total, 1),
            "fraction": round(total / bitrate_bps, 6),
            "frames": [{"name": n, "bps": round(b, 1), "fraction": round(f, 6)}
                       for n, b, f in rows]}


# ============================================================================ measurements


@contextlib.contextmanager
def own_policy(policy: int) -> Iterator[str]:
    """Run the block with this process's scheduler policy set (restored after)."""
    try:
        old = os.sched_getscheduler(0), os.sched_getparam(0)
    except (OSError, AttributeError):
        yield sched_policy()
        return
    try:
        os.sched_setscheduler(0, policy, os.sched_param(0))
    except (PermissionError, OSError):
        pass
    try:
        yield sched_policy()
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
                            rt_priority=args.rt,
                            telemetry=args.channel if args.interface == "lcm" else None)
    summary = supervise(path, out, ns, quiet=True)
    return (summary, list(read_jsonl(out / "plant.jsonl")),
            list(read_jsonl(out / "flight.jsonl")))


def _bus_where(summary: dict) -> dict[str, str]:
    """The bus a run went over (an LCM run names its URL)."""
    if summary.get("bus_kind") == "lcm":
        return {"bus": f"lcm {summary.get('lcm_url')}"}
    return {"bus": "can"}


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
               where={**where_here(), **_bus_where(summary),
                      "sched": {**_node_sched(plant, flight), "supervisor": sup},
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
               where={**where_here(), **_bus_where(summary),
                      "sched": {**_node_sched(plant, flight), "supervisor": sup},
                      "clock": "CLOCK_MONOTONIC"},
               run_dir=str(out))
    return fig


def measure_hostile_part(args, out: Path) -> dict[str, Any]:
    """The fuzz-and-flood campaign (``hil.hostile``) on the bench's scenario."""
    from hil.hostile import measure_hostile

    sc = bench_scenario(args.vehicle, args.hostile_duration, "bench-hostile")
    where = {**where_here(), "clock": "CLOCK_MONOTONIC"}
    with own_policy(os.SCHED_BATCH) as sup:
        where["sched"] = {"supervisor": sup}
        return measure_hostile(args, out, sc, where)


# -- bus latency: raw frames ping-pong between two processes (was bench_vcan_latency.py)
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
                                    "where": {**where_here(), "sched": sched_policy(),
                                              "clock": "CLOCK_MONOTONIC (perf_counter)"}}),
             ("load", lambda: bus_load_figures(args.bitrate)),
             ("hostile", lambda: measure_hostile_part(args, out / "hostile"))]
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


# Over LCM: the runs and the allocator; the raw-frame ping-pong and the bus load are CAN's
# (bench/bench_lcm.py measures LCM's latency).
LCM_PARTS = ("realtime", "lockstep", "allocator")
DEFAULT_HOSTILE_DURATION_S = 20.0


def _parse_parts(text: str | None, bus: str = "can") -> tuple[str, ...]:
    if text is None:
        return LCM_PARTS if bus == "lcm" else DEFAULT_PARTS
    parts = tuple(p.strip() for p in text.split(",") if p.strip())
    bad = [p for p in parts if p not in PARTS]
    if bad or not parts:
        raise UsageError(f"hil bench: --parts: expected a comma list of {', '.join(PARTS)}, "
                         f"got {text!r}")
    if bus == "lcm" and set(parts) - set(LCM_PARTS):
        raise UsageError(f"hil bench: --parts: expected {', '.join(LCM_PARTS)} with --bus lcm "
                         f"(bus and load measure CAN; bench/bench_lcm.py measures LCM), got "
                         f"{text!r}")
    return parts


def _check_bus(args) -> None:
    """--bus lcm: the CAN-only options refused (one line), LCM's URL as the channel."""
    if args.bus != "lcm":
        if args.lcm_url is not None:
            raise UsageError(f"hil bench: --lcm-url: expected it with --bus lcm, got "
                             f"{args.lcm_url!r} with the can bus")
        args.channel = args.channel or "vcan0"
        return
    for flag, val in (("--channel", args.channel), ("--pings", args.pings),
                      ("--bitrate", args.bitrate)):
        if val is not None:
            raise UsageError(f"hil bench: {flag}: expected it only with the can bus (the "
                             f"ping-pong and the bus load are CAN's), got {val!r} with --bus lcm")
    from bus.lcm_transport import DEFAULT_URL

    args.interface, args.channel = "lcm", args.lcm_url or DEFAULT_URL


def _check_args(args) -> None:
    if args.bitrate is None:
        from bus.catalog import BITRATE_BPS

        args.bitrate = BITRATE_BPS
    if args.pings is None:
        args.pings = DEFAULT_PINGS
    if "hostile" not in args.parts:
        for flag, val in (("--hostile-loads", args.hostile_loads),
                          ("--hostile-duration", args.hostile_duration),
                          ("--hostile-sender", args.hostile_sender)):
            if val is not None:
                raise UsageError(f"hil bench: {flag}: expected it only with --parts hostile, "
                                 f"got {val!r} with --parts {','.join(args.parts)}")
    if args.hostile_loads is None:
        args.hostile_loads = ",".join(DEFAULT_HOSTILE_LOADS)
    if args.hostile_duration is None:
        args.hostile_duration = DEFAULT_HOSTILE_DURATION_S
    if args.hostile_sender is None:
        args.hostile_sender = "auto"
    for name, value, lo in (("--duration", args.duration, 2.0),
                            ("--lockstep-duration", args.lockstep_duration, 1.0),
                            ("--hostile-duration", args.hostile_duration, 2.0),
                            ("--pings", args.pings, 10), ("--alloc-ticks", args.alloc_ticks, 10),
                            ("--bitrate", args.bitrate, 1)):
        if not (math.isfinite(value) and value >= lo):
            raise UsageError(f"hil bench: {name}: expected a finite number >= {lo:g}, got "
                             f"{value:g}")
    if "hostile" in args.parts:
        from hil.hostile import parse_loads

        parse_loads(args.hostile_loads)
    from hil.config import VEHICLE_DIR

    if not (VEHICLE_DIR / f"{args.vehicle}.yaml").exists():
        raise UsageError(f"hil bench: --vehicle: expected one of "
                         f"{sorted(p.stem for p in VEHICLE_DIR.glob('*.yaml'))}, "
                         f"got {args.vehicle!r}")
    if args.interface not in ("socketcan", "lcm"):
        raise UsageError(f"hil bench: --interface: expected socketcan (the bench measures "
                         f"SocketCAN between processes), got {args.interface!r}")


def _maybe_in_uml(args, argv: list[str]) -> int | None:
    """``hil.run.maybe_in_uml`` for this module: re-run ``python -m hil.bench`` inside UML."""
    from hil.run import INSIDE_UML_ENV, _vcan_ready

    if args.interface == "lcm":  # LCM: a private network namespace (hil.netns)
        from hil.netns import run_in_namespace

        return run_in_namespace(argv, args.channel, cwd=os.getcwd())
    if os.environ.get(INSIDE_UML_ENV) or _vcan_ready(args.channel):
        return None
    from hil.uml import run_in_uml

    print("hil: this kernel has no CAN; running inside user-mode Linux (real vcan0 there)",
          flush=True)
    env = dict(os.environ, **{INSIDE_UML_ENV: "1",
                              HOST_LOAD_ENV: f"{os.getloadavg()[0]:.2f}"})
    return run_in_uml([sys.executable, "-m", "hil.bench", *argv], env=env, cwd=os.getcwd())


def _cmd_bench(args) -> int:
    args.parts = _parse_parts(args.parts, args.bus)
    _check_bus(args)
    _check_args(args)
    out = Path(args.out).resolve()
    json_path = Path(args.json).resolve() if args.json else out / "bench.json"
    argv = ["bench", "--out", str(out), "--json", str(json_path), "--duration",
            str(args.duration), "--lockstep-duration", str(args.lockstep_duration),
            "--vehicle", args.vehicle, "--alloc-ticks", str(args.alloc_ticks), "--parts",
            ",".join(args.parts)]
    argv += (["--bus", "lcm", "--lcm-url", args.channel] if args.bus == "lcm" else
             ["--pings", str(args.pings), "--bitrate", str(args.bitrate), "--channel",
              args.channel])
    if "hostile" in args.parts:
        argv += ["--hostile-loads", args.hostile_loads, "--hostile-duration",
                 str(args.hostile_duration), "--hostile-sender", args.hostile_sender]
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
    p.add_argument("--pings", type=int, help=f"frames of the bus ping-pong (default "
                                              f"{DEFAULT_PINGS})")
    p.add_argument("--alloc-ticks", type=int, default=1000,
                   help="LP problems for the allocator comparison")
    p.add_argument("--bitrate", type=int, default=None,
                   help="bit rate for the bus load (default the catalog's)")
    p.add_argument("--parts",
                   help=f"comma list of the parts to measure, of {','.join(PARTS)} (default "
                        f"{','.join(DEFAULT_PARTS)}; with --bus lcm {','.join(LCM_PARTS)})")
    p.add_argument("--hostile-loads", metavar="LOAD,...",
                   help="hostile part: none or CLASS:RATE (frames/s) per run; CLASS one of "
                        f"{', '.join(FLOOD_CLASSES)} (default: {','.join(DEFAULT_HOSTILE_LOADS)})")
    p.add_argument("--hostile-sender", choices=("auto", "kernel", "python"),
                   help="hostile part: who sends the flood (hil flood --sender; default auto: "
                        "the kernel's CAN broadcast manager for the classes that do not "
                        "listen)")
    p.add_argument("--hostile-duration", type=float,
                   help=f"hostile part: seconds of each real-time run (default "
                        f"{DEFAULT_HOSTILE_DURATION_S:g})")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--interface", default="socketcan", help=argparse.SUPPRESS)
    p.add_argument("--channel", help="SocketCAN channel (default vcan0)")
    p.add_argument("--bus", choices=("can", "lcm"), default="can",
                   help="the runs over CAN (default) or over LCM (in a private network "
                        "namespace; parts realtime, lockstep, allocator)")
    p.add_argument("--lcm-url", metavar="URL", help="LCM provider with --bus lcm")
    p.set_defaults(func=_cmd_bench)


def register(sub) -> None:
    import argparse

    summary = ("timing figures over the bus: jitter, compute, latency, lockstep speed, "
               "allocator, bus load")
    p = sub.add_parser("bench", help=summary, description=summary,
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog="""examples:
  hil bench                              every part, orel, 60 s (a few minutes)
  hil bench --parts bus                  vcan0 one way / round trip only
  hil bench --duration 20 --stress --rt  a short run under CPU load, SCHED_FIFO asked
  hil bench --parts hostile              floods, forged and replayed frames, per class and rate
  hil bench --parts hostile --hostile-loads none,catalog-bad-crc:500 --hostile-duration 15

It prints one table and writes runs/bench/bench.json and histograms; exit 0 when every
figure was measured (goals not met are shown, not failed).""")
    add_arguments(p)


def main(argv: list[str] | None = None) -> int:
    """``python -m hil.bench bench ...`` (what ``hil bench`` runs; also the UML re-run)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    from hil.cli import main as cli_main

    return cli_main(argv)

if __name__ == "__main__":
    sys.exit(main())
