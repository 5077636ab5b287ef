"""Bus faults on a node's send path (docs/hostile-bus.md): drop, delay, corrupt, babble, silent.

``SendFaults`` is the object a ``bus.transport.Port`` calls as its ``send_hook``: every frame
the node sends passes it after encoding and E2E protection, just before the wire, so the same
faults act on every python-can interface. It is sans-IO apart from the clock it is given
(``clock``: seconds in the port's clock, used only to hold delayed frames and to pace a
babble); which faults are active is decided by the node's scenario time ``t_s``, which the
process shell sets once per tick (``SendFaults.t_s``), so a lockstep run drops, corrupts and
delays the same frames every time for a given seed.

Kinds (``common.scenario.FaultSpec``, ``kind``):

* ``bus_drop``: a matching frame is not sent, with ``probability`` or by ``pattern``
  (1 = drop, 0 = pass, cycled over the matching frames);
* ``bus_delay``: a matching frame (with ``probability``) is held ``delay_ms`` (or a uniform
  draw in [delay_ms, delay_max_ms]) and sent when due (``Port.poll`` and ``Port.send`` release
  what is due). Frames keep their order: a frame is never released before one held earlier by
  the same fault (``reorder: true`` lifts that);
* ``bus_corrupt``: a matching frame (with ``probability``) goes out with ``bits`` bits of its
  data flipped (the receiver counts ``bad_crc``), one bit of its 11-bit identifier flipped
  (``unknown_id`` or ``bad_crc``: the data ID under the CRC changed), or its length changed
  (shorter: ``wrong_length``);
* ``bus_babble``: while active the node floods ``rate_hz`` frames per second of garbage on
  ``message``'s first identifier with a random payload (bad CRC), or on identifier 0x000
  (the highest priority, not in the catalog);
* ``node_silent``: nothing the node sends (of ``message``, if given) goes out.

Each fault draws from its own generator seeded from (scenario seed, node, fault index), so a
fault added or removed live does not shift the draws of another. Counts: ``counts`` (frames
dropped, delayed, corrupted, babbled, silenced) for the node's records; the receivers count
what they saw (``bus.receiver`` classes).
"""

from __future__ import annotations

import heapq
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from bus.catalog import CATALOG, FRAME_BYTES, Catalog
from bus.codec import Frame
from bus.errors import BusError
from common.scenario import FaultSpec

KINDS = ("bus_drop", "bus_delay", "bus_corrupt", "bus_babble", "node_silent")
COUNTS = ("dropped", "delayed", "corrupted", "babbled", "silenced")
_COUNT_OF = dict(zip(KINDS, COUNTS, strict=True))
NODE_IDS = {"plant": 1, "flight": 2, "panel": 3}
# The messages a fault may be limited to (FAULT_CMD.message k names the k-th; 0 is "all").
MESSAGE_NAMES = tuple(sorted({f.set_name or f.name for f in CATALOG.frames}))
BABBLE_MAX_PER_CALL = 2000  # frames one release may flood (a long gap does not become a burst)


def message_ids(message: str | None, catalog: Catalog = CATALOG) -> frozenset[int] | None:
    """The identifiers of a catalog message (set) or frame name, with the authenticator of a
    secured message (``<name>_MAC``: the trailer of the secured PDU, bus.secoc, travels with
    it); None for "every frame". BusError (one line) for a name the catalog does not have."""
    if message is None:
        return None
    ids = {f.frame_id for f in catalog.frames
           if message in (f.name, f.set_name) or f.name == f"{message}_MAC"}
    if not ids:
        names = sorted({f.set_name or f.name for f in catalog.frames})
        raise BusError(f"bus fault: message: expected a catalog message or frame ({names}), "
                       f"got {message!r}")
    return frozenset(ids)


@dataclass
class ActiveFault:
    """One bus fault of this node, with its window in scenario seconds and its generator."""

    spec: FaultSpec
    index: int
    rng: np.random.Generator
    ids: frozenset[int] | None
    t_on_s: float
    t_off_s: float
    n_matched: int = 0
    last_release_s: float = -math.inf
    babble_last_s: float | None = None
    reported: bool = False

    def active(self, t_s: float) -> bool:
        return self.t_on_s <= t_s + 1e-9 and t_s < self.t_off_s - 1e-9

    def matches(self, fid: int) -> bool:
        return self.ids is None or fid in self.ids

    def hit(self) -> bool:
        """Does this matching frame get the fault (pattern or probability)?"""
        s = self.spec
        k = self.n_matched
        self.n_matched += 1
        if getattr(s, "pattern", None):
            return bool(s.pattern[k % len(s.pattern)])
        p = float(s.probability)
        return p >= 1.0 or bool(self.rng.random() < p)


