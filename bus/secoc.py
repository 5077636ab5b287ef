"""Authentication of the frames that can hurt (AUTOSAR SecOC as the model; docs/hostile-bus.md).

E2E (CRC + alive counter, ``bus.e2e``) protects against corruption, not against a sender that
should not be there: anyone on the bus can compute a CRC. THR_CMD, FAULT_CMD, GYRO (a
forged sample that completes its set would be flown on), SYNC (a forged tick far ahead makes
the lockstep flight refuse the genuine ones as duplicates) and the heartbeats (forged ones with
the alive counter the genuine sender is about to use make the genuine beats "repeated": the
plant went safe for a flight that was beating) therefore carry an authenticator, sent as a
frame of its own after the message (``THR_CMD_MAC``, ``FAULT_CMD_MAC``, ``GYRO_MAC``,
``SYNC_MAC``, ``HEARTBEAT_<NODE>_MAC`` in the catalog; classic CAN has no room left in the message's
frames):

    MAC = HMAC-SHA256(key, id16 | payload | freshness64)[:3]      (24 bits, SecOC's truncation)

``id16`` is the identifier of the message's first frame, ``payload`` the message's frames as
``bus.codec.encode`` gives them (E2E header zero: the MAC covers the signals, the E2E header
covers the transfer), ``freshness64`` the freshness value, big endian:

* THR_CMD and SYNC: the tick (the lockstep and the real-time grid keep it in step on both
  sides); the receiver takes a tick only when it is newer than the last one of that message
  it authenticated;
* FAULT_CMD: the sender's clock in 10 ms units (the panel is a new process each time and
  keeps no counter); the receiver rebuilds it from the 16 low bits and its own clock and takes
  it only within ``FAULT_FRESH_WINDOW`` of its clock and newer than the last one it took.
* GYRO: the sender's clock in 10 ms units, as FAULT_CMD (a lockstep plant sends many samples
  in one 10 ms, and a flight that joins late cannot know how often the 16-bit sample sequence
  has wrapped); the receiver takes it within ``FAULT_FRESH_WINDOW`` of its clock and only
  when the sample sequence (covered by the MAC) is ahead of the last one it took, or the
  clock more than ``RESTART_S`` ahead of that one's (a restarted plant counts from 0 again).
* HEARTBEAT: the sender's clock in 10 ms units, taken within ``FAULT_FRESH_WINDOW`` of the
  receiver's clock when newer than the last beat of that node taken (or as new and different:
  a lockstep node may beat twice within 10 ms); the key is the node id.

The key (32 random bytes) is made per run by ``hil run`` / ``hil up`` and handed to the nodes
and the panel in a file only the user may read (``hil.secoc_key``); it never goes on the bus
or into a log. A message whose authenticator is missing (``auth_missing``), wrong
(``auth_fail``) or not fresh (``auth_replay``) is counted and never handed on.

Sans-IO: times are arguments (seconds in the port's clock). The cryptography is the standard
library's ``hmac`` and ``hashlib``.
"""

from __future__ import annotations

import hashlib
import hmac
from collections import Counter

from bus.codec import (
    FaultCmd,
    FaultCmdMac,
    Gyro,
    GyroMac,
    Heartbeat,
    HeartbeatMac,
    Message,
    Sync,
    SyncMac,
    ThrCmd,
    ThrCmdMac,
    encode,
)

MAC_BITS = 24
KEY_BYTES = 32
FAULT_FRESH_WINDOW_S = 2.0  # a FAULT_CMD freshness this far from the receiver's clock is refused
# A secured message and its authenticator are sent together: when a frame received this much
# later than the message has been read and its authenticator has not, it is missing. Judged on
# receive times, not on when the reader got round to them (a loaded reader is not a forger);
# WAIT_LIMIT_S bounds the wait when nothing at all follows.
MATCH_WINDOW_S = 0.1
WAIT_LIMIT_S = 1.0
PER_KEY = 4  # secured messages of one key waiting for an authenticator at most
CLASSES = ("auth_ok", "auth_fail", "auth_missing", "auth_replay")
RESTART_S = 1.0  # a GYRO this much newer than the last one taken is taken whatever its sequence
SECURED: dict[type, type] = {ThrCmd: ThrCmdMac, FaultCmd: FaultCmdMac, Gyro: GyroMac,
                             Heartbeat: HeartbeatMac, Sync: SyncMac}
MAC_OF: dict[type, type] = {mac: msg for msg, mac in SECURED.items()}
# Logical messages (bus.codec.set_name_of) of the secured messages and their authenticators:
# the receiver of an authenticating node lets the authenticator judge them (bus.receiver).
AUTHENTICATED_SETS = frozenset(n for m in SECURED.items() for n in (m[0].SET, m[1].SET))


