"""Time from a fault request to the plant's FAULT_ACK, against a running `hil up`.

    .venv/bin/hil up --out runs/up &                 # (user-mode Linux where no CAN)
    .venv/bin/python bench/bench_fault_ack.py --run runs/up [--via run|bus] [--n 10]

Each round injects a fail-to-fire on the first thruster, then clears it, through
``hil.panel.deliver`` (the path of `hil fault`, without its process start-up) and prints
the times to each FAULT_ACK: p50 and max, and the bridge's own bus share when the request
went through the run folder. Never run as a test.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hil.panel import _request_id, build_command, deliver, resolve_vehicle  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--run", default="runs/up")
    p.add_argument("--via", default="auto", choices=("auto", "run", "bus"))
    p.add_argument("--interface", default="socketcan")
    p.add_argument("--channel", default="vcan0")
    p.add_argument("--n", type=int, default=10)
    a = p.parse_args()
    run = Path(a.run)
    v, _ = resolve_vehicle(None, run)
    first = v.thrusters[0].name
    times = []
    for _ in range(a.n):
        for action, kind in (("inject", "fail_to_fire"), ("clear", None)):
            cmd = build_command(v, action, first, kind, None, None, None, _request_id())
            t0 = time.monotonic()
            deliver(cmd, run, a.via, a.interface, a.channel, 5.0)
            times.append(time.monotonic() - t0)
    ms = sorted(t * 1e3 for t in times)
    print(f"FAULT_CMD -> FAULT_ACK via {a.via} ({len(ms)} requests): p50 "
          f"{statistics.median(ms):.1f} ms, max {ms[-1]:.1f} ms, min {ms[0]:.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
