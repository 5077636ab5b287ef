"""Thin transport over python-can: ``open_bus``, ``Port``, ``BusLogger`` (docs/design.md section 4).

Clocks. python-can stamps received frames in wall-clock seconds: socketcan with the kernel's
receive timestamp (CLOCK_REALTIME), ``virtual`` and ``udp_multicast`` with ``time.time()``.
A ``Port`` therefore works in one named clock, ``Port.clock == "realtime"``: rx times it
returns, ``Port.now_s()`` and the ``now_s`` it passes to the receiver are all CLOCK_REALTIME.
Code that schedules on the monotonic clock converts explicitly with ``Port.to_monotonic_s``
(``clock_offset_s``: the narrowest of a few bracketed reads of both clocks, so that a process
preempted between two reads does not carry that stall into every conversion; sampled again
once it is ``OFFSET_RESAMPLE_S`` old, so that a wall-clock step or slew shows up for at most
that long).

Backends. ``open_bus`` opens python-can buses by name. The ``socketcan`` interface opens this
project's backend ``hil_socketcan`` (``bus.socketcan_fast.FastSocketcanBus``, a python-can
``SocketcanBus`` registered through python-can's ``can.interface`` entry points), which also
offers batch frame I/O (``FrameBus``: a message of several frames in one ``sendmmsg``, a
receive queue drained with one ``select``); a ``Port`` uses that when its bus offers it, and
python-can's ``send``/``recv`` otherwise. Every other interface goes through python-can
unchanged.

Send path. Every frame a ``Port`` sends passes ``Port.send_hook`` (when set) after encoding
and E2E protection, just before the wire: the one place where bus faults (drop, delay,
corrupt, babble, silence: ``bus.faults.SendFaults``) attach. A hook that holds frames back
(delay) or adds its own (babble) also offers ``due(now_s)`` and ``next_due_s()``: the port
sends what is due on every ``send`` and ``poll``, and a ``poll`` waits no longer than until
the next one is due.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import can
from pydantic import BaseModel, ConfigDict, Field

from bus.catalog import BITRATE_BPS, Node, consumed_ids
from bus.codec import Frame, Message, encode
from bus.e2e import Protector
from bus.errors import BusError
from bus.receiver import Receiver, Verdict

CLOCK = "realtime"
OFFSET_RESAMPLE_S = 1.0
_OFFSET_READS = 5


def clock_offset_s() -> tuple[float, float]:
    """``time.monotonic() - time.time()`` and the uncertainty of it (seconds): of a few
    ``monotonic, time, monotonic`` reads, the one whose two monotonic reads are closest (a
    process descheduled between two reads of a pair, under load a few milliseconds, would
    otherwise offset every converted time by as much)."""
    best_w, best = float("inf"), 0.0
    for _ in range(_OFFSET_READS):
        m0 = time.monotonic()
        r = time.time()
        m1 = time.monotonic()
        if m1 - m0 < best_w:
            best_w, best = m1 - m0, 0.5 * (m0 + m1) - r
    return best, best_w


class BusConfig(BaseModel):
    """Which bus to open. ``kwargs`` go to ``can.Bus`` unchanged (e.g. ``port`` for
    udp_multicast, ``receive_own_messages``, adapter-specific options)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    interface: str = "socketcan"
    channel: str = "vcan0"
    bitrate: int = Field(default=BITRATE_BPS, gt=0)
    fd: bool = False
    kwargs: dict[str, Any] = Field(default_factory=dict)


_HINTS = {"socketcan": "; run `hil vcan up` or `hil vcan exec`"}
# Configured interface name -> the python-can backend (by its registered name) that opens it.
BACKENDS = {"socketcan": "hil_socketcan"}


@runtime_checkable
class FrameBus(Protocol):
    """A python-can bus that also sends and receives this project's ``Frame`` in batches
    (``bus.socketcan_fast.FastSocketcanBus``)."""

    def send_frame(self, fr: Frame) -> bool: ...

    def send_frames(self, frames: list[Frame]) -> int: ...

    def drain_frames(self, timeout_s: float, got: list, with_messages: bool = False,
                     limit: int | None = None) -> None: ...


SendHook = Callable[[list[Frame]], list[Frame]]


def node_filters(node: Node) -> list[dict[str, Any]]:
    """python-can ``can_filters`` letting through only the identifiers ``node`` consumes (from
    the catalog). SocketCAN applies them in the kernel (``CAN_RAW_FILTER``): a frame of
    another identifier never wakes the process; other interfaces filter in python-can."""
    return [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in consumed_ids(node)]


