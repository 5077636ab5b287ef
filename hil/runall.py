"""`hil run-all`: every reference scenario over the bus, then the report.

``hil run-all [--out DIR] [--mode lockstep|realtime] [--only NAME ...] [--jobs N]`` runs each
scenario of ``configs/scenarios`` (or the ``--only`` ones) through the real flight and plant
processes, exactly as ``hil run`` does, into ``DIR/<scenario>/``, then writes ``DIR/report/``
(``hil report``). Exit 0 only when every scenario's expectations hold, 1 when one does not, 2 on
a usage or configuration error (every scenario file is validated before anything starts).

Where the kernel has no CAN the scenarios run inside user-mode Linux: ``--jobs N`` boots N
user-mode Linux instances side by side (each has one CPU and its own vcan0), each running a
share of the scenarios in turn; natively, ``--jobs`` > 1 would put several lockstep pairs on one
vcan0, so the scenarios run one after the other there. Lockstep results do not depend on the
machine's load (the plant waits for the flight), so parallel runs give the same verdicts.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from hil.config import SCENARIO_DIR, load_scenario
from hil.errors import UsageError
from hil.node_settings import ACTUATION_PHASE_HELP, actuation_phase_ms
from hil.verdict import EXIT_RUN_FAILED

INSIDE_UML_ENV = "HIL_INSIDE_UML"


def scenario_files(only: list[str] | None) -> list[Path]:
    """The reference scenarios, sorted; ``only``: names (stems) to keep, all must exist."""
    files = sorted(SCENARIO_DIR.glob("*.yaml"))
    if not only:
        return files
    by_name = {p.stem: p for p in files}
    missing = [n for n in only if n not in by_name]
    if missing:
        raise UsageError(f"run-all: --only: expected names from {sorted(by_name)}, "
                         f"got {missing}")
    return [by_name[n] for n in only]


def _split(files: list[Path], jobs: int) -> list[list[Path]]:
    """Share the scenarios among ``jobs`` workers, longest first, balancing simulated time."""
    durations = {p: load_scenario(p).cfg.duration_s for p in files}
    groups: list[list[Path]] = [[] for _ in range(max(1, jobs))]
    load = [0.0] * len(groups)
    for p in sorted(files, key=lambda q: -durations[q]):
        k = load.index(min(load))
        groups[k].append(p)
        load[k] += durations[p]
    return [g for g in groups if g]


class Progress:
    """``k/N`` scenarios done and the time left, from the summaries as they appear in
    ``out/<scenario>/`` (written there by this process or by user-mode Linux instances on the
    shared disk). Time left: the wall time so far times the simulated seconds still to run
    over those done (the lockstep runs at a roughly steady speed)."""

    def __init__(self, files: list[Path], out: Path, t0_wall: float) -> None:
        self.dur = {p.stem: load_scenario(p).cfg.duration_s for p in files}
        self.out, self.t0, self.t0_unix = out, t0_wall, time.time()
        self.done: list[str] = []

    def poll(self) -> list[str]:
        """Lines for the scenarios finished since the last call."""
        lines = []
        for name in self.dur:
            f = self.out / name / "summary.json"
            if name in self.done:
                continue
            try:
                fresh = f.stat().st_mtime >= self.t0_unix - 1
            except OSError:
                continue
            if fresh:
                self.done.append(name)
                lines.append(self.line(name))
        return lines

    def line(self, name: str) -> str:
        done_s = sum(self.dur[n] for n in self.done)
        left_s = sum(self.dur.values()) - done_s
        wall = time.monotonic() - self.t0
        eta = f", about {wall * left_s / done_s:.0f} s left" if left_s > 0 and done_s else ""
        return (f"run-all: {len(self.done)}/{len(self.dur)} done ({name}), {wall:.0f} s wall"
                f"{eta}")


def run_all_bus(args, files: list[Path]) -> str:
    """The one bus of the whole set: ``--bus``, else the scenarios' ``bus:`` (which must
    agree; none names can). Options of the other bus are refused (one line)."""
    buses = {p.stem: load_scenario(p).cfg.bus for p in files}
    kinds = {n: b.kind if b is not None else "can" for n, b in buses.items()}
    kind = args.bus
    if kind is None:
        found = sorted(set(kinds.values()))
        if len(found) > 1:
            by = ", ".join(f"{n}: {k}" for n, k in kinds.items())
            raise UsageError(f"run-all: bus: expected every scenario on one bus (or --bus "
                             f"can|lcm for all), got {by}")
        kind = found[0] if found else "can"
    if kind == "lcm":
        for flag, val in (("--interface", args.interface), ("--channel", args.channel)):
            if val is not None:
                raise UsageError(f"run-all: {flag}: expected no python-can {flag[2:]} with the "
                                 f"lcm bus (--lcm-url names its provider), got {val!r}")
    elif args.lcm_url is not None:
        raise UsageError(f"run-all: --lcm-url: expected it with the lcm bus, got "
                         f"{args.lcm_url!r} with the can bus")
    args.interface = args.interface or "socketcan"
    args.channel = args.channel or "vcan0"
    args.bus_kind = kind
    return kind


def _scenario_args(args, scenario: Path):
    """This scenario's copy of the options: its bus resolved as ``hil run`` does (``--bus``
    and ``--lcm-url`` win over its ``bus:``)."""
    from hil.run import resolve_bus

    a = argparse.Namespace(**vars(args))
    a.telemetry, a.lcm_log = None, False
    if args.bus_kind == "lcm":
        a.interface = a.channel = None  # resolve_bus puts LCM's there
    resolve_bus(a, load_scenario(scenario))
    return a


def _run_here(files: list[Path], out: Path, args, progress: Progress | None = None) -> list[dict]:
    """Run the scenarios one after the other in this process's environment (vcan0 here, or
    the private network namespace of an LCM set)."""
    from hil.run import supervise

    results = []
    for p in files:
        name = p.stem
        t0 = time.monotonic()
        print(f"run-all: {name} ...", flush=True)
        s = supervise(p.resolve(), (out / name).resolve(), _scenario_args(args, p), quiet=True)
        verdict = {"passed": "met", "not_met": "NOT met"}.get(s["verdict"], "RUN FAILED")
        dets = ", ".join(
            f"{d['type']} {d['thruster']} +{d['latency_s']:.1f} s" if d["latency_s"] is not None
            else f"{d['type']} {d['thruster']} (false alarm)" for d in s["detections"]) or "-"
        print(f"run-all: {name}: {verdict}; detections: {dets}; "
              f"{s['speed_x_realtime']}x real time, {time.monotonic() - t0:.0f} s wall",
              flush=True)
        for line in s["run_failures"] + s["expectation_failures"]:
            print(f"run-all:   FAILED: {line}", flush=True)
        results.append(s)
        for line in progress.poll() if progress is not None else []:
            print(line, flush=True)
    return results


def _in_parallel(groups: list[list[Path]], one, files: list[Path], out: Path,
                 t0: float) -> list[int]:
    """``one(group)`` for every group side by side, with the progress of all; exit codes."""
    progress = Progress(files, out, t0)
    with ThreadPoolExecutor(max_workers=len(groups)) as pool:
        running = pool.map(one, groups)
        watcher_halt = threading.Event()

        def watch() -> None:
            while not watcher_halt.wait(1.0):
                for line in progress.poll():
                    print(line, flush=True)

        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
        try:
            codes = list(running)
        finally:
            watcher_halt.set()
            watcher.join(3)
        for line in progress.poll():
            print(line, flush=True)
    return codes


def _child_argv(args, out: Path, group: list[Path]) -> list[str]:
    argv = [sys.executable, "-m", "hil.cli", "run-all", "--out", str(out), "--mode", args.mode,
            "--no-report", "--only", *[p.stem for p in group]]
    if args.bus is not None:
        argv += ["--bus", args.bus]
    if args.rt_priority:
        argv.append("--rt")
    if args.actuation_phase_ms is not None:
        argv += ["--actuation-phase-ms", repr(args.actuation_phase_ms)]
    return argv + (["--lcm-url", args.lcm_url] if args.lcm_url else [])


def _cmd_run_all(args) -> int:
    from hil.netns import NETNS_ENV, run_in_namespace
    from hil.run import _vcan_ready

    if args.jobs < 1:
        raise UsageError(f"run-all: --jobs: expected an integer >= 1, got {args.jobs}")
    files = scenario_files(args.only)
    for p in files:
        load_scenario(p)  # config errors exit 2 before anything starts
    kind = run_all_bus(args, files)
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    needs_uml = (kind == "can" and args.interface == "socketcan"
                 and not os.environ.get(INSIDE_UML_ENV) and not _vcan_ready(args.channel))
    if kind == "lcm" and args.jobs > 1 and not args.no_report:
        # Each share of the set in its own private network namespace (a child run-all that
        # makes its own, hil.netns): runs side by side on one URL cannot hear each other.
        groups = _split(files, args.jobs)
        print(f"hil: {len(files)} scenarios over LCM in {len(groups)} private network "
              f"namespace(s) side by side", flush=True)
        env = {k: v for k, v in os.environ.items() if k != NETNS_ENV}
        codes = _in_parallel(groups, lambda g: subprocess.run(
            _child_argv(args, out, g), env=env, cwd=os.getcwd()).returncode, files, out, t0)
        if any(c not in (0, 1) for c in codes):
            print(f"run-all: a share of the set failed (exit codes {codes})", file=sys.stderr)
    elif kind == "lcm":
        from bus.lcm_transport import DEFAULT_URL

        argv = _child_argv(args, out, files)[3:]
        if not args.no_report:
            argv.remove("--no-report")
        rc = run_in_namespace(argv, args.lcm_url or DEFAULT_URL, cwd=os.getcwd())
        if rc is not None:
            return rc
        # A share of a bigger set (--no-report): the parent shows the progress of all.
        _run_here(files, out, args, None if args.no_report else Progress(files, out, t0))
    elif needs_uml:
        from hil.uml import run_in_uml

        groups = _split(files, args.jobs)
        print(f"hil: this kernel has no CAN; {len(files)} scenarios in {len(groups)} user-mode "
              f"Linux instance(s) (real vcan0 in each)", flush=True)
        env = dict(os.environ, **{INSIDE_UML_ENV: "1"})
        codes = _in_parallel(groups, lambda g: run_in_uml(_child_argv(args, out, g), env=env,
                                                          cwd=os.getcwd()), files, out, t0)
        if any(c not in (0, 1) for c in codes):
            print(f"run-all: a user-mode Linux instance failed (exit codes {codes})",
                  file=sys.stderr)
    else:
        # Inside a UML instance of a bigger run-all the host shows the progress of all.
        _run_here(files, out, args,
                  None if os.environ.get(INSIDE_UML_ENV) else Progress(files, out, t0))
    if args.no_report:
        import json

        from hil.verdict import EXIT_CODES, judge_summary

        verdicts = [judge_summary(json.loads((out / p.stem / "summary.json").read_text()))[0]
                    if (out / p.stem / "summary.json").exists() else "run_failed"
                    for p in files]
        return max(EXIT_CODES[v] for v in verdicts)
    from hil.report import write_report

    missing = [p.stem for p in files if not (out / p.stem / "summary.json").exists()]
    runs = [out / p.stem for p in files if p.stem not in missing]
    if not runs:
        print("run-all: no scenario produced a summary", file=sys.stderr)
        return EXIT_RUN_FAILED
    print(f"run-all: building the report of {len(runs)} run(s) (plots per run) ...", flush=True)
    res = write_report(runs, out / "report")
    print(f"run-all: {len(runs)} scenario(s) in {time.monotonic() - t0:.0f} s wall; report in "
          f"{out / 'report' / 'report.md'}")
    for name in missing:
        print(f"run-all: {name}: no summary (the run did not finish)", file=sys.stderr)
    ok = res.all_met and not missing
    print(f"run-all: every expectation {'holds' if ok else 'does NOT hold'}")
    if missing or res.run_failed:
        return EXIT_RUN_FAILED
    return 0 if ok else 1


def register(sub) -> None:
    p = sub.add_parser("run-all", help="run every reference scenario over the bus, then report",
                       description=__doc__.split("\n\n")[1])
    p.add_argument("--out", metavar="DIR", default="runs/all",
                   help="output folder (default runs/all): DIR/<scenario>/ and DIR/report/")
    p.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    p.add_argument("--only", nargs="+", metavar="NAME", help="scenario names (file stems)")
    p.add_argument("--jobs", type=int, default=1,
                   help="user-mode Linux instances side by side (no-CAN kernels), or private "
                        "network namespaces over LCM")
    p.add_argument("--no-report", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--interface", help="python-can interface (default socketcan)")
    p.add_argument("--channel", help="bus channel (default vcan0)")
    p.add_argument("--bus", choices=("can", "lcm"),
                   help="the bus of every scenario: can (--interface/--channel) or lcm (in a "
                        "private network namespace; with --jobs N, N of them side by side); "
                        "default: the scenarios' bus:, else can")
    p.add_argument("--lcm-url", metavar="URL",
                   help="LCM provider with the lcm bus (default udpm://239.255.76.67:7667?ttl=0)")
    p.add_argument("--rt", dest="rt_priority", action="store_true",
                   help="ask SCHED_FIFO and locked memory for flight (50) and plant (40)")
    p.add_argument("--actuation-phase-ms", type=actuation_phase_ms, metavar="MS",
                   help=ACTUATION_PHASE_HELP)
    p.set_defaults(func=_cmd_run_all)
