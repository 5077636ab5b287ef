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
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from hil.config import SCENARIO_DIR, load_scenario
from hil.errors import UsageError
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


def _run_here(files: list[Path], out: Path, args, progress: Progress | None = None) -> list[dict]:
    """Run the scenarios one after the other in this process's environment (vcan0 here)."""
    from hil.run import supervise

    results = []
    for p in files:
        name = p.stem
        t0 = time.monotonic()
        print(f"run-all: {name} ...", flush=True)
        s = supervise(p.resolve(), (out / name).resolve(), args, quiet=True)
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


def _cmd_run_all(args) -> int:
    from hil.run import _vcan_ready

    if args.jobs < 1:
        raise UsageError(f"run-all: --jobs: expected an integer >= 1, got {args.jobs}")
    files = scenario_files(args.only)
    for p in files:
        load_scenario(p)  # config errors exit 2 before anything starts
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    needs_uml = (args.interface == "socketcan" and not os.environ.get(INSIDE_UML_ENV)
                 and not _vcan_ready(args.channel))
    if needs_uml:
        from hil.uml import run_in_uml

        groups = _split(files, args.jobs)
        print(f"hil: this kernel has no CAN; {len(files)} scenarios in {len(groups)} user-mode "
              f"Linux instance(s) (real vcan0 in each)", flush=True)
        env = dict(os.environ, **{INSIDE_UML_ENV: "1"})

        def one(group: list[Path]) -> int:
            argv = [sys.executable, "-m", "hil.cli", "run-all", "--out", str(out), "--mode",
                    args.mode, "--no-report", "--only", *[p.stem for p in group]]
            return run_in_uml(argv, env=env, cwd=os.getcwd())

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
                   help="user-mode Linux instances side by side (no-CAN kernels only)")
    p.add_argument("--no-report", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--interface", default="socketcan", help="python-can interface")
    p.add_argument("--channel", default="vcan0", help="bus channel (default vcan0)")
    p.set_defaults(func=_cmd_run_all)
