"""Thin transport over python-can: ``open_bus``, ``Port``, ``BusLogger`` (DESIGN.md section 4).

Clocks. python-can stamps received frames in wall-clock seconds: socketcan with the kernel's
receive timestamp (CLOCK_REALTIME), ``virtual`` and ``udp_multicast`` with ``time.time()``.
A ``Port`` therefore works in one named clock, ``Port.clock == "realtime"``: rx times it
returns, ``Port.now_s()`` and the ``now_s`` it passes to the receiver are all CLOCK_REALTIME.
Code that schedules on the monotonic clock converts explicitly with ``Port.to_monotonic_s``
(offset sampled once when the port opens; wall-clock steps after that show up as an error of
the same size, which is why the conversion is explicit and never silent).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import can
from pydantic import BaseModel, ConfigDict, Field

from bus.catalog import BITRATE_BPS
from bus.codec import Frame, Message, encode
from bus.e2e import Protector
from bus.receiver import Receiver, Verdict
from hil.errors import BusError

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

    def send(self, msg: Message) -> int:
        """Encode, protect and send every frame of ``msg``; returns frames sent.

        EncodeError for illegal values (before anything is sent). A transmit failure (buffer
        full, interface down) is counted in ``tx_errors``, not raised: the peer sees a gap.
        """
        frames = self.protect(msg)
        sent = 0
        for fr in frames:
            if self.send_frame(fr):
                sent += 1
        return sent

    def send_frame(self, fr: Frame) -> bool:
        """Send one frame as is (tests use it to inject corrupted frames)."""
        m = to_can_message(fr, time.time())
        try:
            self.bus.send(m)
        except (can.CanError, OSError):
            self.tx_errors += 1
            return False
        self.tx_frames += 1
        if self.logger:
            self.logger.log(m)
        return True

    def poll(self, timeout_s: float = 0.0) -> list[tuple[Message, float]]:
        """Wait up to ``timeout_s`` for the first frame, then drain what is queued."""
        out: list[tuple[Message, float]] = []
        timeout: float | None = timeout_s
        while True:
            try:
                m = self.bus.recv(timeout)
            except (can.CanError, OSError) as exc:
                self.receiver.counters["internal"] += 1
                self.receiver.events.append(Verdict("internal", detail=f"bus: recv failed: {exc}"))
                break
            if m is None:
                break
            timeout = 0.0
            if self.logger:
                self.logger.log(m)
            v = self.receiver.classify(from_can_message(m), self.now_s())
            if v.message is not None:
                out.append((v.message, v.rx_time_s))
        self.receiver.expire(self.now_s())
        return out

    def counts(self) -> dict[str, int]:
        return {**self.receiver.counts(), "tx_frames": self.tx_frames, "tx_errors": self.tx_errors}

    def close(self) -> None:
        if self.logger:
            self.logger.close()
        self.bus.shutdown()
