"""`hil flood`: a hostile third node on the bus (docs/hostile-bus.md).

``hil flood --class CLASS --rate HZ --seconds S`` sends frames at ``rate`` per second for
``seconds`` (0: until stopped) on ``--interface`` / ``--channel`` (vcan0 by default), seeded
by ``--seed``. Two senders (``--sender``):

* ``kernel`` (SocketCAN only, the classes that do not listen): the kernel's broadcast manager
  (``can-bcm``) sends the frames from its timers, so the flood costs no process wake-ups and
  reaches rates a Python loop cannot inside user-mode Linux. The frames are generated once from
  the seed, 256 per timer, and sent in turn, again and again; the rate is shared by
  ``ceil(rate / 500)`` timers. What was sent is read back from the kernel at the end: exact
  when the flood runs its ``seconds`` (each timer stops at its count, and is read after it
  stopped); a flood stopped early (a signal, or timers still behind at twice the duration)
  reads each timer just before deleting it, and may miss the frames of that instant;
* ``python``: bursts of one millisecond's worth from a loop (``sendmmsg`` on SocketCAN).

``auto`` (the default) takes ``kernel`` where it can and says which in the result.

The classes:

* ``foreign``: identifiers that are not in the catalog, random payloads;
* ``catalog-bad-crc``: the catalog's identifiers with random payloads whose E2E CRC is made
  wrong on purpose (every one is rejected as ``bad_crc``);
* ``catalog-forged``: the catalog's identifiers with a valid E2E CRC and alive counter over a
  random payload: what corruption checks cannot stop;
* ``forged``: whole THR_CMD sets ("every thruster full on", the next tick), FAULT_CMD sets
  ("stuck on" of thruster 0) and GYRO sets (0.05 rad/s about every axis, the next sample) with
  a valid E2E CRC and the alive counter that follows the genuine sender's, each followed by
  an authenticator with a wrong MAC or by none (in turn): they pass every E2E check and must
  stop at authentication (``auth_fail``, ``auth_missing``);
* ``replay``: the newest authentic THR_CMD set heard on the bus with its authenticator, sent
  again with fresh E2E counters: the MAC verifies and only its freshness stops it
  (``auth_replay``).

``forged`` and ``replay`` listen to the bus (``Listener``: alive counters, the newest tick,
the thruster count, the newest authentic set). The flood prints the frames sent and the rate
reached (``--json``: one JSON line, with the frames sent per identifier). Used by
``hil bench --parts hostile`` (``hil.hostile``), its CI test and by hand next to ``hil up``;
it is a test tool, not part of a run.
"""

from __future__ import annotations

import ctypes
import json
import math
import signal
import sys
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import can
import numpy as np

from bus import e2e
from bus.catalog import (
    ALLOWED_ON_QUANTA,
    CATALOG,
    FAULT_CMD_IDS,
    THR_CMD_IDS,
    FaultAction,
    FaultKind,
)
from bus.codec import FaultCmd, FaultCmdMac, Frame, Gyro, GyroMac, ThrCmd, ThrCmdMac, encode
from bus.secoc import fault_freshness
from bus.transport import BusConfig, FrameBus, from_can_message, open_bus, to_can_message
from hil.argtypes import number

CLASSES = ("foreign", "catalog-bad-crc", "catalog-forged", "forged", "replay")
LISTENING = ("forged", "replay")  # the classes that listen to the bus first
THR_CMD_MAC_ID = CATALOG.frame("THR_CMD_MAC").frame_id
FAULT_CMD_MAC_ID = CATALOG.frame("FAULT_CMD_MAC").frame_id
GYRO_IDS = tuple(CATALOG.frame(n).frame_id for n in ("GYRO_1", "GYRO_2", "GYRO_MAC"))
SECURED_IDS = (*THR_CMD_IDS, THR_CMD_MAC_ID, *FAULT_CMD_IDS, FAULT_CMD_MAC_ID, *GYRO_IDS)
GROUP_FIRST_IDS = (THR_CMD_IDS[0], FAULT_CMD_IDS[0], GYRO_IDS[0])  # a group's first frame
FORGED_RATE_RAD_S = 0.05  # a forged gyro sample's rate about every axis
DEFAULT_THRUSTERS = 12  # a forged THR_CMD's size before a genuine one was heard
# A receive filter nothing on the bus matches (an extended identifier nobody sends): the
# classes that do not listen leave the kernel no queue to fill.
DEAF = [{"can_id": 0x1FFFFFFF, "can_mask": 0x1FFFFFFF, "extended": True}]


