"""Whole flight tick compute time (all stages), closed loop with the plant core, no bus.

    .venv/bin/python bench/bench_flight_tick.py [--vehicles orel iss_rs] [--seconds 120]

Prints p50/p99/max per stage and for the whole tick, and the share of the tick used. The
plant runs in the same process (its time is not counted). Garbage collection as in the flight
process (``hil.process_policy.quiet_gc``/``idle_gc``: start-up frozen, collected every 10 ticks
after the tick); ``--auto-gc`` keeps Python's automatic collection to show what that costs. A
benchmark, not a test.
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import time

import numpy as np

from flight.software import FlightSoftware
from hil.config import AttitudeCfg, InitialCfg, load_vehicle
from hil.process_policy import idle_gc, quiet_gc
from plant.core import Plant


def run(name: str, seconds: float, auto_gc: bool = False) -> None:
    v = load_vehicle(name)
    h = v.timing.tick_s
    initial = InitialCfg(attitude=AttitudeCfg(axis=(1.0, 0.5, 0.2), angle_deg=3.0),
                         rate_B_deg_s=(0.02, -0.01, 0.01))
    plant = Plant(v, seed=1, initial=initial)
    fs = FlightSoftware(v, initial_attitude=initial.attitude)
    if auto_gc:
        gc.enable()
    else:
        quiet_gc()
    stages: dict[str, list[float]] = {s: [] for s in ("read", *fs.STAGES)}
    total: list[float] = []
    clk = time.perf_counter_ns
    pending: list = []
    for n in range(int(seconds / h)):
        t_n = n * h
        samples = pending + plant.advance_to(t_n)
        omega = np.asarray(samples[-1].rate_B_rad_s) if samples else np.zeros(3)
        pending = []
        t0 = clk()
        fs.begin(n, omega)
        stages["read"].append(clk() - t0)
        for s in fs.STAGES:
            t1 = clk()
            getattr(fs, "stage_" + s)()
            stages[s].append(clk() - t1)
        out = fs.finish()
        total.append(clk() - t0)
        if not auto_gc:
            idle_gc(n)  # after the tick, as the flight process does
        plant.apply_command(n, t_n, out.on_ms, out.manifold_open)
        pending = plant.advance_to(t_n + h)
    skip = 10  # first ticks include imports and solver warm-up
    print(f"\n{name}: {len(total)} ticks ({seconds:g} s simulated), {len(v.thrusters)} thrusters")
    print(f"  {'stage':<12}{'p50 ms':>10}{'p99 ms':>10}{'max ms':>10}")
    for s, vals in [*stages.items(), ("whole tick", total)]:
        a = np.asarray(vals[skip:]) / 1e6
        print(f"  {s:<12}{np.percentile(a, 50):10.3f}{np.percentile(a, 99):10.3f}{a.max():10.3f}")
    a = np.asarray(total[skip:]) / 1e6
    print(f"  share of the {h * 1e3:.0f} ms tick at p99: {np.percentile(a, 99) / (h * 1e3):.2%}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--vehicles", nargs="+", default=["orel", "iss_rs"])
    p.add_argument("--seconds", type=float, default=120.0)
    p.add_argument("--auto-gc", action="store_true",
                   help="Python's automatic garbage collection instead of the flight's policy")
    args = p.parse_args()
    print(f"machine: {platform.machine()} {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}, "
          f"python {platform.python_version()}")
    for name in args.vehicles:
        run(name, args.seconds, args.auto_gc)


if __name__ == "__main__":
    main()
