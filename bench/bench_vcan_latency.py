"""Latency between two processes over vcan0 with python-can's socketcan interface.

Run where vcan0 exists, natively or inside user-mode Linux:

    hil vcan exec -- .venv/bin/python bench/bench_vcan_latency.py [-n 2000]

Process A sends N classic CAN frames one at a time (ping-pong, so no queueing), each carrying
a sequence number and A's CLOCK_MONOTONIC send time; process B echoes each with its own send
time. Both processes share one kernel clock, so the one-way times are differences of
timestamps from two processes: A->B (B's receive minus A's send), B->A, and the round trip
(A's receive of the echo minus A's send). Times are user space to user space (python-can
``send`` to the return of ``recv``). Prints p50, p99 and max in milliseconds, and where it
ran. A benchmark prints figures; it asserts nothing. The measurement is
``hil.bench.ping_pong`` (``hil bench`` reports the same figures with the rest).
"""

from __future__ import annotations

import argparse
import sys
import time

import can
import numpy as np

from hil.bench import ping_pong
from hil.uml import in_uml


def stats_ms(values_ns: list[int]) -> str:
    a = np.asarray(values_ns, dtype=float) / 1e6
    return (f"p50 {np.percentile(a, 50):7.3f}  p99 {np.percentile(a, 99):7.3f}  "
            f"max {a.max():7.3f}  (n={a.size})")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=2000, help="frames to measure (default 2000)")
    ap.add_argument("--warmup", type=int, default=50, help="frames not counted (default 50)")
    ap.add_argument("--channel", default="vcan0")
    ap.add_argument("--rt", action="store_true", help="try SCHED_FIFO in both processes")
    args = ap.parse_args(argv)
    where = "user-mode Linux" if in_uml() else "native kernel"
    t_start = time.monotonic()
    r = ping_pong(args.channel, args.n, args.warmup, rt=args.rt)
    elapsed = time.monotonic() - t_start
    print(f"vcan latency, python-can {can.__version__} socketcan on {args.channel}, "
          f"{where}, classic CAN 8-byte frames, ping-pong, {args.n} frames "
          f"(+{args.warmup} warm-up), {elapsed:.2f} s, lost {r['lost']}, "
          f"A {r['sched']['A']}, B {r['sched']['B']}, CLOCK_MONOTONIC")
    print(f"  round trip A->B->A  {stats_ms(r['rtt_ns'])}  ms")
    print(f"  one-way    A->B     {stats_ms(r['a_to_b_ns'])}  ms")
    print(f"  one-way    B->A     {stats_ms(r['b_to_a_ns'])}  ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
