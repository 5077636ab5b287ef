"""Thin transport over python-can: ``open_bus``, ``Port``, ``BusLogger`` (docs/design.md section 4).

Clocks. python-can stamps received frames in wall-clock seconds: socketcan with the kernel's
receive timestamp (CLOCK_REALTIME), ``virtual`` and ``udp_multicast`` with ``time.time()``.
A ``Port`` therefore works in one named clock, ``Port.clock == "realtime"``: rx times it
returns, ``Port.now_s()`` and the ``now_s`` it passes to the receiver are all CLOCK_REALTIME.
Code that schedules on the monotonic clock converts explicitly with ``Port.to_monotonic_s``
(offset sampled once when the port opens; wall-clock steps after that show up as an error of
the same size, which is why the conversion is explicit and never silent).

System calls. On socketcan a ``Port`` talks to python-can's socket directly: a message of
several frames (THR_CMD: 5, GYRO: 2) goes out in one ``sendmmsg`` (the receiver wakes once
for the whole set), a single frame in one ``send`` (python-can's ``send`` adds a ``select``
and two clock reads per frame); ``poll`` is one ``select`` followed by non-blocking
``recvmsg`` until the queue is empty (python-can's ``recv`` adds a ``select`` and a clock
read per frame). Under user-mode Linux every system call, clock reads included, costs tens of
microseconds: sending THR_CMD went from 1.2 ms to 0.27 ms there (``bench/bench_transport.py``
measures both paths). Every other interface goes through python-can unchanged.
"""

from __future__ import annotations

import collections
import select
import socket
import time
from pathlib import Path
from typing import Any

import can
from pydantic import BaseModel, ConfigDict, Field

from bus.catalog import BITRATE_BPS
from bus.codec import Frame, Message, encode
from bus.e2e import Protector
from bus.errors import BusError
from bus.receiver import Receiver, Verdict

CLOCK = "realtime"


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


def open_bus(cfg: BusConfig | None = None) -> can.BusABC:
    """Open the configured python-can bus; BusError (one line) if it cannot be opened."""
    cfg = cfg or BusConfig()
    kwargs = dict(cfg.kwargs)
    if cfg.interface not in ("socketcan", "virtual", "udp_multicast"):
        kwargs.setdefault("bitrate", cfg.bitrate)  # real adapters configure their bit rate
    if cfg.fd:
        kwargs["fd"] = True
    try:
        return can.Bus(interface=cfg.interface, channel=cfg.channel, **kwargs)
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
        self, bus: can.BusABC, receiver: Receiver | None = None, logger: BusLogger | None = None
    ):
        self.bus = bus
        self.receiver = receiver or Receiver()
        self.protector = Protector()
        self.logger = logger
        self.tx_frames = 0
        self.tx_errors = 0
        self.monotonic_offset_s = time.monotonic() - time.time()
        self._raw = _RawSocketcan.wrap(bus)
        # udp_multicast loops every datagram back to its sender: remember what we sent and drop
        # the first matching frame received (loopback keeps the send order; with the alive
        # counter and CRC, a peer's frame equal to one of ours in flight cannot occur).
        self._echo: collections.deque[tuple[int, bytes]] | None = (
            collections.deque(maxlen=4096) if _echoes_own_frames(bus) else None
        )
        self.echoes_dropped = 0

    @staticmethod
    def now_s() -> float:
        """Now in the port's clock (CLOCK_REALTIME seconds)."""
        return time.time()

    def to_monotonic_s(self, t_realtime_s: float) -> float:
        """A time of this port's clock converted to ``time.monotonic()`` seconds."""
        return t_realtime_s + self.monotonic_offset_s

    def protect(self, msg: Message) -> list[Frame]:
        """The frames of ``msg`` with E2E counter and CRC (advances the counters)."""
        out = []
        for fr in encode(msg):
            f_def = self.receiver.catalog.by_id[fr.arbitration_id]
            out.append(Frame(fr.arbitration_id, self.protector.protect(f_def.data_id, fr.data)))
        return out

    def send(self, *msgs: Message) -> int:
        """Encode, protect and send every frame of ``msgs`` (in order); returns frames sent.

        Several messages given at once go out together (one ``sendmmsg`` on socketcan).
        EncodeError for illegal values (before anything is sent). A transmit failure (buffer
        full, interface down) is counted in ``tx_errors``, not raised: the peer sees a gap.
        """
        frames = [fr for msg in msgs for fr in self.protect(msg)]
        if self._raw is not None and len(frames) > 1:
            sent = self._raw.send_many(frames)
            self.tx_frames += sent
            self.tx_errors += len(frames) - sent
            if self.logger:
                t = time.time()
                for fr in frames[:sent]:
                    self.logger.log(to_can_message(fr, t))
            return sent
        sent = 0
        for fr in frames:
            if self.send_frame(fr):
                sent += 1
        return sent

    def send_frame(self, fr: Frame) -> bool:
        """Send one frame as is (tests use it to inject corrupted frames)."""
        if self._raw is not None:
            ok = self._raw.send(fr)
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
        """Wait up to ``timeout_s`` for the first frame, then drain what is queued."""
        got: list[tuple[Frame, can.Message | None]] = []
        try:
            if self._raw is not None:
                self._raw.drain(timeout_s, got, with_messages=self.logger is not None)
            else:
                self._drain_python_can(timeout_s, got)
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
        self.receiver.expire(now)
        return out

    def _drain_python_can(self, timeout_s: float,
                          got: list[tuple[Frame, can.Message | None]]) -> None:
        timeout: float | None = timeout_s
        echo = self._echo
        while True:
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
        return {**self.receiver.counts(), "tx_frames": self.tx_frames, "tx_errors": self.tx_errors}

    def close(self) -> None:
        if self.logger:
            self.logger.close()
        self.bus.shutdown()


