"""Bus benchmark: latency between two OS processes and the catalog's bus load.

    .venv/bin/hil vcan exec -- .venv/bin/python bench/bench_bus.py            # socketcan/vcan0
    .venv/bin/python bench/bench_bus.py --interface virtual                   # no peer process

Figures (a benchmark prints, it asserts nothing):

* raw one-way latency: sender's ``time.time_ns()`` just before ``send`` to the peer's
  ``time.time_ns()`` just after ``recv`` (CLOCK_REALTIME, one kernel, two processes);
* raw round trip: PING -> PONG echoed by the peer, ``time.perf_counter_ns()``
  (CLOCK_MONOTONIC) in the sender;
* lockstep round trip: SYNC(n) sent -> THR_CMD(n) set (5 frames) complete and valid through
  ``Port`` (encode, E2E, classify, assemble on both sides), CLOCK_MONOTONIC;
* bus load of the catalog at 1 Mbit/s (``hil dbc --load``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import can

from bus.catalog import bus_load
from bus.echo_peer import PING_ID, PONG_ID, STOP_ID
from bus.transport import BusConfig, open_bus
from hil.bench import stack_round_trip


def pct(samples_ns: list[int]) -> str:
    s = sorted(samples_ns)
    if not s:
        return "no samples"

    def q(p):
        return s[min(len(s) - 1, int(p * len(s)))] / 1e6

    return f"p50 {q(0.5):.3f} ms, p99 {q(0.99):.3f} ms, max {s[-1] / 1e6:.3f} ms (n={len(s)})"


def start_peer(cfg: BusConfig, mode: str, ticks: int = 0) -> subprocess.Popen:
    p = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "bus.echo_peer",
            "--interface",
            cfg.interface,
            "--channel",
            cfg.channel,
            "--mode",
            mode,
            "--ticks",
            str(ticks),
            "--idle-s",
            "3",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    if p.stdout.readline().strip() != "ready":
        raise SystemExit("bench: echo peer did not start")
    return p


def raw_ping(cfg: BusConfig, n: int) -> tuple[list[int], list[int]]:
    peer = start_peer(cfg, "ping")
    bus = open_bus(cfg)
    rtt = []
    try:
        for _ in range(n):
            t0 = time.perf_counter_ns()
            bus.send(
                can.Message(
                    arbitration_id=PING_ID,
                    is_extended_id=False,
                    data=time.time_ns().to_bytes(8, "little"),
                )
            )
            while True:
                m = bus.recv(2.0)
                if m is None:
                    raise SystemExit("bench: no PONG within 2 s")
                if m.arbitration_id == PONG_ID:
                    break
            rtt.append(time.perf_counter_ns() - t0)
        bus.send(can.Message(arbitration_id=STOP_ID, is_extended_id=False, data=b""))
    finally:
        out, _ = peer.communicate(timeout=30)
        bus.shutdown()
    return json.loads(out.strip().splitlines()[-1])["one_way_ns"], rtt


def lockstep(cfg: BusConfig, n: int) -> list[int]:
    """SYNC -> complete THR_CMD set round trips through ``Port`` (``hil.bench``)."""
    return stack_round_trip(cfg.channel, n)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--interface", default="socketcan")
    ap.add_argument("--channel", default="vcan0")
    ap.add_argument("--n", type=int, default=2000, help="pings and lockstep ticks")
    args = ap.parse_args()
    cfg = BusConfig(interface=args.interface, channel=args.channel)
    if cfg.interface == "virtual":
        print(
            "note: python-can's virtual bus does not cross processes; the peer process "
            "cannot see us. Use socketcan (vcan0) or another interface."
        )
        return 2
    print(f"interface {cfg.interface}, channel {cfg.channel}, two OS processes")
    one_way, rtt = raw_ping(cfg, args.n)
    print(f"raw one-way (CLOCK_REALTIME, send -> peer recv): {pct(one_way)}")
    print(f"raw round trip (CLOCK_MONOTONIC):                {pct(rtt)}")
    ls = lockstep(cfg, args.n)
    print(f"lockstep SYNC -> THR_CMD set (CLOCK_MONOTONIC):  {pct(ls)} (safe replies "
          f"left out: {args.n - len(ls)})")
    rows = bus_load(1_000_000)
    total = sum(r[1] for r in rows)
    print(f"bus load at 1 Mbit/s, nominal cycles: {total:.0f} bit/s = {100 * total / 1e6:.2f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