class Listener:
    """What a hostile node learns by listening to THR_CMD, FAULT_CMD and GYRO: the last alive
    counter of each identifier, the newest THR_CMD tick, its thruster count, manifold mask,
    the newest gyro sample sequence, and the newest authentic THR_CMD set with its
    authenticator (frames as sent)."""

    def __init__(self) -> None:
        self.counter: dict[int, int] = {}
        self.tick: int | None = None
        self.n_thr = DEFAULT_THRUSTERS
        self.manifolds = 0xF
        self.gyro_seq = 0
        self.authentic: list[Frame] = []
        self._set: list[Frame] = []

    def see(self, fr: Frame) -> None:
        fid = fr.arbitration_id
        if fid not in SECURED_IDS or len(fr.data) != 8:
            return
        self.counter[fid] = e2e.counter_of(fr.data)
        if fid in THR_CMD_IDS:
            if fid == THR_CMD_IDS[0]:
                self._set = []
            self._set.append(fr)
        elif fid == THR_CMD_MAC_ID and self._set:
            self.authentic = [*self._set, fr]
            self._learn(self._set)
            self._set = []
        elif fid == GYRO_IDS[1]:  # GYRO_2: the full sample sequence
            from bus.codec import unpack

            self.gyro_seq = int(unpack(CATALOG.by_id[fid], fr.data)["sample_seq"])

    def _learn(self, frames: list[Frame]) -> None:
        from bus.codec import decode

        try:
            cmd = decode([Frame(f.arbitration_id, f.data) for f in frames])
        except Exception:  # noqa: BLE001 - a set we cannot read teaches nothing
            return
        if isinstance(cmd, ThrCmd):
            self.tick, self.n_thr = cmd.tick, len(cmd.on_quanta)
            self.manifolds, self.gyro_seq = cmd.manifold_enable, cmd.gyro_seq

    def next_counter(self, fid: int) -> int:
        """The alive counter that follows the last one on ``fid`` (and remember it: the
        receivers saw it)."""
        c = (self.counter.get(fid, -1) + 1) % e2e.COUNTER_MODULO
        self.counter[fid] = c
        return c

    def protect(self, frames: list[Frame]) -> list[Frame]:
        """``frames`` with the E2E counter that follows the genuine sender's and a valid CRC
        (what a receiver's E2E check cannot tell from the genuine sender)."""
        return [Frame(f.arbitration_id,
                      e2e.protect(CATALOG.by_id[f.arbitration_id].data_id, f.data,
                                  self.next_counter(f.arbitration_id)))
                for f in frames]


