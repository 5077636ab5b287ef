"""A small flight-side peer for integration tests and the bus benchmark.

``python -m bus.echo_peer --interface socketcan --channel vcan0 --ticks 50``

* ``lockstep`` mode: answers every SYNC(n) with THR_CMD(n) = ``expected_command(n)`` through
  a ``Port`` and ``FlightLockstep``; with ``--corrupt-tick K`` it first sends one THR_CMD
  frame of tick K with a flipped bit (the receiver must count it as bad_crc and still get the
  valid set). Stops after tick ``ticks - 1`` or ``--idle-s`` without traffic.
* ``ping`` mode: sends every frame with id ``PING_ID`` straight back as ``PONG_ID`` (raw, for
  latency measurements), stops on ``STOP_ID``.

Prints ``ready`` once the bus is open, and one JSON line of counters at the end.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import can

from bus.catalog import ALLOWED_ON_QUANTA
from bus.codec import Frame
from bus.protocol import FlightLockstep, TickRequest
from bus.transport import BusConfig, Port, open_bus

PING_ID = 0x7E0
PONG_ID = 0x7E1
STOP_ID = 0x7E2
N_THRUSTERS = 30


def expected_command(tick: int, n_thrusters: int = N_THRUSTERS) -> tuple[tuple[int, ...], int, int]:
    """(on_quanta, manifold_enable, gyro_seq) the peer sends for ``tick`` (deterministic)."""
    q = tuple(
        ALLOWED_ON_QUANTA[(tick + 3 * i) % len(ALLOWED_ON_QUANTA)] for i in range(n_thrusters)
    )
    return q, tick % 16, (10 * tick) % 65536


def run_lockstep(
    port: Port, ticks: int, corrupt_tick: int | None = None, idle_s: float = 5.0,
    whole_sets: bool = False,
) -> dict:
    """Answer SYNC(n) with THR_CMD(n) until tick ``ticks - 1``. At ``corrupt_tick`` frame 2
    of the command goes out with a flipped bit and then intact (CAN); with ``whole_sets``
    (LCM, where a set travels as one message) the set goes with the bad frame, then the
    command again with the next counters."""
    fl = FlightLockstep()
    last_rx = time.monotonic()
    replied = 0
    while True:
        got = port.poll(0.05)
        if got:
            last_rx = time.monotonic()
        elif time.monotonic() - last_rx > idle_s:
            break
        done = False
        for msg, rx_s in got:
            for ev in fl.on_message(msg, rx_s):
                if not isinstance(ev, TickRequest):
                    continue
                q, mask, seq = expected_command(ev.tick)
                cmd = fl.reply(ev.tick, q, mask, seq)
                frames = port.protect(cmd)
                for i, fr in enumerate(frames):
                    if ev.tick == corrupt_tick and i == 2:
                        bad = bytearray(fr.data)
                        bad[4] ^= 0x10
                        port.send_frame(Frame(fr.arbitration_id, bytes(bad)))
                        if whole_sets:  # LCM carries sets: this one goes with the bad frame
                            continue
                    port.send_frame(fr)
                if whole_sets and ev.tick == corrupt_tick:
                    port.send(cmd)  # then the whole command again, with the next counters
                replied += 1
                if ev.tick >= ticks - 1:
                    done = True
        if done:
            break
    return {
        "replied": replied,
        **port.counts(),
        "sync_gaps": fl.gaps,
        "sync_duplicates": fl.duplicates,
    }


def run_ping(bus: can.BusABC, idle_s: float = 5.0) -> dict:
    """Echo PING as PONG. A PING carries the sender's ``time.time_ns()`` (8 bytes, little
    endian); the one-way latency sender-send -> our recv is measured in CLOCK_REALTIME, which
    both processes share on one kernel."""
    echoed = 0
    one_way_ns = []
    last_rx = time.monotonic()
    while time.monotonic() - last_rx <= idle_s:
        m = bus.recv(0.05)
        if m is None:
            continue
        now_ns = time.time_ns()
        last_rx = time.monotonic()
        if m.arbitration_id == STOP_ID:
            break
        if m.arbitration_id == PING_ID:
            bus.send(can.Message(arbitration_id=PONG_ID, data=m.data, is_extended_id=False))
            one_way_ns.append(now_ns - int.from_bytes(bytes(m.data), "little"))
            echoed += 1
    return {"echoed": echoed, "one_way_ns": one_way_ns}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bus.echo_peer", description=__doc__.split("\n")[0])
    ap.add_argument("--interface", default="socketcan")
    ap.add_argument("--channel", default="vcan0")
    ap.add_argument("--mode", choices=("lockstep", "ping"), default="lockstep")
    ap.add_argument("--ticks", type=int, default=50)
    ap.add_argument("--corrupt-tick", type=int, default=None)
    ap.add_argument("--idle-s", type=float, default=5.0)
    args = ap.parse_args(argv)
    if args.interface == "lcm":  # LCM: the channel is the provider URL (docs/lcm.md)
        from bus.lcm_transport import LcmPort

        port = LcmPort(args.channel)
        print("ready", flush=True)
        try:
            result = run_lockstep(port, args.ticks, args.corrupt_tick, args.idle_s,
                                  whole_sets=True)
        finally:
            port.close()
        print(json.dumps(result, sort_keys=True), flush=True)
        return 0
    bus = open_bus(BusConfig(interface=args.interface, channel=args.channel))
    print("ready", flush=True)
    try:
        if args.mode == "ping":
            result = run_ping(bus, args.idle_s)
        else:
            port = Port(bus)
            result = run_lockstep(port, args.ticks, args.corrupt_tick, args.idle_s)
    finally:
        bus.shutdown()
    print(json.dumps(result, sort_keys=True), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