def udp_channel(channel: str) -> tuple[str, int | None]:
    """udp_multicast's channel: ``GROUP`` or ``GROUP:PORT`` for an IPv4 group (python-can
    binds every such socket to one UDP port, and Linux hands a datagram for a group joined on
    the host to every socket bound to its port: two runs on one host keep apart by their
    ports, not by their groups). BusError (one line) for a bad port."""
    group, sep, port = channel.rpartition(":")
    if not sep or group.count(".") != 3:
        return channel, None  # a group alone (IPv6 groups hold colons: no port form)
    if not port.isdigit() or not 1 <= int(port) <= 65535:
        raise BusError(f"bus: udp_multicast channel {channel!r}: expected GROUP or GROUP:PORT "
                       f"with a port 1-65535, got port {port!r}")
    return group, int(port)


def open_bus(cfg: BusConfig | None = None) -> can.BusABC:
    """Open the configured python-can bus; BusError (one line) if it cannot be opened."""
    cfg = cfg or BusConfig()
    kwargs = dict(cfg.kwargs)
    channel = cfg.channel
    if cfg.interface == "udp_multicast":
        channel, port = udp_channel(channel)
        if port is not None:
            kwargs["port"] = port
    if cfg.interface not in ("socketcan", "virtual", "udp_multicast"):
        kwargs.setdefault("bitrate", cfg.bitrate)  # real adapters configure their bit rate
    if cfg.fd:
        kwargs["fd"] = True
    try:
        return can.Bus(interface=BACKENDS.get(cfg.interface, cfg.interface),
                       channel=channel, **kwargs)
    except (OSError, can.CanError, ImportError, ValueError, NotImplementedError) as exc:
        hint = _HINTS.get(cfg.interface, "")
        raise BusError(
            f"bus: cannot open {cfg.interface} channel {cfg.channel}: {exc}{hint}"
        ) from exc


def to_can_message(fr: Frame, timestamp_s: float = 0.0) -> can.Message:
    """A frame we transmit (``is_rx`` False: the log marks it ``T``, received ones ``R``)."""
    return can.Message(
        arbitration_id=fr.arbitration_id,
        data=fr.data,
        is_extended_id=fr.is_extended_id,
        is_fd=fr.is_fd,
        timestamp=timestamp_s,
        is_rx=False,
    )


def from_can_message(msg: can.Message) -> Frame:
    """python-can message to the core's Frame. Error and remote frames get id -1 (unknown)."""
    bad = msg.is_error_frame or msg.is_remote_frame
    return Frame(
        -1 if bad else msg.arbitration_id,
        bytes(msg.data),
        bool(msg.is_fd),
        bool(msg.is_extended_id),
        float(msg.timestamp),
    )


def _echoes_own_frames(bus: can.BusABC) -> bool:
    """True for python-can buses that deliver a node's own frames back to it (udp_multicast)."""
    return type(bus).__name__ == "UdpMulticastBus"


class BusLogger:
    """Every frame in and out as a candump ``-L`` log (``(time) channel id#data``).

    Readable by ``can.LogReader``, ``canplayer`` and ``python -m can.player``; decodable with
    ``bus/hil.dbc``. Times are the port's clock (CLOCK_REALTIME), as candump writes them.
    """

    def __init__(self, path: str | Path, channel: str = "vcan0"):
        self.path = Path(path)
        self.channel = channel
        self._writer = can.CanutilsLogWriter(str(self.path), channel=channel)

    def log(self, msg: can.Message) -> None:
        self._writer.on_message_received(msg)

    def close(self) -> None:
        self._writer.stop()


