"""Sans-IO receiver: classify every frame, count what is wrong, assemble frame sets.

``Receiver.classify(frame, now_s) -> Verdict`` (docs/design.md section 4). Checks, in order:

1. ``unknown_id``: identifier not in the catalog (or extended / FD / remote / error frame);
2. ``wrong_length``: not 8 data bytes;
3. ``bad_crc``: the E2E CRC does not match (``bus.e2e``);
4. ``repeated_counter`` (delta 0) or ``counter_jump`` (delta > 1, ``lost`` = delta - 1
   frames). A jump of at most ``max_delta_counter`` is AUTOSAR's "ok, some lost": the frame
   itself is intact and is used (counted, with the lost count). A larger jump is not used
   (an old frame replayed looks like a large jump). The counter state follows every frame
   whose CRC is good, so the receiver resynchronises on the next frame. For the messages the
   node authenticates (``Receiver.authenticated``, set by the port with its SecOC key) the
   counter is counted but does not gate: anyone on the bus can send the counter that makes
   the genuine frame look repeated, and the authenticator's freshness does the counter's job;
5. ``stale``: ``now_s - frame.timestamp_s`` above the frame's catalog deadline. Both times
   must be in the same clock (the transport's, see ``bus.transport.Port.clock``);
6. ``out_of_range``: a signal outside its catalog limits;
7. frames of a set (THR_CMD, GYRO, FAULT_CMD) go to a ``SetAssembler``: the verdict is
   ``ok`` with ``message`` None until the set is complete. A set that is superseded by a
   newer key, has a frame twice, disagrees inside, or is older than its deadline is dropped
   and counted as ``incomplete_set`` (as a verdict from ``expire`` and as an event). For an
   authenticated set, a frame that differs from one already held starts a variant of the set
   instead, and sets of other keys are not superseded (at most ``VARIANTS`` variants of at
   most ``VARIANT_KEYS`` keys): each complete variant is handed on (``Verdict.messages``) and
   the authenticator keeps the one its authenticator verifies.

Nothing raises out of ``classify``: a bug in a check of ours becomes ``internal`` (counted).
Nothing bad is returned as a message: ``Verdict.message`` is set only when usable.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from bus import e2e
from bus.catalog import CATALOG, FRAME_BYTES, Catalog, FrameDef
from bus.codec import (
    MESSAGE_TYPES,
    Frame,
    Message,
    Signals,
    range_problem,
    set_name_of,
    to_physical,
    unpack,
)

CLASSES = (
    "ok",
    "bad_crc",
    "repeated_counter",
    "counter_jump",
    "wrong_length",
    "unknown_id",
    "out_of_range",
    "stale",
    "incomplete_set",
    "internal",
)


# Authenticated sets: variants of one key, and keys, held at once (see the module doc).
VARIANTS = 4
VARIANT_KEYS = 4


@dataclass(frozen=True)
class Verdict:
    """What the receiver made of one frame (or, for ``incomplete_set``, of a set).

    ``usable``: the frame passed every check. ``message``: a complete logical message, only
    when usable and its set is complete. ``lost``: frames missing before this one
    (counter_jump). ``detail``: one line, for the event log.
    """

    kind: str
    frame_name: str | None = None
    message: Message | None = None
    usable: bool = False
    lost: int = 0
    detail: str = ""
    rx_time_s: float | None = None
    messages: tuple[Message, ...] = ()  # further complete variants of an authenticated set


@dataclass
class _PendingSet:
    key: int  # low 8 bits of the set key
    first_rx_s: float
    signals: Signals = field(default_factory=dict)


class SetAssembler:
    """Assembles one logical message sent as a set of frames (one key pending at a time).

    A frame set is sent back to back by one node, so at most one key is in flight; a frame
    with another key means the pending set will never complete.
    """

    def __init__(self, set_name: str, catalog: Catalog = CATALOG, deadline_s: float | None = None):
        self.set_name = set_name
        self.frames = catalog.set_frames(set_name)
        self.names = tuple(f.name for f in self.frames)
        self.deadline_s = (
            deadline_s if deadline_s is not None else max(f.deadline_s for f in self.frames)
        )
        self.pending: _PendingSet | None = None
        self.incomplete = 0
        self.completed = 0
        # Authenticated set (Receiver.authenticate): variants by key, oldest key first.
        self.variants: dict[int, list[_PendingSet]] | None = None

    def _drop(self, why: str, rx_s: float | None) -> Verdict:
        p = self.pending
        self.pending = None
        return self._incomplete(p, why, rx_s)

    def _incomplete(self, p: _PendingSet | None, why: str, rx_s: float | None) -> Verdict:
        """Count a set (the pending one, or a variant) that will not complete."""
        self.incomplete += 1
        have = sorted(p.signals) if p else []
        return Verdict(
            "incomplete_set",
            self.set_name,
            detail=f"{self.set_name}: expected frames {', '.join(self.names)}, got "
            f"{', '.join(have) or 'none'} ({why})",
            rx_time_s=rx_s,
        )

    def _add_variant(
        self, f: FrameDef, phys: dict[str, float], rx_s: float
    ) -> tuple[list[Message], list[Verdict]]:
        """An authenticated set: the frame joins every variant of its key that lacks it, and
        starts a new variant beside each that holds a different one (module doc)."""
        assert self.variants is not None
        dropped: list[Verdict] = []
        key = int(phys[f.key_signal]) & 0xFF
        if key not in self.variants:
            if len(self.variants) >= VARIANT_KEYS:
                oldest = next(iter(self.variants))
                for p in self.variants.pop(oldest):
                    dropped.append(self._incomplete(p, "pushed out by newer keys", rx_s))
            self.variants[key] = []
        sets = self.variants[key]
        forks = []
        for p in sets:
            have = p.signals.get(f.name)
            if have is None:
                p.signals[f.name] = phys
            elif have != phys:
                forks.append(_PendingSet(key, rx_s, {**p.signals, f.name: phys}))
        if not sets:
            forks.append(_PendingSet(key, rx_s, {f.name: phys}))
        for q in forks:
            if q.signals not in [p.signals for p in sets]:
                sets.append(q)
        while len(sets) > VARIANTS:
            dropped.append(self._incomplete(sets.pop(0), "variants of the key", rx_s))
        out: list[Message] = []
        cls = MESSAGE_TYPES[self.set_name]
        check = getattr(cls, "set_problem", None)
        for p in [p for p in sets if len(p.signals) == len(self.frames)]:
            sets.remove(p)
            problem = check(p.signals) if check else None
            if problem:
                dropped.append(self._incomplete(p, problem, rx_s))
                continue
            self.completed += 1
            out.append(cls.from_signals(p.signals))
        if not sets:
            del self.variants[key]
        return out, dropped

    def add(
        self, f: FrameDef, phys: dict[str, float], rx_s: float
    ) -> tuple[Message | None, list[Verdict]]:
        """Add one valid frame. Returns (complete message or None, incomplete_set verdicts).
        An authenticated set (``variants``) may complete several variants at once: use
        ``add_all``."""
        msgs, dropped = self.add_all(f, phys, rx_s)
        return (msgs[0] if msgs else None), dropped

    def add_all(
        self, f: FrameDef, phys: dict[str, float], rx_s: float
    ) -> tuple[list[Message], list[Verdict]]:
        """Add one valid frame. Returns (complete messages, incomplete_set verdicts)."""
        if self.variants is not None:
            return self._add_variant(f, phys, rx_s)
        msg, dropped = self._add_one(f, phys, rx_s)
        return ([] if msg is None else [msg]), dropped

    def _add_one(
        self, f: FrameDef, phys: dict[str, float], rx_s: float
    ) -> tuple[Message | None, list[Verdict]]:
        dropped: list[Verdict] = []
        key_full = int(phys[f.key_signal])
        key = key_full & 0xFF
        if self.pending is not None and self.pending.key != key:
            dropped.append(self._drop(f"superseded by key {key_full}", rx_s))
        if self.pending is not None and f.name in self.pending.signals:
            dropped.append(self._drop(f"{f.name} twice", rx_s))
        if self.pending is None:
            self.pending = _PendingSet(key, rx_s)
        p = self.pending
        p.signals[f.name] = phys
        if len(p.signals) < len(self.frames):
            return None, dropped
        self.pending = None
        cls = MESSAGE_TYPES[self.set_name]
        check = getattr(cls, "set_problem", None)
        problem = check(p.signals) if check else None
        if problem:
            self.pending = p
            dropped.append(self._drop(problem, rx_s))
            return None, dropped
        self.completed += 1
        return cls.from_signals(p.signals), dropped

    def expire(self, now_s: float) -> list[Verdict]:
        if self.variants is not None:
            out = []
            for key, sets in list(self.variants.items()):
                for p in [p for p in sets if now_s - p.first_rx_s > self.deadline_s]:
                    sets.remove(p)
                    out.append(self._incomplete(p, f"older than {self.deadline_s} s", now_s))
                if not sets:
                    del self.variants[key]
            return out
        p = self.pending
        if p is not None and now_s - p.first_rx_s > self.deadline_s:
            return [self._drop(f"older than {self.deadline_s} s", now_s)]
        return []


class ThrCmdAssembler(SetAssembler):
    """The THR_CMD set (header + 4 frames of 8 thrusters): applied only when complete.

    ``take(tick)`` is what the plant calls at its deadline: the complete command of that tick,
    or None (the caller applies the safe action and counts the miss).
    """

    def __init__(self, catalog: Catalog = CATALOG, deadline_s: float | None = None):
        super().__init__("THR_CMD", catalog, deadline_s)
        self.ready: dict[int, Message] = {}

    def add_all(self, f, phys, rx_s):
        msgs, dropped = super().add_all(f, phys, rx_s)
        for msg in msgs if self.variants is None else ():  # variants: the authenticator picks
            self.ready[msg.tick] = msg
            for t in [t for t in self.ready if t < msg.tick - 4]:
                del self.ready[t]
        return msgs, dropped

    def take(self, tick: int):
        cmd = self.ready.pop(tick, None)
        for t in [t for t in self.ready if t < tick]:
            del self.ready[t]
        return cmd


class Receiver:
    """Classifies frames from one bus; per-class counters, an event list, frame sets.

    ``max_delta_counter``: largest counter step whose frame is still used (AUTOSAR
    MaxDeltaCounter). ``max_events``: the event list keeps the newest ones.
    """

    def __init__(
        self,
        catalog: Catalog = CATALOG,
        max_delta_counter: int = 3,
        accept: set[str] | None = None,
        max_events: int = 1000,
    ):
        self.catalog = catalog
        self.max_delta_counter = max_delta_counter
        self.accept = accept  # set names this node listens to (None: all)
        self.counters: Counter[str] = Counter({c: 0 for c in CLASSES})
        self.lost_frames = 0
        self.events: list[Verdict] = []
        self.max_events = max_events
        self._last_counter: dict[int, int] = {}
        # Messages this node authenticates (SecOC): their alive counter does not gate and
        # their sets keep variants (module doc). Set with ``authenticate``.
        self.authenticated: frozenset[str] = frozenset()
        self.thr_cmd = ThrCmdAssembler(catalog)
        self.assemblers: dict[str, SetAssembler] = {"THR_CMD": self.thr_cmd}
        for f in catalog.frames:
            if f.set_name and f.set_name not in self.assemblers:
                self.assemblers[f.set_name] = SetAssembler(f.set_name, catalog)

    def authenticate(self, names: frozenset[str] | set[str]) -> None:
        """The logical messages (set names, and their authenticators' names) this node
        authenticates; empty: none (the plain E2E checks)."""
        self.authenticated = frozenset(names)
        for name, a in self.assemblers.items():
            a.variants = ({} if a.variants is None else a.variants) \
                if name in self.authenticated else None
            a.pending = None

    def _record(self, v: Verdict) -> Verdict:
        self.counters[v.kind] += 1
        if v.kind != "ok":
            self.events.append(v)
            if len(self.events) > self.max_events:
                del self.events[: len(self.events) - self.max_events]
        return v

    def counts(self) -> dict[str, int]:
        """Counters per class (plus ``lost_frames``), as a plain dict."""
        return {**{c: self.counters[c] for c in CLASSES}, "lost_frames": self.lost_frames}

    @property
    def rejected(self) -> int:
        return sum(n for c, n in self.counters.items() if c not in ("ok", "counter_jump"))

    def classify(self, frame: Frame, now_s: float) -> Verdict:
        try:
            return self._classify(frame, now_s)
        except Exception as exc:  # noqa: BLE001 - a bug of ours must not kill the loop
            return self._record(
                Verdict(
                    "internal",
                    detail=f"receiver: {type(exc).__name__}: {exc}",
                    rx_time_s=frame.timestamp_s,
                )
            )

    def expire(self, now_s: float) -> list[Verdict]:
        """Drop frame sets older than their deadline; returns the incomplete_set verdicts."""
        out = []
        for a in self.assemblers.values():
            out.extend(self._record(v) for v in a.expire(now_s))
        return out

    def _classify(self, fr: Frame, now_s: float) -> Verdict:
        rx = fr.timestamp_s
        f = self.catalog.by_id.get(fr.arbitration_id)
        if f is None or fr.is_extended_id or fr.is_fd:
            return self._record(
                Verdict(
                    "unknown_id",
                    detail=f"bus: expected a catalog id, got "
                    f"0x{fr.arbitration_id:03X}"
                    f"{' (extended)' if fr.is_extended_id else ''}"
                    f"{' (fd)' if fr.is_fd else ''}",
                    rx_time_s=rx,
                )
            )
        name = f.name
        if len(fr.data) != FRAME_BYTES:
            return self._record(
                Verdict(
                    "wrong_length",
                    name,
                    detail=f"{name}: expected {FRAME_BYTES} bytes, got {len(fr.data)}",
                    rx_time_s=rx,
                )
            )
        if not e2e.crc_ok(f.data_id, fr.data):
            return self._record(
                Verdict(
                    "bad_crc",
                    name,
                    detail=f"{name}: expected CRC "
                    f"0x{e2e.frame_crc(f.data_id, fr.data):02X}, got "
                    f"0x{fr.data[0]:02X}",
                    rx_time_s=rx,
                )
            )
        ctr = e2e.counter_of(fr.data)
        prev = self._last_counter.get(f.data_id)
        self._last_counter[f.data_id] = ctr
        lost = 0
        advisory = None  # an authenticated message's counter fault: counted, not gating
        if prev is not None and set_name_of(f) in self.authenticated:
            delta = e2e.counter_delta(prev, ctr)
            lost = delta - 1 if 1 < delta <= self.max_delta_counter else 0
            if delta == 0 or delta > self.max_delta_counter:
                advisory = (
                    "repeated_counter" if delta == 0 else "counter_jump",
                    f"{name}: expected counter {(prev + 1) % 16}, got {ctr} (authenticated: "
                    f"used, its authenticator decides)",
                )
        elif prev is not None:
            delta = e2e.counter_delta(prev, ctr)
            if delta == 0:
                return self._record(
                    Verdict(
                        "repeated_counter",
                        name,
                        detail=f"{name}: expected counter {(prev + 1) % 16}, got {ctr}",
                        rx_time_s=rx,
                    )
                )
            lost = delta - 1
            if delta > self.max_delta_counter:
                self.lost_frames += lost
                return self._record(
                    Verdict(
                        "counter_jump",
                        name,
                        lost=lost,
                        detail=f"{name}: "
                        f"expected counter {(prev + 1) % 16}, got {ctr} "
                        f"(jump > {self.max_delta_counter}, not used)",
                        rx_time_s=rx,
                    )
                )
        if rx is not None and now_s - rx > f.deadline_s:
            return self._record(
                Verdict(
                    "stale",
                    name,
                    detail=f"{name}: expected age <= {f.deadline_s} s, got {now_s - rx:.6f} s",
                    rx_time_s=rx,
                )
            )
        raws = unpack(f, fr.data)
        problem = range_problem(f, raws)
        if problem:
            return self._record(Verdict("out_of_range", name, detail=problem, rx_time_s=rx))
        set_name = set_name_of(f)
        if self.accept is not None and set_name not in self.accept:
            return self._record(
                Verdict("ok", name, usable=True, rx_time_s=rx, detail="not for this node")
            )
        phys = to_physical(f, raws)
        kind = "ok"
        detail = ""
        if advisory is not None:
            kind, detail = advisory
        elif lost:
            self.lost_frames += lost
            kind = "counter_jump"
            detail = f"{name}: expected counter {(prev + 1) % 16}, got {ctr} ({lost} lost)"
        more: tuple[Message, ...] = ()
        if f.set_name:
            msgs, dropped = self.assemblers[f.set_name].add_all(
                f, phys, rx if rx is not None else now_s)
            for v in dropped:
                self._record(v)
            msg = msgs[0] if msgs else None
            more = tuple(msgs[1:])
        else:
            msg = MESSAGE_TYPES[set_name].from_signals({name: phys})
        return self._record(
            Verdict(kind, name, message=msg, usable=True, lost=lost, detail=detail, rx_time_s=rx,
                    messages=more)
        )
