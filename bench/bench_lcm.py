"""LCM against CAN in the same place: latency between two processes, lockstep speed, bytes per
tick (docs/lcm.md). Prints figures; asserts nothing.

Where vcan0 exists (inside user-mode Linux on a kernel without CAN), CAN is SocketCAN vcan0;
LCM is udpm on the same kernel's loopback (the multicast route is added there, never on the
host). Elsewhere it runs in a private network namespace and CAN is python-can's
``udp_multicast`` (no vcan there):

    hil vcan exec -- .venv/bin/python bench/bench_lcm.py     # vcan0 and LCM, user-mode Linux
    hil netns exec -- .venv/bin/python bench/bench_lcm.py    # LCM and udp_multicast, native

Latency: process A publishes a 16-byte ping (sequence, A's CLOCK_MONOTONIC send time) and
waits for the echo (ping-pong, no queueing); B echoes with its own send time. One kernel, so
A->B, B->A and the round trip are differences of one clock read by two processes, user space
to user space (``lcm.publish`` to the subscriber's handler; python-can ``send`` to ``recv``).
The CAN figures come from ``hil.bench_bus.ping_pong`` (the ``hil bench`` measurement) on
vcan0. Lockstep: ``hil run S000-stuck`` over each bus; ``speed_x_realtime`` of the loop and
bytes per tick (LCM: message bytes as published, and with LCM's 8-byte header, the channel
name and 28 bytes of UDP/IPv4; CAN: 8 data bytes per frame and 135 bits on the wire per
frame at worst-case stuffing, ``bus.catalog.classic_frame_bits``).
"""

from __future__ import annotations

import argparse
import json
import os
import select
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
URL = "udpm://239.255.76.67:7671?ttl=0"
PING = struct.Struct("<IQ4x")  # 16 bytes


def stats_ms(values_ns) -> str:
    a = np.asarray(values_ns, dtype=float) / 1e6
    if a.size == 0:
        return "no samples"
    return (f"p50 {np.percentile(a, 50):7.3f}  p99 {np.percentile(a, 99):7.3f}  "
            f"max {a.max():7.3f}  (n={a.size})")


def _peer(url: str, total: int) -> int:
    import lcm

    lc = lcm.LCM(url)
    a_to_b = []

    def on_ping(_channel, data):
        t_rx = time.monotonic_ns()
        seq, t_tx = PING.unpack(data)
        a_to_b.append(t_rx - t_tx)
        lc.publish("BENCH_PONG", PING.pack(seq, time.monotonic_ns()))

    lc.subscribe("BENCH_PING", on_ping)
    print("ready", flush=True)
    t_end = time.monotonic() + 60
    while len(a_to_b) < total and time.monotonic() < t_end:
        lc.handle_timeout(200)
    print(json.dumps({"a_to_b_ns": a_to_b}), flush=True)
    return 0


def lcm_ping_pong(url: str, n: int, warmup: int) -> dict:
    import lcm

    total = n + warmup
    peer = subprocess.Popen([sys.executable, __file__, "--peer", url, str(total)],
                            stdout=subprocess.PIPE, text=True)
    assert peer.stdout.readline().strip() == "ready"
    lc = lcm.LCM(url)
    got: list[tuple[int, int, int]] = []
    lc.subscribe("BENCH_PONG", lambda _c, d: got.append((*PING.unpack(d), time.monotonic_ns())))
    time.sleep(0.3)
    rtt, b_to_a, lost = [], [], 0
    fd = lc.fileno()
    for seq in range(total):
        got.clear()
        t_tx = time.monotonic_ns()
        lc.publish("BENCH_PING", PING.pack(seq, t_tx))
        t_end = time.monotonic() + 2
        while not got and time.monotonic() < t_end:
            if select.select([fd], [], [], 0.5)[0]:
                lc.handle()
        if not got or got[0][0] != seq:
            lost += 1
            continue
        _, t_echo, t_rx = got[0]
        if seq >= warmup:
            rtt.append(t_rx - t_tx)
            b_to_a.append(t_rx - t_echo)
    out, _ = peer.communicate(timeout=60)
    a_to_b = json.loads(out.strip().splitlines()[-1])["a_to_b_ns"][warmup:]
    return {"rtt_ns": rtt, "a_to_b_ns": a_to_b, "b_to_a_ns": b_to_a, "lost": lost}