class Port:
    """A node's port on the bus: encodes, protects and sends; receives, classifies, assembles.

    ``poll(timeout_s)`` returns the complete, valid messages as (message, rx_time_s) in the
    port's clock; every rejected frame is counted in ``receiver`` and never raises.
    """

    clock = CLOCK

    def __init__(
        self, bus: can.BusABC, receiver: Receiver | None = None, logger: BusLogger | None = None,
        send_hook: SendHook | None = None, max_frames_per_poll: int | None = None,
    ):
        self.bus = bus
        self.receiver = receiver or Receiver()
        self.protector = Protector()
        self.logger = logger
        self.tx_frames = 0
        self.tx_errors = 0
        self.monotonic_offset_s, self.monotonic_offset_width_s = clock_offset_s()
        self._offset_at = time.monotonic()
        # Batch frame I/O where the bus offers it (not on a socket bound to every interface).
        self._raw: FrameBus | None = (
            bus if isinstance(bus, FrameBus) and getattr(bus, "channel", None) != "" else None)
        # The frames about to go on the wire -> the frames that do (see the module doc).
        self.send_hook = send_hook
        # udp_multicast loops every datagram back to its sender: remember what we sent and drop
        # the first matching frame received (loopback keeps the send order; with the alive
        # counter and CRC, a peer's frame equal to one of ours in flight cannot occur).
        self._echo: collections.deque[tuple[int, bytes]] | None = (
            collections.deque(maxlen=4096) if _echoes_own_frames(bus) else None
        )
        self.echoes_dropped = 0
        # Bounded work per poll: at most this many frames are taken from the socket per
        # ``poll``; the rest wait in the kernel's queue for the next one (what overflows that
        # queue the kernel drops and counts, ``kernel_drops``). None: no bound.
        self.max_frames_per_poll = max_frames_per_poll
        self.polls_capped = 0
        # SecOC (bus.secoc.Authenticator): signs the secured messages (SECURED) on send, hands on
        # received ones only once authenticated. None: no authentication.
        self._auth = None

    @property
    def auth(self):
        return self._auth

    @auth.setter
    def auth(self, auth) -> None:
        """Setting an authenticator also tells the receiver which messages it authenticates:
        their alive counter stops gating and their sets keep variants (bus.receiver)."""
        from bus.secoc import AUTHENTICATED_SETS

        self._auth = auth
        self.receiver.authenticate(AUTHENTICATED_SETS if auth is not None else frozenset())

    @staticmethod
    def now_s() -> float:
        """Now in the port's clock (CLOCK_REALTIME seconds)."""
        return time.time()

    def to_monotonic_s(self, t_realtime_s: float) -> float:
        """A time of this port's clock converted to ``time.monotonic()`` seconds (the offset
        sampled again once it is ``OFFSET_RESAMPLE_S`` old)."""
        now = time.monotonic()
        if now - self._offset_at > OFFSET_RESAMPLE_S:
            self.monotonic_offset_s, self.monotonic_offset_width_s = clock_offset_s()
            self._offset_at = now
        return t_realtime_s + self.monotonic_offset_s

    def protect(self, msg: Message, plain: list[Frame] | None = None) -> list[Frame]:
        """The frames of ``msg`` with E2E counter and CRC (advances the counters); ``plain``:
        ``encode(msg)`` when the caller has it already."""
        out = []
        for fr in encode(msg) if plain is None else plain:
            f_def = self.receiver.catalog.by_id[fr.arbitration_id]
            out.append(Frame(fr.arbitration_id, self.protector.protect(f_def.data_id, fr.data)))
        return out

    def frames_to_send(self, msgs) -> list[Frame]:
        """The protected frames of ``msgs`` in order, with an authenticator after each
        secured message when the port authenticates (``bus.secoc``); every transport sends
        these."""
        if self.auth is None:
            return [fr for msg in msgs for fr in self.protect(msg)]
        now = self.now_s()
        frames: list[Frame] = []
        for msg in msgs:
            plain = encode(msg)
            frames += self.protect(msg, plain)
            mac = self.auth.sign(msg, now, plain)
            if mac is not None:
                frames += self.protect(mac)
        return frames

    def send(self, *msgs: Message) -> int:
        """Encode, protect and send every frame of ``msgs`` (in order); returns frames sent.

        Several messages given at once go out together (one ``sendmmsg`` on socketcan).
        EncodeError for illegal values (before anything is sent). A transmit failure (buffer
        full, interface down) is counted in ``tx_errors``, not raised: the peer sees a gap.
        """
        frames = self.frames_to_send(msgs)
        if self.send_hook is not None:
            self.release_due()
            frames = self.send_hook(frames)
        if self._raw is not None and len(frames) > 1:
            sent = self._raw.send_frames(frames)
            self.tx_frames += sent
            self.tx_errors += len(frames) - sent
            if self.logger:
                t = time.time()
                for fr in frames[:sent]:
                    self.logger.log(to_can_message(fr, t))
            return sent
        sent = 0
        for fr in frames:
            if self._put(fr):
                sent += 1
        return sent

    def send_frame(self, fr: Frame) -> bool:
        """Send one frame as is (tests use it to inject corrupted frames), through the hook;
        False when it did not go out (or the hook dropped it)."""
        frames = [fr] if self.send_hook is None else self.send_hook([fr])
        sent = [self._put(f) for f in frames]
        return bool(sent) and all(sent)

    def release_due(self) -> int:
        """Send what the send hook held back and is now due (delayed or babbled frames)."""
        due = getattr(self.send_hook, "due", None)
        if due is None:
            return 0
        return sum(self._put(fr) for fr in due(self.now_s()))

    def _hook_wait_s(self, timeout_s: float) -> float:
        nxt = getattr(self.send_hook, "next_due_s", None)
        t = None if nxt is None else nxt()
        return timeout_s if t is None else max(0.0, min(timeout_s, t - self.now_s()))

    def _put(self, fr: Frame) -> bool:
        """One frame on the wire, counted in ``tx_frames`` or ``tx_errors``."""
        if self._raw is not None:
            ok = self._raw.send_frame(fr)
            if ok and self.logger:
                self.logger.log(to_can_message(fr, time.time()))
        else:
            m = to_can_message(fr, time.time())
            try:
                self.bus.send(m)
                ok = True
            except (can.CanError, OSError):
                ok = False
            if ok and self.logger:
                self.logger.log(m)
            if ok and self._echo is not None:
                self._echo.append((fr.arbitration_id, bytes(fr.data)))
        if ok:
            self.tx_frames += 1
        else:
            self.tx_errors += 1
        return ok

    def poll(self, timeout_s: float = 0.0) -> list[tuple[Message, float]]:
        """Wait up to ``timeout_s`` for the first frame, then drain what is queued (the wait
        ends early when the send hook has frames due, which then go out)."""
        got: list[tuple[Frame, can.Message | None]] = []
        if self.send_hook is not None:
            self.release_due()
            timeout_s = self._hook_wait_s(timeout_s)
        try:
            cap = self.max_frames_per_poll
            if self._raw is not None:
                self._raw.drain_frames(timeout_s, got, with_messages=self.logger is not None,
                                       limit=cap)
            else:
                self._drain_python_can(timeout_s, got, cap)
            if cap is not None and len(got) >= cap:
                self.polls_capped += 1
        except (can.CanError, OSError) as exc:
            self.receiver.counters["internal"] += 1
            self.receiver.events.append(Verdict("internal", detail=f"bus: recv failed: {exc}"))
        now = self.now_s()  # one clock read per poll: every frame here arrived before it
        out: list[tuple[Message, float]] = []
        for fr, m in got:
            if self.logger and m is not None:
                self.logger.log(m)
            v = self.receiver.classify(fr, now)
            if v.message is not None:
                out.append((v.message, v.rx_time_s))
                out.extend((m, v.rx_time_s) for m in v.messages)
        self.receiver.expire(now)
        if self.auth is not None:
            out = self.auth.accept(out, now)
        if self.send_hook is not None:
            self.release_due()
        return out

    def _drain_python_can(self, timeout_s: float,
                          got: list[tuple[Frame, can.Message | None]],
                          cap: int | None = None) -> None:
        timeout: float | None = timeout_s
        echo = self._echo
        while cap is None or len(got) < cap:
            m = self.bus.recv(timeout)
            if m is None:
                return
            timeout = 0.0
            if echo and (m.arbitration_id, bytes(m.data)) in echo:
                echo.remove((m.arbitration_id, bytes(m.data)))  # our own frame, looped back
                self.echoes_dropped += 1
                continue
            got.append((from_can_message(m), m))

    def counts(self) -> dict[str, int]:
        out = {**self.receiver.counts(), "tx_frames": self.tx_frames, "tx_errors": self.tx_errors}
        injected = getattr(self.send_hook, "counts", None)
        if injected is not None:  # bus faults this node's send path injected (bus.faults)
            out.update({f"injected_{k}": v for k, v in injected.items()})
        drops = getattr(self.bus, "kernel_drops", None)
        if drops is not None:  # SocketCAN: frames the kernel dropped, receive queue full
            out["kernel_drops"] = drops
        if self.max_frames_per_poll is not None:
            out["polls_capped"] = self.polls_capped
        if self.auth is not None:
            out.update(self.auth.counts)
        return out

    def close(self) -> None:
        if self.logger:
            self.logger.close()
        self.bus.shutdown()