@dataclass(order=True)
class _Held:
    due_s: float
    seq: int
    frame: Frame = field(compare=False)


class SendFaults:
    """The bus faults of one node's send path (module doc). Call it with the frames about to
    go out; it returns those that go out now. ``due(now_s)`` returns held and babbled frames
    whose time has come; ``next_due_s()`` says when the next one is."""

    def __init__(self, seed: int, node: str, clock: Callable[[], float] = time.time,
                 catalog: Catalog = CATALOG) -> None:
        if node not in NODE_IDS:
            raise BusError(f"bus fault: node: expected one of {list(NODE_IDS)}, got {node!r}")
        self.seed, self.node, self.clock, self.catalog = int(seed), node, clock, catalog
        self.faults: list[ActiveFault] = []
        self.t_s = 0.0  # the node's scenario time; the shell sets it every tick
        self.counts = {c: 0 for c in COUNTS}
        self.events: list[str] = []
        self._held: list[_Held] = []
        self._seq = 0
        self._n_added = 0

    # -- configuration --------------------------------------------------------------------

    def add(self, spec, t_on_s: float | None = None) -> ActiveFault:
        """Add fault ``spec`` (a ``FaultSpec`` of a bus kind for this node); it starts at
        ``t_on_s`` (default ``spec.t_s``) and ends at ``spec.clear_t_s`` (or never)."""
        if spec.kind not in KINDS:
            raise BusError(f"bus fault: kind: expected one of {list(KINDS)}, got {spec.kind!r}")
        i = self._n_added
        self._n_added += 1
        rng = np.random.default_rng([self.seed, NODE_IDS[self.node], i, 0xB05])
        f = ActiveFault(spec, i, rng, message_ids(spec.message, self.catalog),
                        spec.t_s if t_on_s is None else t_on_s,
                        math.inf if spec.clear_t_s is None else float(spec.clear_t_s))
        self.faults.append(f)
        return f

    def clear(self, kind: str | None, t_s: float) -> list[ActiveFault]:
        """End the active (or pending) faults of ``kind`` (every kind: None) at ``t_s``."""
        ended = []
        for f in self.faults:
            if (kind is None or f.spec.kind == kind) and f.t_off_s > t_s:
                f.t_off_s = max(t_s, f.t_on_s)
                ended.append(f)
        if ended:
            self.events.append(f"bus fault cleared on {self.node}: "
                               f"{', '.join(f.spec.kind for f in ended)} at {t_s:.2f} s")
        return ended

    def newly_active(self) -> list[dict]:
        """Faults active at ``t_s`` not reported before (the ``faults_injected`` entries)."""
        out = []
        for f in self.faults:
            if not f.reported and f.t_on_s <= self.t_s + 1e-9:
                f.reported = True
                s = f.spec
                out.append({"t_s": round(f.t_on_s, 6), "thruster": None, "type": s.kind,
                            "fraction": float(s.probability), "node": self.node,
                            "message": s.message,
                            "clear_t_s": None if math.isinf(f.t_off_s) else f.t_off_s})
                self.events.append(f"bus fault active on {self.node}: {describe(s)} "
                                   f"at {f.t_on_s:.2f} s")
        return out

    # -- the send path --------------------------------------------------------------------

    def __call__(self, frames: list[Frame]) -> list[Frame]:
        active = [f for f in self.faults if f.active(self.t_s)]
        if not active:
            return frames
        now = self.clock()
        out: list[Frame] = []
        for fr in frames:
            fr2: Frame | None = fr
            for f in active:
                if fr2 is None or not f.matches(fr.arbitration_id):
                    continue
                fr2 = self._apply(f, fr2, now)
            if fr2 is not None:
                out.append(fr2)
        return out

    def _apply(self, f: ActiveFault, fr: Frame, now: float) -> Frame | None:
        kind = f.spec.kind
        if kind == "node_silent":
            self.counts["silenced"] += 1
            return None
        if kind == "bus_babble":
            return fr  # babble adds frames (due), it does not touch the node's own
        if kind == "bus_delay":
            queued = not f.spec.reorder and f.last_release_s > now
            if not (f.hit() or queued):
                return fr
            lo = float(f.spec.delay_ms) / 1e3
            hi = lo if f.spec.delay_max_ms is None else float(f.spec.delay_max_ms) / 1e3
            d = lo if hi <= lo else float(f.rng.uniform(lo, hi))
            due = now + d
            if not f.spec.reorder:
                due = max(due, f.last_release_s)  # never before a frame held earlier
            f.last_release_s = max(f.last_release_s, due)
            heapq.heappush(self._held, _Held(due, self._seq, fr))
            self._seq += 1
            self.counts["delayed"] += 1
            return None
        if not f.hit():
            return fr
        if kind == "bus_drop":
            self.counts["dropped"] += 1
            return None
        self.counts["corrupted"] += 1
        return corrupt(fr, f.spec.corrupt, int(f.spec.bits), f.rng)

    def due(self, now_s: float | None = None) -> list[Frame]:
        """Frames whose time has come: delayed ones in release order, then babble."""
        now = self.clock() if now_s is None else now_s
        out = []
        while self._held and self._held[0].due_s <= now:
            out.append(heapq.heappop(self._held).frame)
        for f in self.faults:
            if f.spec.kind != "bus_babble":
                continue
            if not f.active(self.t_s):
                f.babble_last_s = None
                continue
            if f.babble_last_s is None:
                f.babble_last_s = now
                continue
            n = int((now - f.babble_last_s) * float(f.spec.rate_hz))
            if n <= 0:
                continue
            f.babble_last_s += n / float(f.spec.rate_hz)
            n = min(n, BABBLE_MAX_PER_CALL)
            fid = 0x000 if f.ids is None else min(f.ids)
            payload = f.rng.integers(0, 256, size=(n, FRAME_BYTES), dtype=np.uint8)
            out.extend(Frame(fid, bytes(row)) for row in payload)
            self.counts["babbled"] += n
        return out

    def next_due_s(self) -> float | None:
        """When ``due`` next has something (port clock), None when nothing is pending."""
        t = self._held[0].due_s if self._held else None
        for f in self.faults:
            if f.spec.kind == "bus_babble" and f.active(self.t_s):
                nxt = self.clock() + 0.002 if f.babble_last_s is None else \
                    f.babble_last_s + 1.0 / float(f.spec.rate_hz)
                t = nxt if t is None else min(t, nxt)
        return t

    @property
    def held(self) -> int:
        return len(self._held)