def _summary(args: list[str], env: dict | None = None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        r = subprocess.run([sys.executable, "-m", "hil.cli", "run",
                            str(REPO / "configs/scenarios/S000-stuck.yaml"), "--out", tmp,
                            *args], capture_output=True, text=True, cwd=REPO, env=env)
        if r.returncode != 0:
            raise SystemExit(f"hil run {' '.join(args)} failed: {r.stdout[-500:]}{r.stderr}")
        return json.loads((Path(tmp) / "summary.json").read_text())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=2000, help="pings to measure (default 2000)")
    ap.add_argument("--warmup", type=int, default=50)
    ap.add_argument("--runs", type=int, default=2, help="lockstep runs per bus (default 2)")
    ap.add_argument("--peer", nargs=2, metavar=("URL", "N"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.peer:
        return _peer(args.peer[0], int(args.peer[1]))

    from bus.catalog import classic_frame_bits
    from hil.netns import NETNS_ENV, uml_route
    from hil.uml import in_uml
    from hil.vcan import vcan_present

    if in_uml() and not os.environ.get(NETNS_ENV):
        uml_route()  # the instance's own loopback
        os.environ[NETNS_ENV] = "user-mode Linux loopback"
    if not os.environ.get(NETNS_ENV):
        raise SystemExit("bench_lcm: run it through `hil netns exec` or `hil vcan exec` "
                         "(LCM's udpm needs the multicast route hil sets up there)")
    vcan = vcan_present("vcan0")
    where = "user-mode Linux" if in_uml() else "native kernel, private network namespace"
    print(f"bench_lcm: {where}; LCM {URL}; CAN "
          f"{'SocketCAN vcan0' if vcan else 'python-can udp_multicast (no vcan here)'}")

    t0 = time.monotonic()
    r = lcm_ping_pong(URL, args.n, args.warmup)
    print(f"LCM udpm ping-pong, 16-byte payload, {args.n} (+{args.warmup}) pings, "
          f"{time.monotonic() - t0:.1f} s, lost {r['lost']}")
    print(f"  round trip A->B->A  {stats_ms(r['rtt_ns'])}  ms")
    print(f"  one-way    A->B     {stats_ms(r['a_to_b_ns'])}  ms")
    print(f"  one-way    B->A     {stats_ms(r['b_to_a_ns'])}  ms")
    if vcan:
        from hil.bench_bus import ping_pong

        t0 = time.monotonic()
        c = ping_pong("vcan0", args.n, args.warmup)
        print(f"vcan0 ping-pong, 8-byte frames, {args.n} (+{args.warmup}) frames, "
              f"{time.monotonic() - t0:.1f} s, lost {c['lost']}")
        print(f"  round trip A->B->A  {stats_ms(c['rtt_ns'])}  ms")
        print(f"  one-way    A->B     {stats_ms(c['a_to_b_ns'])}  ms")
        print(f"  one-way    B->A     {stats_ms(c['b_to_a_ns'])}  ms")
        can_args, can_env = [], None
    else:
        port = 47000 + os.getpid() % 1000
        can_args = ["--interface", "udp_multicast", "--channel", "239.74.163.2"]
        can_env = dict(os.environ, CAN_CONFIG=json.dumps({"port": port}))

    print(f"lockstep S000-stuck (150 ticks), {args.runs} runs per bus, loop speed "
          "(simulated s per wall s):")
    for _ in range(args.runs):
        s_l = _summary(["--bus", "lcm", "--lcm-url", URL])
        s_c = _summary(can_args, env=can_env)
        print(f"  LCM {s_l['speed_x_realtime']:6.1f}x   CAN {s_c['speed_x_realtime']:6.1f}x   "
              f"(same detections, fuel: {s_l['detections'] == s_c['detections']}, "
              f"{s_l['fuel_kg'] == s_c['fuel_kg']})")
    ticks = s_l["ticks"]
    per_msg_overhead = 8 + 28  # LCM small-message header + UDP/IPv4
    msgs, payload = s_l["lcm_messages_logged"], s_l["lcm_bytes_logged"]
    chan_bytes = 0
    names = {"HIL_SYNC": 1, "HIL_GYRO": 1, "HIL_THR_CMD": 1, "HIL_FDIR_STATUS": 1,
             "HIL_FLIGHT_TIMING": 1}  # one of each per lockstep tick
    chan_bytes = sum(len(n) + 1 for n in names) * msgs / len(names)
    frames = s_c["bus_frames_logged"]
    print(f"bytes per tick, control bus (lockstep, {ticks} ticks):")
    print(f"  LCM  {msgs / ticks:.1f} messages, {payload / ticks:.0f} B of messages, "
          f"{(payload + chan_bytes + per_msg_overhead * msgs) / ticks:.0f} B with LCM header, "
          "channel name and UDP/IPv4")
    print(f"  CAN  {frames / ticks:.1f} frames, {8 * frames / ticks:.0f} B of data, "
          f"{classic_frame_bits(8) * frames / ticks / 8:.0f} B on the wire (classic, stuffed)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
