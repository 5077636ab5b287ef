"""Allocation time per tick (seed 004 LP + scaling + quantisation) on a stream of demands.

Prints p50 / p99 / max per allocation for each solver and ``scipy.optimize.linprog`` (HiGHS) on
the same LP problems in the same run, and the ratio. Garbage collection as in the flight process
(``hil.process_policy.quiet_gc``/``idle_gc``: collected every 10 ticks outside the timed
call). Vehicle:
``orel`` (30 thrusters) when its file exists, else a synthetic 30-thruster set. A figure, not a
test: nothing here fails on speed.
``hil bench`` reports the same comparison (``hil.bench.compare_allocator``, the same demands).

    .venv/bin/python bench/bench_allocator.py [--ticks 2000] [--vehicle orel]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from flight.allocator import Allocator  # noqa: E402
from flight.lp import linprog_solve  # noqa: E402
from hil.bench import demand_stream  # noqa: E402
from hil.config import VEHICLE_DIR, load_vehicle  # noqa: E402
from hil.process_policy import idle_gc, quiet_gc  # noqa: E402


def _synthetic():
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "flight"))
    from test_allocator import synthetic_vehicle

    return synthetic_vehicle()


def stats(t_s: list[float]) -> tuple[float, float, float]:
    a = np.array(t_s) * 1e6
    return float(np.percentile(a, 50)), float(np.percentile(a, 99)), float(a.max())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ticks", type=int, default=2000)
    ap.add_argument("--vehicle", default="orel")
    args = ap.parse_args()
    if (VEHICLE_DIR / f"{args.vehicle}.yaml").exists():
        vehicle = load_vehicle(args.vehicle)
    else:
        print(f"{args.vehicle}.yaml not found: synthetic 30-thruster set")
        vehicle = _synthetic()
    problems = list(demand_stream(args.ticks))
    quiet_gc()
    ref = Allocator(vehicle, solver="simplex")
    times: dict[str, list[float]] = {}
    statuses: dict[str, int] = {}
    for solver in ("simplex", "highs"):
        alloc = Allocator(vehicle, solver=solver)
        ts = times[solver] = []
        for k, (lo, hi) in enumerate(problems):
            t0 = time.perf_counter()
            a = alloc.allocate(lo, hi)
            ts.append(time.perf_counter() - t0)
            idle_gc(k)
            if solver == "simplex":
                statuses[a.status] = statuses.get(a.status, 0) + 1
    # linprog on the same (scaled) LPs, the first solve of each tick.
    ts = times["linprog"] = []
    cols = np.arange(ref.n)
    rs = ref._row_scale6[:3]
    A, c = ref._A6[:3], ref._c
    ub = np.full(ref.n, ref.tau_max_s / ref.h_s)
    lp_only = []
    for k, (lo, hi) in enumerate(problems):
        idle_gc(k)
        t0 = time.perf_counter()
        linprog_solve(A, c, lo / rs, hi / rs, ub)
        ts.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        ref._solve_main(3, lo / rs, hi / rs, ub, cols)
        lp_only.append(time.perf_counter() - t0)
    times["simplex LP only"] = lp_only
    print(f"vehicle {vehicle.name}: {ref.n} thrusters, {len(problems)} ticks, statuses {statuses}")
    print(f"{'solver':<18}{'p50 us':>10}{'p99 us':>10}{'max us':>10}")
    for name, t in times.items():
        p50, p99, mx = stats(t)
        print(f"{name:<18}{p50:10.1f}{p99:10.1f}{mx:10.1f}")
    lp50 = stats(times["linprog"])[0]
    for name in ("simplex", "highs", "simplex LP only"):
        print(f"linprog / {name} (p50): {lp50 / stats(times[name])[0]:.1f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