def message_key(msg: Message) -> int:
    """The set key a secured message's authenticator names (low 8 bits)."""
    if isinstance(msg, ThrCmd | Sync):
        return msg.tick & 0xFF
    if isinstance(msg, Gyro):
        return msg.sample_seq & 0xFF
    if isinstance(msg, Heartbeat):
        return int(msg.node)
    return msg.request_id & 0xFF


def _stream(msg: Message) -> object:
    """What a secured message's freshness is judged against: the last message of the same
    type taken (of the same node, for heartbeats)."""
    return (Heartbeat, int(msg.node)) if isinstance(msg, Heartbeat) else type(msg)


def compute_mac(key: bytes, msg: Message, freshness: int, frames: list | None = None) -> int:
    """The 24-bit truncated HMAC-SHA256 of ``msg`` with ``freshness`` (module doc);
    ``frames``: ``encode(msg)`` when the caller has it already (encoding costs more than the
    MAC)."""
    frames = encode(msg) if frames is None else frames
    data = frames[0].arbitration_id.to_bytes(2, "big") + b"".join(f.data for f in frames) + \
        int(freshness).to_bytes(8, "big")
    return int.from_bytes(hmac.new(key, data, hashlib.sha256).digest()[: MAC_BITS // 8], "big")


def fault_freshness(now_s: float) -> int:
    """FAULT_CMD's freshness value: the clock in 10 ms units."""
    return int(now_s * 100)


class Authenticator:
    """Signs what a node sends and checks what it receives (module doc)."""

    def __init__(self, key: bytes) -> None:
        if len(key) < 16:
            raise ValueError(f"secoc: key: expected at least 16 bytes, got {len(key)}")
        self._key = bytes(key)
        # The last message taken per stream (``_stream``) and its freshness value.
        self._last: dict[object, tuple[int, Message]] = {}
        self.counts: Counter[str] = Counter({c: 0 for c in CLASSES})
        self.events: list[str] = []
        self.events_given = 0
        # Secured messages waiting for their authenticator, by (type, key): a few per key, so
        # that a forged message with the key of a genuine one cannot push the genuine one out.
        self._msgs: dict[tuple[type, int], list[tuple[Message, float]]] = {}
        # Authenticators waiting for their message, by (type, key): a few per key too, so a
        # forged one cannot push the genuine one out. A message no authenticator verified
        # keeps waiting (the genuine one may still come); ``_tried`` remembers that one was
        # tried, so it is counted as failed rather than missing when it expires.
        self._macs: dict[tuple[type, int], list[tuple[ThrCmdMac, float]]] = {}
        self._tried: set[int] = set()
        self._latest_rx = -float("inf")

    def __repr__(self) -> str:  # never show the key
        return f"Authenticator(counts={dict(self.counts)})"

    # -- sender ---------------------------------------------------------------------------

    def sign(self, msg: Message, now_s: float, frames: list | None = None) -> Message | None:
        """The authenticator message to send right after ``msg`` (None: not secured);
        ``frames``: ``encode(msg)`` if the caller has it."""
        mac_type = SECURED.get(type(msg))
        if mac_type is None:
            return None
        fv = msg.tick if isinstance(msg, ThrCmd | Sync) else fault_freshness(now_s)
        return mac_type(message_key(msg), fv & 0xFFFF, compute_mac(self._key, msg, fv, frames))

    # -- receiver -------------------------------------------------------------------------

    def accept(self, items: list[tuple[Message, float]],
               now_s: float) -> list[tuple[Message, float]]:
        """The received messages that may be used: unsecured ones as they are, secured ones
        once their authenticator arrived and checks; authenticators are consumed."""
        out: list[tuple[Message, float]] = []
        for msg, rx in items:
            self._latest_rx = max(self._latest_rx, rx)
            of = MAC_OF.get(type(msg))
            if of is not None:
                k = (of, msg.key_lo)
                if not (k in self._msgs and self._check_any(k, msg, now_s, out)):
                    macs = self._macs.setdefault(k, [])
                    if len(macs) >= PER_KEY:
                        macs.pop(0)
                    macs.append((msg, rx))
            elif type(msg) in SECURED:
                k = (type(msg), message_key(msg))
                waiting = self._msgs.setdefault(k, [])
                if len(waiting) >= PER_KEY:  # the oldest has waited long enough
                    self._gone(waiting.pop(0)[0])
                waiting.append((msg, rx))
                for i, (mac, _) in enumerate(self._macs.get(k, [])):
                    if self._check_any(k, mac, now_s, out):
                        del self._macs[k][i]
                        break
            else:
                out.append((msg, rx))
        self.expire(now_s)
        return out

    def expire(self, now_s: float) -> None:
        """Secured messages whose authenticator did not come in time (see ``MATCH_WINDOW_S``):
        counted, dropped; authenticators without their message: dropped."""
        def late(rx: float) -> bool:
            return self._latest_rx - rx > MATCH_WINDOW_S or now_s - rx > WAIT_LIMIT_S

        for k, waiting in list(self._msgs.items()):
            for item in [w for w in waiting if late(w[1])]:
                waiting.remove(item)
                self._gone(item[0])
            if not waiting:
                del self._msgs[k]
        for k, macs in list(self._macs.items()):
            macs[:] = [m for m in macs if not late(m[1])]
            if not macs:
                del self._macs[k]

    def _gone(self, m: Message) -> None:
        """A secured message leaves unused: failed when an authenticator was tried on it,
        else missing."""
        if id(m) in self._tried:
            self._tried.discard(id(m))
            self._fail(m)
        else:
            self._miss(m)

    def _miss(self, m: Message) -> None:
        self.counts["auth_missing"] += 1
        self._event(f"{type(m).__name__} without its authenticator: not used")

    def _event(self, text: str) -> None:
        if self.events_given < 20:  # a flood of forgeries must not flood the log: counts only
            self.events_given += 1
            self.events.append(text + (" (further ones counted only)"
                                       if self.events_given == 20 else ""))

    def _check_any(self, k: tuple[type, int], mac: ThrCmdMac, now_s: float,
                   out: list[tuple[Message, float]]) -> bool:
        """The authenticator against the messages waiting with its key, newest first: the
        first that verifies is checked for freshness and used, the others of the key failed.
        None verifies: they keep waiting (a forged authenticator must not make the genuine
        message fail before its own authenticator arrives). Returns whether one verified."""
        waiting = self._msgs.get(k, [])
        for m, rx in reversed(waiting):
            if self._verifies(m, mac, now_s):
                for m2, _ in waiting:
                    if m2 is not m:
                        self._tried.discard(id(m2))
                        self._fail(m2)
                self._tried.discard(id(m))
                del self._msgs[k]
                self._check(m, mac, now_s, rx, out)
                return True
        for m, _ in waiting:
            self._tried.add(id(m))
        return False

    def _fail(self, m: Message) -> None:
        self.counts["auth_fail"] += 1
        self._event(f"{type(m).__name__} failed authentication: not used")

    def _freshness(self, m: Message, mac: ThrCmdMac, now_s: float) -> int:
        if isinstance(m, ThrCmd | Sync):
            return m.tick
        mine = fault_freshness(now_s)
        # The value nearest our clock whose low 16 bits are the ones sent.
        fv = mine - ((mine - mac.fresh_lo) & 0xFFFF)
        return fv + 0x10000 if mine - fv > 0x8000 else fv

    def _verifies(self, m: Message, mac: ThrCmdMac, now_s: float) -> bool:
        fv = self._freshness(m, mac, now_s)
        if not 0 <= fv < 1 << 64:  # no sender's clock gives this (a forgery near our clock's
            return False           # zero): it cannot verify, and must not raise
        return hmac.compare_digest(compute_mac(self._key, m, fv).to_bytes(3, "big"),
                                   int(mac.mac).to_bytes(3, "big"))

    def _check(self, m: Message, mac: ThrCmdMac, now_s: float, rx: float,
               out: list[tuple[Message, float]]) -> None:
        """``m`` verified against ``mac``: used when fresh, else counted as a replay."""
        fv = self._freshness(m, mac, now_s)
        last = self._last.get(_stream(m))
        if isinstance(m, ThrCmd | Sync):  # the tick: newer than the last one taken
            fresh = (fv & 0xFFFF) == mac.fresh_lo and (last is None or fv > last[0])
        else:  # the sender's clock: within the window, and newer (module doc)
            if last is None:
                newer = True
            elif isinstance(m, Gyro):
                newer = 0 < (m.sample_seq - last[1].sample_seq) & 0xFFFF < 0x8000 \
                    or fv > last[0] + RESTART_S * 100
            elif isinstance(m, Heartbeat):
                newer = fv > last[0] or (fv == last[0] and m != last[1])
            else:
                newer = fv > last[0]
            fresh = newer and abs(fv - fault_freshness(now_s)) <= FAULT_FRESH_WINDOW_S * 100
        if not fresh:
            self.counts["auth_replay"] += 1
            self._event(f"{type(m).__name__} authentic but not fresh (replay): not used")
            return
        self._last[_stream(m)] = (fv, m)
        self.counts["auth_ok"] += 1
        out.append((m, rx))