class _RawSocketcan:
    """python-can's SocketCAN socket used directly: fewer system calls per frame.

    ``send`` is one non-blocking ``send(2)`` (a full queue is a failed send, as python-can's
    ``send`` without a timeout). ``drain`` is one ``select(2)`` (none when ``timeout_s`` is 0)
    and then non-blocking ``recvmsg(2)`` until the queue is empty; frames keep the kernel's
    receive time stamp (CLOCK_REALTIME, ``SO_TIMESTAMPNS`` as python-can sets it).
    """

    def __init__(self, sock: socket.socket, mod: Any) -> None:
        self.sock = sock
        self._mod = mod
        self._dontwait = socket.MSG_DONTWAIT
        self._ancillary = mod.RECEIVED_ANCILLARY_BUFFER_SIZE
        self._mtu = mod.constants.CANFD_MTU
        self._ts = mod.RECEIVED_TIMESTAMP_STRUCT
        self._hdr = mod.CAN_FRAME_HEADER_STRUCT
        self._mm: _Sendmmsg | None | bool = False  # made on first use (buffers of this port)
        self._eff, self._rtr, self._err = (mod.constants.CAN_EFF_FLAG, mod.constants.CAN_RTR_FLAG,
                                           mod.constants.CAN_ERR_FLAG)

    @classmethod
    def wrap(cls, bus: can.BusABC) -> _RawSocketcan | None:
        try:
            from can.interfaces.socketcan import socketcan as mod
        except ImportError:  # not Linux
            return None
        if not isinstance(bus, mod.SocketcanBus) or not isinstance(
                getattr(bus, "socket", None), socket.socket) or bus.channel == "":
            return None
        return cls(bus.socket, mod)

    def send(self, fr: Frame) -> bool:
        data = self._wire(fr)
        try:
            return self.sock.send(data, self._dontwait) == len(data)
        except OSError:  # ENOBUFS / EAGAIN (queue full), ENETDOWN (interface down)
            return False

    def send_many(self, frames: list[Frame]) -> int:
        """All frames in one ``sendmmsg(2)`` (the receiver gets the set at once); frames sent.

        Falls back to one ``send`` per frame where ``sendmmsg`` is not available (or for CAN
        FD frames). Frames the kernel did not take are not retried: the caller counts them.
        """
        if self._mm is False:
            self._mm = _Sendmmsg.create()
        mm = self._mm
        if mm is None or len(frames) > mm.slots or any(f.is_fd or len(f.data) > 8
                                                       for f in frames):
            n = 0
            for fr in frames:
                if not self.send(fr):
                    break
                n += 1
            return n
        return mm.send(self.sock.fileno(), [self._wire(fr) for fr in frames])

    def _wire(self, fr: Frame) -> bytes:
        if fr.is_fd or len(fr.data) > 8:
            data = self._mod.build_can_frame(to_can_message(fr))
        else:
            can_id = fr.arbitration_id | (self._eff if fr.is_extended_id else 0)
            data = self._hdr.pack(can_id, len(fr.data), 0, len(fr.data)) + \
                bytes(fr.data).ljust(8, b"\x00")
        return data

    def drain(self, timeout_s: float, got: list[tuple[Frame, can.Message | None]],
              with_messages: bool = False) -> None:
        """Append every queued frame to ``got`` (with its python-can message for a logger)."""
        if timeout_s > 0 and not select.select([self.sock], [], [], timeout_s)[0]:
            return
        while True:
            try:
                cf, anc, _flags, _addr = self.sock.recvmsg(self._mtu, self._ancillary,
                                                            self._dontwait)
            except BlockingIOError:
                return
            can_id, dlc, _fl, data = self._mod.dissect_can_frame(cf)
            ts = 0.0
            if anc:
                sec, ns = self._ts.unpack_from(anc[0][2])
                ts = sec + ns * 1e-9
            ext = bool(can_id & self._eff)
            rtr, err = bool(can_id & self._rtr), bool(can_id & self._err)
            arb = can_id & (0x1FFFFFFF if ext else 0x7FF)
            is_fd = len(cf) == self._mtu
            fr = Frame(-1 if rtr or err else arb, bytes(data), is_fd, ext, ts)
            m = None
            if with_messages:
                m = can.Message(timestamp=ts, arbitration_id=arb, is_extended_id=ext,
                                is_remote_frame=rtr, is_error_frame=err, is_fd=is_fd,
                                dlc=dlc, data=data)
            got.append((fr, m))


