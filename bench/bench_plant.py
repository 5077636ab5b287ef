"""Plant speed: simulated seconds per wall-clock second (lockstep use, no bus).

Vehicle ``orel`` (30 thrusters, 2 manifolds; its two flex modes, or two added here if the file
has none), a typical command pattern (every tick a few thrusters pulse with varying durations,
as the phase-plane controller does in a dead zone), the gyro sampled every tick. Prints the step,
the figures and the machine. A benchmark prints; it asserts nothing (docs/style.md habit 8).

    .venv/bin/python bench/bench_plant.py [--vehicle orel] [--seconds 120] [--steps 0.01 0.001]
                                          [--repeat 5]

With ``--repeat N`` each step is run N times and the best and median figures are printed (the
machine is shared: single runs are noisy).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hil.config import FlexModeCfg, ModeShapeCfg, load_vehicle  # noqa: E402
from plant.core import Plant  # noqa: E402
from plant.thruster import allowed_on_ms  # noqa: E402

DEFAULT_STEP_S = 0.01


def vehicle_with_flex(name: str):
    v = load_vehicle(name)
    if len(v.flex_modes) >= 2:
        return v, "from the vehicle file"
    modes = [
        FlexModeCfg(name="bench_1", freq_hz=0.3, log_decrement=0.04, gyro_phi=(1e-3, 0, 0),
                    default=ModeShapeCfg(f=(0, 2e-4, 0), phi=(1e-3, 0, 0))),
        FlexModeCfg(name="bench_2", freq_hz=0.8, log_decrement=0.05, gyro_phi=(0, 8e-4, 0),
                    default=ModeShapeCfg(f=(2e-4, 0, 0), phi=(0, 8e-4, 0))),
    ]
    return v.model_copy(update={"flex_modes": modes}), "two added by the benchmark"


def run(vehicle, step_s: float, seconds: float, seed: int = 1
        ) -> tuple[float, float, Plant]:
    plant = Plant(vehicle, seed=seed, step_s=step_s)
    n_thr = len(vehicle.thrusters)
    tick = vehicle.timing.tick_s
    allowed = np.array([a for a in allowed_on_ms(vehicle.timing) if a > 0])
    rng = np.random.default_rng(seed)
    ticks = int(round(seconds / tick))
    t0 = time.perf_counter()
    c0 = time.process_time()
    for n in range(ticks):
        t_n = n * tick
        plant.advance_to(t_n)
        plant.gyro_samples_until(t_n)
        on = np.zeros(n_thr)
        on[rng.choice(n_thr, size=4, replace=False)] = rng.choice(allowed, size=4)
        plant.apply_command(n, plant.apply_time(t_n), on)
        plant.pop_tick_records()
    plant.advance_to(ticks * tick)
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    return ticks * tick / wall, ticks * tick / max(cpu, 1e-9), plant


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicle", default="orel")
    ap.add_argument("--seconds", type=float, default=120.0, help="simulated seconds per run")
    ap.add_argument("--steps", type=float, nargs="+", default=[DEFAULT_STEP_S, 0.005, 0.001])
    ap.add_argument("--repeat", type=int, default=1, help="runs per step (best and median)")
    args = ap.parse_args()
    v, flex_src = vehicle_with_flex(args.vehicle)
    print(f"machine: {platform.machine()} {platform.processor() or ''} cpus={os.cpu_count()} "
          f"python {platform.python_version()} numpy {np.__version__} {platform.system()}")
    print(f"vehicle: {v.name}, {len(v.thrusters)} thrusters, {len(v.manifolds)} manifolds, "
          f"{len(v.flex_modes)} flex modes ({flex_src}), gravity gradient "
          f"{v.orbit.gravity_gradient}, gyro {v.gyro.rate_hz:g} Hz")
    if hasattr(os, "getloadavg"):
        print("load average before: " + " ".join(f"{x:.2f}" for x in os.getloadavg()))
    print("pattern: every 0.2 s tick, 4 random thrusters pulse 30..200 ms; run "
          f"{args.seconds:g} s simulated")
    for h in args.steps:
        run(v, h, 2.0)  # warm up
        runs = [run(v, h, args.seconds) for _ in range(max(1, args.repeat))]
        rate, rate_cpu, plant = max(runs, key=lambda r: r[0])
        tag = " (default)" if h == DEFAULT_STEP_S else ""
        print(f"step {h * 1000:g} ms{tag}: {rate:8.1f} x real time (wall), {rate_cpu:8.1f} x per "
              f"CPU second  ({plant.counters['steps'] / (args.seconds / rate) / 1000:.1f} k "
              f"steps/s wall; fuel {plant.truth.fuel_total_kg:.3f} kg)")
        if len(runs) > 1:
            med_wall = statistics.median(r[0] for r in runs)
            med_cpu = statistics.median(r[1] for r in runs)
            print(f"    (best of {len(runs)} runs; median {med_wall:8.1f} x real time (wall), "
                  f"{med_cpu:8.1f} x per CPU second)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
