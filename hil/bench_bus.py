"""`hil bench`'s bus latency: raw python-can frames ping-pong between two processes (one way
both directions, round trip) and the lockstep exchange through the whole stack (SYNC to a
complete, checked 30-thruster THR_CMD set). ``python -m hil.bench_bus CHANNEL N [--rt]`` is the
echoing peer process.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
from typing import Any

from hil.errors import HilError
from hil.process_policy import sched_policy, where_here
from hil.timing import stats_ms

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


def _set_fifo(rt: bool) -> str:
    if rt:
        with contextlib.suppress(PermissionError, OSError, AttributeError):
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
    return sched_policy()


def echo(channel: str, n: int, rt: bool = False) -> None:
    """Process B: echo every ping with B's send time; print A->B one-way times as JSON."""
    import can

    pol = _set_fifo(rt)
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
    print(json.dumps({"a_to_b_ns": a_to_b, "sched": pol}), flush=True)


def ping_pong(channel: str = "vcan0", n: int = 1000, warmup: int = 50,
              rt: bool = False) -> dict[str, Any]:
    """Round trip and one-way times (ns lists) of ``n`` frames between two processes.

    Process A (this one) sends a frame with its CLOCK_MONOTONIC send time; process B echoes
    it with its own. One kernel, so both processes read the same CLOCK_MONOTONIC: A->B is B's
    receive minus A's send, B->A the reverse, round trip A's receive of the echo minus its
    send. User space to user space (python-can ``send`` to the return of ``recv``).
    """
    import can

    total = n + warmup
    peer = subprocess.Popen([sys.executable, "-m", "hil.bench_bus", channel, str(total)]
                            + (["--rt"] if rt else []), stdout=subprocess.PIPE, text=True)
    try:
        if peer.stdout.readline().strip() != "ready":
            raise HilError("bench: the echo process did not start")
        old = os.sched_getscheduler(0), os.sched_getparam(0)
        pol = _set_fifo(rt)
        bus = can.Bus(interface="socketcan", channel=channel,
                      can_filters=[{"can_id": ECHO_ID, "can_mask": 0x7FF, "extended": False}])
        rtt, b_to_a, lost = [], [], 0
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
                if seq >= warmup:
                    rtt.append(t_rx - t_tx)
                    b_to_a.append(since(t_rx, unpack(msg.data)[1]))
        finally:
            bus.shutdown()
            with contextlib.suppress(PermissionError, OSError):
                os.sched_setscheduler(0, old[0], old[1])
        out, _ = peer.communicate(timeout=30)
    finally:
        if peer.poll() is None:
            peer.kill()
            peer.wait()
    res = json.loads(out.strip().splitlines()[-1])
    return {"rtt_ns": rtt, "a_to_b_ns": res["a_to_b_ns"][warmup:], "b_to_a_ns": b_to_a,
            "lost": lost, "sched": {"A": pol, "B": res["sched"]}}


def stack_round_trip(channel: str = "vcan0", n: int = 300) -> list[int]:
    """SYNC(n) sent -> a complete, checked 30-thruster THR_CMD(n) set back through ``Port``
    on both sides (encode, E2E, classify, assemble), ns, CLOCK_MONOTONIC (was bench_bus)."""
    from bus.codec import ThrCmd
    from bus.protocol import PlantLockstep
    from bus.transport import BusConfig, Port, open_bus

    cfg = BusConfig(interface="socketcan", channel=channel)
    peer = subprocess.Popen([sys.executable, "-m", "bus.echo_peer", "--channel", channel,
                             "--mode", "lockstep", "--ticks", str(n), "--idle-s", "3"],
                            stdout=subprocess.PIPE, text=True)
    rtt: list[int] = []
    try:
        if peer.stdout.readline().strip() != "ready":
            raise HilError("bench: the lockstep echo peer did not start")
        port = Port(open_bus(cfg))
        plant = PlantLockstep(30, reply_timeout_s=2.0)
        try:
            for k in range(n):
                t0 = time.monotonic_ns()
                port.send(plant.begin_tick(k, port.now_s()))
                while plant.result is None:
                    for msg, rx_s in port.poll(0.05):
                        if isinstance(msg, ThrCmd):
                            plant.on_message(msg, rx_s)
                    plant.poll(port.now_s())
                if not plant.result.safe:
                    rtt.append(time.monotonic_ns() - t0)
        finally:
            port.close()
        peer.communicate(timeout=30)
    finally:
        if peer.poll() is None:
            peer.kill()
            peer.wait()
    return rtt


def measure_bus(args) -> dict[str, Any]:
    pp = ping_pong(args.channel, args.pings, warmup=50, rt=args.rt)
    stack = stack_round_trip(args.channel, max(50, args.pings // 4))
    ns = 1e-9
    return {
        "frames": args.pings, "lost": pp["lost"],
        "one_way_ms": {"a_to_b": stats_ms(x * ns for x in pp["a_to_b_ns"]),
                       "b_to_a": stats_ms(x * ns for x in pp["b_to_a_ns"])},
        "round_trip_ms": stats_ms(x * ns for x in pp["rtt_ns"]),
        "stack_round_trip_ms": stats_ms(x * ns for x in stack),
        "clock": "CLOCK_MONOTONIC, one kernel, two processes (user space to user space)",
        "where": {**where_here(), "sched": pp["sched"],
                  "clock": "CLOCK_MONOTONIC"},
        "_series": {"one_way_ms": [x / 1e6 for x in pp["a_to_b_ns"]],
                    "round_trip_ms": [x / 1e6 for x in pp["rtt_ns"]]},
    }


if __name__ == "__main__":  # the peer process of ping_pong
    echo(sys.argv[1], int(sys.argv[2]), rt="--rt" in sys.argv)
