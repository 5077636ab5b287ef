"""`hil flood`: a hostile third node on the bus (docs/hostile-bus.md).

``hil flood --class foreign|catalog-bad-crc|catalog-forged --rate HZ --seconds S`` sends
frames at ``rate`` per second for ``seconds`` (0: until stopped) on ``--interface`` /
``--channel`` (vcan0 by default), in bursts of one millisecond's worth (``sendmmsg`` on
SocketCAN), seeded by ``--seed``:

* ``foreign``: identifiers that are not in the catalog, random payloads;
* ``catalog-bad-crc``: the catalog's identifiers with random payloads whose E2E CRC is made
  wrong on purpose (every one is rejected as ``bad_crc``);
* ``catalog-forged``: the catalog's identifiers with a valid E2E CRC and alive counter over a
  random payload: what corruption checks cannot stop (authentication, docs/hostile-bus.md).

It prints the frames sent and the rate reached. Used by the flood measurements (and by hand
next to ``hil up``); it is a test tool, not part of a run.
"""

from __future__ import annotations

import signal
import sys
import time

import can
import numpy as np

from bus import e2e
from bus.catalog import CATALOG
from bus.codec import Frame
from bus.transport import BusConfig, FrameBus, open_bus, to_can_message
from hil.argtypes import number

CLASSES = ("foreign", "catalog-bad-crc", "catalog-forged")


def make_frames(kind: str, n: int, rng: np.random.Generator, protector: e2e.Protector) -> list:
    """``n`` frames of class ``kind`` (see the module doc)."""
    cat_ids = [f.frame_id for f in CATALOG.frames]
    known = set(cat_ids)
    data = rng.integers(0, 256, size=(n, 8), dtype=np.uint8)
    out = []
    for row in data:
        if kind == "foreign":
            fid = int(rng.integers(0, 0x800))
            while fid in known:
                fid = int(rng.integers(0, 0x800))
            out.append(Frame(fid, bytes(row)))
            continue
        f = CATALOG.by_id[cat_ids[int(rng.integers(0, len(cat_ids)))]]
        good = protector.protect(f.data_id, bytes(row))
        if kind == "catalog-bad-crc":
            good = bytes([good[0] ^ 0x5A]) + good[1:]
        out.append(Frame(f.frame_id, good))
    return out


def flood(kind: str, rate_hz: float, seconds: float, interface: str, channel: str,
          seed: int, stop=lambda: False) -> tuple[int, float]:
    """Send the flood; returns (frames sent, seconds taken)."""
    rng = np.random.default_rng(seed)
    protector = e2e.Protector()
    bus = open_bus(BusConfig(interface=interface, channel=channel))
    burst_s = 0.001
    sent = 0
    t0 = time.monotonic()
    owed = 0.0
    try:
        t_next = t0
        while not stop() and (seconds <= 0 or time.monotonic() - t0 < seconds):
            owed += rate_hz * burst_s
            n = int(owed)
            owed -= n
            if n:
                frames = make_frames(kind, n, rng, protector)
                if isinstance(bus, FrameBus):
                    sent += bus.send_frames(frames)
                else:
                    for f in frames:
                        try:
                            bus.send(to_can_message(f))
                            sent += 1
                        except (can.CanError, OSError):
                            pass
            t_next += burst_s
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.1:
                t_next = time.monotonic()  # cannot keep up: do not build a burst
    finally:
        bus.shutdown()
    return sent, time.monotonic() - t0


def _cmd(args) -> int:
    stopped = []
    for sig in (signal.SIGINT, signal.SIGTERM):  # stop cleanly and say what was sent
        signal.signal(sig, lambda *_: stopped.append(True))
    sent, took = flood(args.kind, args.rate, args.seconds, args.interface, args.channel,
                       args.seed, stop=lambda: bool(stopped))
    print(f"flood {args.kind}: {sent} frames in {took:.1f} s ({sent / max(took, 1e-9):.0f}/s)")
    return 0


def register(sub) -> None:
    p = sub.add_parser("flood", help="a hostile third node: flood the bus by rate and class")
    p.add_argument("--class", dest="kind", choices=CLASSES, default="foreign")
    p.add_argument("--rate", type=number(gt=0, le=100_000), default=1000.0,
                   help="frames per second (default 1000)")
    p.add_argument("--seconds", type=number(ge=0, le=86_400), default=10.0,
                   help="how long (0: until interrupted)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--interface", default="socketcan")
    p.add_argument("--channel", default="vcan0")
    p.set_defaults(func=_cmd)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(prog="hil flood")
    register(ap.add_subparsers())
    a = ap.parse_args(["flood", *sys.argv[1:]])
    sys.exit(a.func(a))
