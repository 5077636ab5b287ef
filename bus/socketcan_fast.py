"""This project's SocketCAN backend: python-can's ``SocketcanBus`` with batch frame I/O.

Registered with python-can by name (``hil_socketcan``, an entry point of the ``can.interface``
group in ``pyproject.toml``, read into python-can's backend table ``can.interfaces.BACKENDS``),
and opened by ``bus.transport.open_bus`` for the ``socketcan`` interface. It is a
``can.BusABC``: ``send``, ``recv``, filters and ``shutdown`` are python-can's own, unchanged
(the bus monitor and python-can's tools use those). It adds what ``bus.transport.Port`` uses
when a bus offers it (``FrameBus``):

* ``send_frames``: several classic frames in one ``sendmmsg(2)`` (the receiver wakes once for
  the whole set; THR_CMD is 5 frames, GYRO 2), one ``send(2)`` each otherwise;
* ``drain_frames``: one ``select(2)`` (none when the timeout is 0), then non-blocking
  ``recvmsg(2)`` until the queue is empty; frames keep the kernel's receive time stamp
  (CLOCK_REALTIME, ``SO_TIMESTAMPNS`` as python-can sets it).

python-can's own ``send`` adds a ``select`` and two clock reads per frame and ``recv`` a
``select`` and a clock read per frame; under user-mode Linux every system call costs tens of
microseconds: sending THR_CMD went from 1.2 ms to 0.27 ms there (``bench/bench_transport.py``).

What this relies on inside python-can's ``can.interfaces.socketcan.socketcan`` module (pinned
by ``tests/bus/test_socketcan_internals.py``, so a python-can upgrade that changes them fails
there first): ``SocketcanBus.socket`` (the bound raw CAN socket), ``CAN_FRAME_HEADER_STRUCT``,
``RECEIVED_TIMESTAMP_STRUCT``, ``RECEIVED_ANCILLARY_BUFFER_SIZE``, ``build_can_frame``,
``dissect_can_frame`` and the ``constants`` flags and MTU.
"""

from __future__ import annotations

import select
import socket

import can
from can.interfaces.socketcan import constants
from can.interfaces.socketcan import socketcan as _sc

from bus.codec import Frame
from bus.transport import to_can_message

INTERFACE_NAME = "hil_socketcan"

_EFF, _RTR, _ERR = constants.CAN_EFF_FLAG, constants.CAN_RTR_FLAG, constants.CAN_ERR_FLAG
# SO_RXQ_OVFL (linux/socket.h): each received frame carries the socket's count of frames the
# kernel dropped because the receive queue was full (uint32, cumulative).
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
_ANC_SIZE = _sc.RECEIVED_ANCILLARY_BUFFER_SIZE + socket.CMSG_SPACE(4)


class FastSocketcanBus(_sc.SocketcanBus):
    """``SocketcanBus`` plus batch frame I/O (module doc). Same constructor arguments."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._mm: _Sendmmsg | None | bool = False  # made on first use (buffers of this bus)
        # Frames the kernel dropped for this socket (receive queue full): None where the
        # kernel does not report it.
        self.kernel_drops: int | None = None
        try:
            self.socket.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
            self.kernel_drops = 0
        except OSError:
            pass

    def send_frame(self, fr: Frame) -> bool:
        """One non-blocking ``send(2)``; False when the queue is full or the interface down
        (as python-can's ``send`` without a timeout, without raising)."""
        data = _wire(fr)
        try:
            return self.socket.send(data, socket.MSG_DONTWAIT) == len(data)
        except OSError:  # ENOBUFS / EAGAIN (queue full), ENETDOWN (interface down)
            return False

    def send_frames(self, frames: list[Frame]) -> int:
        """All frames in one ``sendmmsg(2)``; the number sent (frames the kernel did not take
        are not retried: the caller counts them). One ``send`` per frame where ``sendmmsg`` is
        not available, or for CAN FD frames."""
        if self._mm is False:
            self._mm = _Sendmmsg.create()
        mm = self._mm
        if mm is None or len(frames) > mm.slots or any(f.is_fd or len(f.data) > 8
                                                       for f in frames):
            n = 0
            for fr in frames:
                if not self.send_frame(fr):
                    break
                n += 1
            return n
        return mm.send(self.socket.fileno(), [_wire(fr) for fr in frames])

    def drain_frames(self, timeout_s: float, got: list[tuple[Frame, can.Message | None]],
                     with_messages: bool = False, limit: int | None = None) -> None:
        """Append the queued frames to ``got`` (with its python-can message for a logger), at
        most ``limit`` of them (None: every one)."""
        sock = self.socket
        if timeout_s > 0 and not select.select([sock], [], [], timeout_s)[0]:
            return
        mtu, anc_size = constants.CANFD_MTU, _ANC_SIZE
        ts_struct = _sc.RECEIVED_TIMESTAMP_STRUCT
        while limit is None or len(got) < limit:
            try:
                cf, anc, _flags, _addr = sock.recvmsg(mtu, anc_size, socket.MSG_DONTWAIT)
            except BlockingIOError:
                return
            can_id, dlc, _fl, data = _sc.dissect_can_frame(cf)
            ts = 0.0
            for level, kind, payload in anc:
                if level != socket.SOL_SOCKET:
                    continue
                if kind == SO_RXQ_OVFL and len(payload) >= 4:
                    self.kernel_drops = int.from_bytes(payload[:4], "little")
                elif kind == constants.SO_TIMESTAMPNS and len(payload) >= ts_struct.size:
                    sec, ns = ts_struct.unpack_from(payload)
                    ts = sec + ns * 1e-9
            ext = bool(can_id & _EFF)
            rtr, err = bool(can_id & _RTR), bool(can_id & _ERR)
            arb = can_id & (0x1FFFFFFF if ext else 0x7FF)
            is_fd = len(cf) == mtu
            fr = Frame(-1 if rtr or err else arb, bytes(data), is_fd, ext, ts)
            m = None
            if with_messages:
                m = can.Message(timestamp=ts, arbitration_id=arb, is_extended_id=ext,
                                is_remote_frame=rtr, is_error_frame=err, is_fd=is_fd,
                                dlc=dlc, data=data)
            got.append((fr, m))


def _wire(fr: Frame) -> bytes:
    """The kernel's ``struct can_frame`` of a frame (``canfd_frame`` for CAN FD)."""
    if fr.is_fd or len(fr.data) > 8:
        return _sc.build_can_frame(to_can_message(fr))
    can_id = fr.arbitration_id | (_EFF if fr.is_extended_id else 0)
    return _sc.CAN_FRAME_HEADER_STRUCT.pack(can_id, len(fr.data), 0, len(fr.data)) + \
        bytes(fr.data).ljust(8, b"\x00")


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