def forged_group(k: int, rng: np.random.Generator, heard: Listener) -> list[Frame]:
    """Group ``k`` of the ``forged`` class: by ``k % 3`` a THR_CMD, a FAULT_CMD or a GYRO,
    each with a wrong authenticator (``k // 3`` even) or none."""
    if k % 3 == 2:
        seq = (heard.gyro_seq + 1) & 0xFFFF
        msg: Any = Gyro(seq, (FORGED_RATE_RAD_S,) * 3, 1)
        mac: Any = GyroMac(seq & 0xFF, fault_freshness(time.time()) & 0xFFFF,
                           int(rng.integers(0, 1 << 24)))
    elif k % 3 == 0:
        tick = 0 if heard.tick is None else heard.tick + 1
        msg = ThrCmd(tick, (max(ALLOWED_ON_QUANTA),) * heard.n_thr, heard.manifolds,
                     heard.gyro_seq)
        mac = ThrCmdMac(tick & 0xFF, tick & 0xFFFF, int(rng.integers(0, 1 << 24)))
    else:
        rid = int(rng.integers(0, 256))
        msg = FaultCmd(rid, FaultAction.INJECT, FaultKind.STUCK_ON, 0, 1.0, 0.0, None)
        mac = FaultCmdMac(rid, fault_freshness(time.time()) & 0xFFFF,
                          int(rng.integers(0, 1 << 24)))
    frames = encode(msg) + (encode(mac) if (k // 3) % 2 == 0 else [])
    return heard.protect(frames)


def make_frames(kind: str, n: int, rng: np.random.Generator, protector: e2e.Protector,
                heard: Listener | None = None, k0: int = 0) -> list:
    """About ``n`` frames of class ``kind`` (see the module doc): exactly ``n`` for the
    random classes, whole groups for ``forged`` and ``replay`` (none to replay before an
    authentic set was heard). ``k0``: the number of the first group (``forged``)."""
    if kind in LISTENING:
        heard = heard or Listener()
        out: list[Frame] = []
        k = k0
        while len(out) < n:
            if kind == "forged":
                out += forged_group(k, rng, heard)
            elif heard.authentic:
                out += heard.protect(heard.authentic)
            else:
                break
            k += 1
        return out
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


def _listen(bus: can.BusABC, heard: Listener) -> None:
    """Take what is queued for us (never waits)."""
    if isinstance(bus, FrameBus):
        got: list = []
        bus.drain_frames(0.0, got, limit=512)
        for fr, _ in got:
            heard.see(fr)
        return
    for _ in range(512):
        m = bus.recv(0.0)
        if m is None:
            return
        heard.see(from_can_message(m))


SENDERS = ("auto", "kernel", "python")
BCM_NFRAMES = 256  # frames per broadcast-manager timer (the kernel's MAX_NFRAMES)
BCM_RATE_PER_TIMER_HZ = 500.0  # one kernel timer at a few kHz falls behind in user-mode Linux
BCM_COUNT_UNLIMITED = 2**31 - 1


class KernelFlood:
    """Frames sent by the kernel's CAN broadcast manager (``can-bcm``): ``len(groups)``
    cyclic transmit jobs, each sending its frames in turn every ``period_s`` until it has
    sent ``count`` (python-can's BCM message layout, our own job control: python-can's
    cyclic task wants one identifier per job and does not read back what was sent)."""

    def __init__(self, channel: str, groups: list[list[Frame]], period_s: float,
                 count: int) -> None:
        from can.interfaces.socketcan import constants as bcm
        from can.interfaces.socketcan import socketcan as sc

        self._sc, self._bcm = sc, bcm
        self.groups = groups
        self.count = count
        self.sock = sc.create_bcm_socket(channel)  # OSError without can-bcm or the channel
        usec = max(1, round(period_s * 1e6))
        try:
            for job, frames in enumerate(groups):
                head = sc.build_bcm_header(bcm.CAN_BCM_TX_SETUP,
                                           bcm.SETTIMER | bcm.STARTTIMER, count,
                                           usec // 1_000_000, usec % 1_000_000, 0, 0, job,
                                           len(frames))
                body = b"".join(sc.build_can_frame(to_can_message(f)) for f in frames)
                self.sock.send(head + body)
        except OSError:
            self.sock.close()
            raise

    def sent_per_job(self) -> list[int]:
        """Frames each job has sent so far (its count left, read back from the kernel)."""
        return [self._read(job) for job in range(len(self.groups))]

    def _read(self, job: int) -> int:
        sc, bcm = self._sc, self._bcm
        size = ctypes.sizeof(sc.BcmMsgHead)
        self.sock.send(sc.build_bcm_header(bcm.CAN_BCM_TX_READ, 0, 0, 0, 0, 0, 0, job, 0))
        while True:
            reply = self.sock.recv(size + 64 * (BCM_NFRAMES + 1))
            head = sc.BcmMsgHead.from_buffer_copy(reply[:size])
            if head.can_id == job:
                return self.count - int(head.count)

    def done(self) -> bool:
        """Whether every job has sent its ``count`` (its timer has stopped)."""
        return all(n >= self.count for n in self.sent_per_job())

    def stop(self) -> list[int]:
        """Stop every job; returns what each sent (each job read just before its deletion)."""
        sc = self._sc
        try:
            sent = []
            for job in range(len(self.groups)):
                sent.append(self._read(job))
                self.sock.send(sc.build_bcm_tx_delete_header(job, 0))
        finally:
            self.sock.close()
        return sent


def by_id_of_cycles(groups: list[list[Frame]], sent: list[int]) -> Counter[int]:
    """Frames per identifier when each group's frames went out in turn, ``sent[k]`` of them."""
    out: Counter[int] = Counter()
    for frames, m in zip(groups, sent, strict=True):
        full, part = divmod(m, len(frames))
        for i, f in enumerate(frames):
            out[f.arbitration_id] += full + (1 if i < part else 0)
    return out


def _kernel_flood(kind: str, rate_hz: float, seconds: float, channel: str, seed: int,
                  stop: Callable[[], bool]) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    protector = e2e.Protector()
    jobs = max(1, math.ceil(rate_hz / BCM_RATE_PER_TIMER_HZ))
    per_job_hz = rate_hz / jobs
    groups = [make_frames(kind, BCM_NFRAMES, rng, protector) for _ in range(jobs)]
    count = (max(1, math.ceil(per_job_hz * seconds)) if seconds > 0
             else BCM_COUNT_UNLIMITED)
    t0 = time.monotonic()
    kf = KernelFlood(channel, groups, 1.0 / per_job_hz, count)
    try:
        # a timed flood waits for its timers to reach their count (they lag inside user-mode
        # Linux under load), so what is read back is what was sent; at most twice the time
        while not stop():
            elapsed = time.monotonic() - t0
            if seconds > 0 and elapsed >= seconds and (kf.done() or elapsed > 2 * seconds + 1):
                break
            time.sleep(0.02)
    finally:
        sent = kf.stop()
    took = time.monotonic() - t0
    by_id = by_id_of_cycles(groups, sent)
    return {"class": kind, "rate_hz": rate_hz, "sender": "kernel", "timers": jobs,
            "sent": sum(sent), "seconds": round(took, 3),
            "rate_reached_hz": round(sum(sent) / max(took, 1e-9), 1), "groups": 0,
            "by_id": {str(k): v for k, v in sorted(by_id.items()) if v}}


def flood(kind: str, rate_hz: float, seconds: float, interface: str, channel: str,
          seed: int, stop: Callable[[], bool] = lambda: False,
          sender: str = "auto") -> dict[str, Any]:
    """Send the flood; returns what was sent: ``{"class", "rate_hz", "sender", "sent",
    "seconds", "rate_reached_hz", "groups", "by_id": {frame id: frames}}`` (``sender_note``:
    why ``auto`` did not take the kernel)."""
    if kind not in CLASSES:
        raise ValueError(f"flood: class: expected one of {', '.join(CLASSES)}, got {kind!r}")
    if sender not in SENDERS:
        raise ValueError(f"flood: sender: expected one of {', '.join(SENDERS)}, "
                         f"got {sender!r}")
    note = None
    if sender != "python":
        why = ("the class listens to the bus first" if kind in LISTENING
               else None if interface == "socketcan"
               else f"interface {interface!r} has no broadcast manager")
        if why and sender == "kernel":
            raise ValueError(f"flood: sender kernel: expected a class that does not listen "
                             f"on interface socketcan, got class {kind!r} on {interface!r}")
        if not why:
            try:
                return _kernel_flood(kind, rate_hz, seconds, channel, seed, stop)
            except OSError as e:
                if sender == "kernel":
                    raise ValueError(f"flood: sender kernel: expected the CAN broadcast "
                                     f"manager on {channel!r}, got {e}") from e
                why = f"no broadcast manager on {channel!r} ({e})"
        note = why
    res = _python_flood(kind, rate_hz, seconds, interface, channel, seed, stop)
    if note:
        res["sender_note"] = note
    return res


def _python_flood(kind: str, rate_hz: float, seconds: float, interface: str, channel: str,
                  seed: int, stop: Callable[[], bool]) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    protector = e2e.Protector()
    heard = Listener()
    filters = ([{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in SECURED_IDS]
               if kind in LISTENING else DEAF)
    bus = open_bus(BusConfig(interface=interface, channel=channel,
                             kwargs={"can_filters": filters}))
    burst_s = 0.001
    sent = 0
    groups = 0
    by_id: Counter[int] = Counter()
    t0 = time.monotonic()
    owed = 0.0
    try:
        t_next = t0
        while not stop() and (seconds <= 0 or time.monotonic() - t0 < seconds):
            if kind in LISTENING:
                _listen(bus, heard)
            owed = min(owed + rate_hz * burst_s, max(rate_hz * 0.01, 8.0))
            n = int(owed)
            if n:
                frames = make_frames(kind, n, rng, protector, heard, groups)
                owed -= len(frames)
                if kind in LISTENING:
                    groups += sum(f.arbitration_id in GROUP_FIRST_IDS for f in frames)
                if isinstance(bus, FrameBus):
                    k = bus.send_frames(frames)
                    sent += k
                    by_id.update(f.arbitration_id for f in frames[:k])
                else:
                    for f in frames:
                        try:
                            bus.send(to_can_message(f))
                        except (can.CanError, OSError):
                            continue
                        sent += 1
                        by_id[f.arbitration_id] += 1
            t_next += burst_s
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.1:
                t_next = time.monotonic()  # cannot keep up: do not build a burst
    finally:
        bus.shutdown()
    took = time.monotonic() - t0
    return {"class": kind, "rate_hz": rate_hz, "sender": "python", "sent": sent,
            "seconds": round(took, 3),
            "rate_reached_hz": round(sent / max(took, 1e-9), 1), "groups": groups,
            "by_id": {str(k): v for k, v in sorted(by_id.items())}}


def _cmd(args) -> int:
    stopped = []
    for sig in (signal.SIGINT, signal.SIGTERM):  # stop cleanly and say what was sent
        signal.signal(sig, lambda *_: stopped.append(True))
    try:
        res = flood(args.kind, args.rate, args.seconds, args.interface, args.channel,
                    args.seed, stop=lambda: bool(stopped), sender=args.sender)
    except ValueError as e:
        print(f"hil {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(res), flush=True)
    else:
        print(f"flood {args.kind}: {res['sent']} frames in {res['seconds']:.1f} s "
              f"({res['rate_reached_hz']:.0f}/s, sent by {res['sender']}"
              + (f": {res['sender_note']}" if res.get("sender_note") else "") + ")",
              flush=True)
    return 0


def register(sub) -> None:
    p = sub.add_parser("flood", help="a hostile third node: flood the bus by rate and class")
    p.add_argument("--class", dest="kind", choices=CLASSES, default="foreign")
    p.add_argument("--rate", type=number(gt=0, le=100_000), default=1000.0,
                   help="frames per second (default 1000)")
    p.add_argument("--seconds", type=number(ge=0, le=86_400), default=10.0,
                   help="how long (0: until interrupted)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--json", action="store_true",
                   help="print what was sent as one JSON line (frames per identifier too)")
    p.add_argument("--sender", choices=SENDERS, default="auto",
                   help="kernel: the CAN broadcast manager sends (SocketCAN, classes that do "
                        "not listen); python: a send loop; auto (default): kernel where it "
                        "can")
    p.add_argument("--interface", default="socketcan")
    p.add_argument("--channel", default="vcan0")
    p.set_defaults(func=_cmd)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(prog="hil flood")
    register(ap.add_subparsers())
    a = ap.parse_args(["flood", *sys.argv[1:]])
    sys.exit(a.func(a))
