"""Campaign throughput: runs per minute and simulated seconds per wall second per core.

For each vehicle, the first ``--runs`` runs of its shipped fault-free envelope campaign
(``configs/campaigns/<vehicle>-envelope.yaml``: thrust, direction and latency errors, random
initial attitude and rate; ``--duration`` overrides the runs' length) are computed with 1 worker
(this process, as ``--workers 1``) and with 2 workers (an embedded LocalCluster of 2
single-threaded worker processes, as ``--workers 2``). The clock runs from the first task
submitted to the last row back: the cluster's start is printed apart; each worker's first task
includes its imports. The ratio of the two rates shows the scaling. A benchmark prints; it
asserts nothing (docs/style.md habit 8). The machine's load (``os.getloadavg``) is printed before
and after: on a shared machine the figures move with it.

    .venv/bin/python bench/bench_campaign.py [--vehicles generic kalman_cube orel iss_rs]
                                             [--runs 20] [--duration 60] [--workers 1 2]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hil.campaign.engine import Executor, Task, run_task  # noqa: E402
from hil.campaign.expansion import expand_run  # noqa: E402
from hil.campaign.load import load_campaign  # noqa: E402
from hil.config import CONFIG_DIR  # noqa: E402


def _campaign(vehicle: str, runs: int, duration: float | None, tmp: Path):
    src = CONFIG_DIR / "campaigns" / f"{vehicle}-envelope.yaml"
    data = yaml.safe_load(src.read_text())
    data["runs"] = runs
    if duration is not None:
        data["duration_s"] = duration
    p = tmp / f"{vehicle}.yaml"
    p.write_text(yaml.safe_dump(data))
    return load_campaign(p)


def measure(vehicle: str, runs: int, duration: float | None, workers: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        c = _campaign(vehicle, runs, duration, Path(tmp))
        tasks = [Task(expand_run(c, k)) for k in range(runs)]
        sim_s = sum(t.spec.scenario["duration_s"] for t in tasks)
        t_start = time.perf_counter()
        with Executor(workers=workers) as ex:
            started = time.perf_counter() - t_start
            t0 = time.perf_counter()
            rows = list(ex.map(run_task, tasks))
            wall = time.perf_counter() - t0
        failed = sum(r["verdict"] in ("error", "incomplete") for r in rows)
    return {"vehicle": vehicle, "workers": workers, "runs": len(rows), "failed": failed,
            "sim_s": sim_s, "wall_s": wall, "start_s": started,
            "runs_per_min": 60.0 * len(rows) / wall,
            "sim_per_wall_per_core": sim_s / wall / workers,
            "task_mean_s": sum(r["wall_s"] for r in rows) / len(rows),
            "task_cpu_s": sum(r["cpu_s"] for r in rows) / len(rows)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", nargs="+", default=["generic", "kalman_cube", "orel",
                                                       "iss_rs"])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--duration", type=float, default=None,
                    help="run length in s (default: the campaign's, 60 s)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}; load average before: "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{'vehicle':12s} {'workers':>7s} {'runs':>5s} {'wall s':>8s} {'runs/min':>9s} "
          f"{'sim s/wall s/core':>18s} {'task wall s':>12s} {'task cpu s':>11s} "
          f"{'cluster start s':>16s}")
    results = []
    for v in args.vehicles:
        for w in args.workers:
            r = measure(v, args.runs, args.duration, w)
            results.append(r)
            print(f"{v:12s} {w:7d} {r['runs']:5d} {r['wall_s']:8.1f} {r['runs_per_min']:9.1f} "
                  f"{r['sim_per_wall_per_core']:18.1f} {r['task_mean_s']:12.3f} "
                  f"{r['task_cpu_s']:11.3f} "
                  f"{r['start_s']:16.1f}" + (f"  ({r['failed']} failed)" if r["failed"] else ""),
                  flush=True)
        by_w = {r["workers"]: r for r in results if r["vehicle"] == v}
        if 1 in by_w and 2 in by_w:
            ratio = by_w[2]["runs_per_min"] / by_w[1]["runs_per_min"]
            print(f"{'':12s} scaling 1 -> 2 workers: x{ratio:.2f}")
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
