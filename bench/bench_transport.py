"""Cost of the bus transport per message: python-can's send/recv path against the direct path.

    hil vcan exec -- .venv/bin/python bench/bench_transport.py [--n 500]

Two ``Port`` objects on vcan0 in one process: one sends THR_CMD (5 frames), GYRO (2 frames)
and SYNC (1 frame), the other polls them. Each figure is measured twice: through python-can's
``send``/``recv`` of its own ``socketcan`` backend (a ``select`` and clock reads per frame) and
through this project's backend ``bus.socketcan_fast`` that ``bus.transport.open_bus`` opens for
socketcan (one system call per message, one ``select`` per poll).
Under user-mode Linux every system call costs tens of microseconds, so the difference is most
of the per-tick bus cost there. A benchmark prints figures; it asserts nothing.
"""

from __future__ import annotations

import argparse
import sys
import time

import can
import numpy as np

from bus.codec import Gyro, Sync, ThrCmd
from bus.transport import BusConfig, Port, open_bus
from hil.uml import in_uml


def _open(path: str, channel: str) -> can.BusABC:
    if path == "direct":
        return open_bus(BusConfig(channel=channel))
    return can.Bus(interface="socketcan", channel=channel)  # python-can's own backend


def measure(channel: str = "vcan0", n: int = 500) -> dict[str, dict[str, float]]:
    """{path: {figure: p50 microseconds}} for path in ("python-can", "direct")."""
    msgs = {"THR_CMD": ThrCmd(1, (3,) * 30, 3, 7), "GYRO": Gyro(7, (1e-3, -2e-3, 3e-3)),
            "SYNC": Sync(1, 200)}
    out: dict[str, dict[str, float]] = {}
    for path in ("python-can", "direct"):
        # "python-can": python-can's own SocketcanBus (its send/recv); "direct": this project's
        # backend with batch frame I/O (bus.socketcan_fast).
        tx = Port(_open(path, channel))
        rx = Port(_open(path, channel))
        res: dict[str, float] = {}
        try:
            for name, msg in msgs.items():
                t_send, t_poll = [], []
                for _ in range(n):
                    t0 = time.perf_counter_ns()
                    tx.send(msg)
                    t1 = time.perf_counter_ns()
                    got = rx.poll(0.5)
                    t2 = time.perf_counter_ns()
                    if got:
                        t_send.append(t1 - t0)
                        t_poll.append(t2 - t1)
                res[f"send {name} us"] = float(np.percentile(t_send, 50)) / 1e3
                res[f"poll {name} us"] = float(np.percentile(t_poll, 50)) / 1e3
        finally:
            tx.close()
            rx.close()
        out[path] = res
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--channel", default="vcan0")
    args = ap.parse_args(argv)
    res = measure(args.channel, args.n)
    print(f"Port cost per message (p50, microseconds), socketcan {args.channel}, "
          f"{'user-mode Linux' if in_uml() else 'native kernel'}")
    names = list(res["direct"])
    print(f"  {'figure':<16}{'python-can':>12}{'direct':>10}")
    for k in names:
        print(f"  {k:<16}{res['python-can'][k]:12.1f}{res['direct'][k]:10.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
