"""Latency between two processes over vcan0 with python-can's socketcan interface.

Run where vcan0 exists, natively or inside user-mode Linux:

    hil vcan exec -- .venv/bin/python bench/bench_vcan_latency.py [-n 2000]

Process A sends N classic CAN frames one at a time (ping-pong, so no queueing), each carrying
a sequence number and A's CLOCK_MONOTONIC send time; process B echoes each with its own send
time. Both processes share one kernel clock, so the one-way times are differences of
timestamps from two processes: A->B (B's receive minus A's send), B->A, and the round trip
(A's receive of the echo minus A's send). Times are user space to user space (python-can
``send`` to the return of ``recv``). Prints p50, p99 and max in milliseconds, and where it
ran. A benchmark prints figures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import can
import numpy as np

from hil.uml import in_uml

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


def echo(channel: str, n: int) -> None:
    """Process B: echo every ping with B's send time; print A->B one-way times as JSON."""
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
    print(json.dumps(a_to_b), flush=True)


def stats_ms(values_ns: list[int]) -> str:
    a = np.asarray(values_ns, dtype=float) / 1e6
    return (f"p50 {np.percentile(a, 50):7.3f}  p99 {np.percentile(a, 99):7.3f}  "
            f"max {a.max():7.3f}  (n={a.size})")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=2000, help="frames to measure (default 2000)")
    ap.add_argument("--warmup", type=int, default=50, help="frames not counted (default 50)")
    ap.add_argument("--channel", default="vcan0")
    ap.add_argument("--echo", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    total = args.n + args.warmup
    if args.echo:
        echo(args.channel, total)
        return 0

    where = "user-mode Linux" if in_uml() else "native kernel"
    peer = subprocess.Popen([sys.executable, __file__, "--echo", "--channel", args.channel,
                             "-n", str(args.n), "--warmup", str(args.warmup)],
                            stdout=subprocess.PIPE, text=True)
    if peer.stdout.readline().strip() != "ready":
        print("error: bench: the echo process did not start", file=sys.stderr)
        return 2
    bus = can.Bus(interface="socketcan", channel=args.channel,
                  can_filters=[{"can_id": ECHO_ID, "can_mask": 0x7FF, "extended": False}])
    rtt, b_to_a, lost = [], [], 0
    t_start = time.monotonic()
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
            if seq >= args.warmup:
                rtt.append(t_rx - t_tx)
                b_to_a.append(since(t_rx, unpack(msg.data)[1]))
    finally:
        bus.shutdown()
    elapsed = time.monotonic() - t_start
    out, _ = peer.communicate(timeout=30)
    a_to_b = json.loads(out.strip().splitlines()[-1])[args.warmup:]

    print(f"vcan latency, python-can {can.__version__} socketcan on {args.channel}, "
          f"{where}, classic CAN 8-byte frames, ping-pong, {args.n} frames "
          f"(+{args.warmup} warm-up), {elapsed:.2f} s, lost {lost}")
    print(f"  round trip A->B->A  {stats_ms(rtt)}  ms")
    print(f"  one-way    A->B     {stats_ms(a_to_b)}  ms")
    print(f"  one-way    B->A     {stats_ms(b_to_a)}  ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