class _Sendmmsg:
    """``sendmmsg(2)`` through ctypes with preallocated buffers (classic 16-byte CAN frames).

    One per port (the buffers are reused on every call; a port is used by one thread)."""

    slots = 32

    def __init__(self) -> None:
        import ctypes

        class IoVec(ctypes.Structure):
            _fields_ = [("base", ctypes.c_void_p), ("len", ctypes.c_size_t)]

        class MsgHdr(ctypes.Structure):
            _fields_ = [("name", ctypes.c_void_p), ("namelen", ctypes.c_uint32),
                        ("iov", ctypes.POINTER(IoVec)), ("iovlen", ctypes.c_size_t),
                        ("control", ctypes.c_void_p), ("controllen", ctypes.c_size_t),
                        ("flags", ctypes.c_int)]

        class MMsgHdr(ctypes.Structure):
            _fields_ = [("hdr", MsgHdr), ("len", ctypes.c_uint)]

        self._libc = ctypes.CDLL(None, use_errno=True)
        self._fn = self._libc.sendmmsg
        self._buf = ctypes.create_string_buffer(16 * self.slots)
        base = ctypes.addressof(self._buf)
        self._iov = (IoVec * self.slots)(*[IoVec(base + 16 * i, 16) for i in range(self.slots)])
        self._msgs = (MMsgHdr * self.slots)()
        for i in range(self.slots):
            self._msgs[i].hdr.iov = ctypes.pointer(self._iov[i])
            self._msgs[i].hdr.iovlen = 1
        self._flags = socket.MSG_DONTWAIT

    @classmethod
    def create(cls) -> _Sendmmsg | None:
        try:
            return cls()
        except (OSError, AttributeError):  # no libc sendmmsg here: one send per frame
            return None

    def send(self, fd: int, wires: list[bytes]) -> int:
        for i, w in enumerate(wires):
            self._buf[16 * i:16 * i + 16] = w
        n = self._fn(fd, self._msgs, len(wires), self._flags)
        return max(n, 0)