def corrupt(fr: Frame, what: str, bits: int, rng: np.random.Generator) -> Frame:
    """``fr`` with ``bits`` data bits flipped (``data``), one identifier bit flipped (``id``),
    or a shorter length (``length``: 0..7 bytes)."""
    if what == "id":
        return Frame(fr.arbitration_id ^ (1 << int(rng.integers(0, 11))), fr.data,
                     fr.is_fd, fr.is_extended_id)
    if what == "length":
        n = int(rng.integers(0, max(len(fr.data), 1)))
        return Frame(fr.arbitration_id, bytes(fr.data[:n]), fr.is_fd, fr.is_extended_id)
    data = bytearray(fr.data)
    nbits = 8 * len(data)
    for b in rng.choice(nbits, size=min(bits, nbits), replace=False):
        data[int(b) // 8] ^= 1 << (int(b) % 8)
    return Frame(fr.arbitration_id, bytes(data), fr.is_fd, fr.is_extended_id)


def describe(spec) -> str:
    """One line for the events: kind, what it matches, its parameters."""
    s = spec
    on = f" {s.message}" if s.message else ""
    if s.kind == "bus_drop":
        how = f"pattern {''.join(map(str, s.pattern))}" if s.pattern else f"p={s.probability:g}"
    elif s.kind == "bus_delay":
        rng = f"..{s.delay_max_ms:g}" if s.delay_max_ms is not None else ""
        how = f"{s.delay_ms:g}{rng} ms p={s.probability:g}" + (" reorder" if s.reorder else "")
    elif s.kind == "bus_corrupt":
        how = f"{s.corrupt} p={s.probability:g}" + (f" {s.bits} bits" if s.corrupt == "data"
                                                    else "")
    elif s.kind == "bus_babble":
        how = f"{s.rate_hz:g} frames/s"
    else:
        how = "silent"
    return f"{s.kind}{on} {how}"
