"""Typed bus messages and their pure encode/decode to CAN frames (docs/design.md section 4).

One frozen dataclass per logical message (``Sync``, ``Gyro``, ``ThrCmd``, ``FdirStatus``,
``FaultCmd``, ``FaultAck``, ``FlightTiming``, ``Heartbeat``). ``encode(msg)`` returns the
frames of the message, in set order, with the E2E header (byte 0, low nibble of byte 1) zero;
``bus.e2e.Protector`` fills it in. Decoding is split in steps so that the receiver can
classify what is wrong: ``unpack`` (bits to raw integers), ``range_problem`` (catalog limits),
``to_physical``, then ``from_signals`` of the message class once a set is complete.

Bit packing is done here from the catalog (little endian, start bit = LSB position, as in
DBC ``@1``); cantools, loading ``bus/hil.dbc`` alone, is the independent oracle in the tests.
Values are quantised by ``round((value - offset) / scale)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from bus.catalog import (
    CATALOG,
    FRAME_BYTES,
    N_THRUSTERS_MAX,
    NO_THRUSTER,
    AckReason,
    AckStatus,
    DetectedFault,
    FaultAction,
    FaultKind,
    FrameDef,
    Node,
    NodeState,
    SignalDef,
)
from bus.errors import EncodeError


@dataclass(frozen=True)
class Frame:
    """A classic CAN frame as the sans-IO core sees it.

    ``timestamp_s`` is the receive time given by the transport, in the clock the transport
    names (``bus.transport.Port.clock``); None for frames we build.
    """

    arbitration_id: int
    data: bytes
    is_fd: bool = False
    is_extended_id: bool = False
    timestamp_s: float | None = None


# --- limits and bit packing -------------------------------------------------------------


def raw_limits(s: SignalDef) -> tuple[int, int]:
    lo = max(s.raw_min, math.ceil((s.minimum - s.offset) / s.scale - 1e-9))
    hi = min(s.raw_max, math.floor((s.phys_max - s.offset) / s.scale + 1e-9))
    return lo, hi


def _fmt(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(float(x))


def _allowed_text(values: tuple[int, ...]) -> str:
    parts, i = [], 0
    while i < len(values):
        j = i
        while j + 1 < len(values) and values[j + 1] == values[j] + 1:
            j += 1
        parts.append(str(values[i]) if j == i else f"{values[i]}..{values[j]}")
        i = j + 1
    return ", ".join(parts)


def _limit_text(s: SignalDef) -> str:
    if s.allowed is not None:
        return f"one of {_allowed_text(s.allowed)}"
    if s.choices is not None:
        lo, hi = raw_limits(s)
        return "one of " + ", ".join(
            f"{k} ({v})" for k, v in sorted(s.choices.items()) if lo <= k <= hi
        )
    unit = f" {s.unit}" if s.unit else ""
    return f"{_fmt(s.minimum)} <= value <= {_fmt(s.phys_max)}{unit}"


def raw_ok(s: SignalDef, raw: int) -> bool:
    lo, hi = raw_limits(s)
    if not lo <= raw <= hi:
        return False
    if s.allowed is not None and raw not in s.allowed:
        return False
    return s.choices is None or raw in s.choices


def to_raw(f: FrameDef, s: SignalDef, value: float) -> int:
    """Physical value to raw integer; EncodeError if the catalog does not allow it."""
    where = f"{f.set_name or f.name}.{s.name}"
    if isinstance(value, bool):
        value = int(value)
    if not isinstance(value, int | float) or (
        isinstance(value, float) and not math.isfinite(value)
    ):
        raise EncodeError(f"{where}: expected {_limit_text(s)}, got {value!r}")
    if s.scale == 1 and s.offset == 0 and not float(value).is_integer():
        raise EncodeError(f"{where}: expected an integer, got {value!r}")
    raw = round((value - s.offset) / s.scale)
    if not raw_ok(s, raw):
        raise EncodeError(f"{where}: expected {_limit_text(s)}, got {value!r}")
    return int(raw)


def pack(f: FrameDef, raws: dict[str, int]) -> bytes:
    """Raw signal values to 8 bytes; E2E header bits zero. Missing signals are 0."""
    word = 0
    for s in f.signals:
        raw = raws.get(s.name, 0)
        word |= (raw & ((1 << s.length) - 1)) << s.start_bit
    return word.to_bytes(FRAME_BYTES, "little")


def unpack(f: FrameDef, data: bytes) -> dict[str, int]:
    """8 bytes to raw signal values (sign-extended where the signal is signed)."""
    word = int.from_bytes(data, "little")
    out = {}
    for s in f.signals:
        raw = (word >> s.start_bit) & ((1 << s.length) - 1)
        if s.signed and raw >> (s.length - 1):
            raw -= 1 << s.length
        out[s.name] = raw
    return out


def range_problem(f: FrameDef, raws: dict[str, int]) -> str | None:
    """First signal whose raw value the catalog forbids: 'FRAME.signal: expected ..., got ...'."""
    for s in f.signals:
        raw = raws[s.name]
        if not raw_ok(s, raw):
            found = _fmt(raw * s.scale + s.offset)
            return f"{f.name}.{s.name}: expected {_limit_text(s)}, got {found}"
    return None


def to_physical(f: FrameDef, raws: dict[str, int]) -> dict[str, float]:
    out: dict[str, float] = {}
    for s in f.signals:
        raw = raws[s.name]
        out[s.name] = raw if (s.scale == 1 and s.offset == 0) else raw * s.scale + s.offset
    return out


# --- typed messages ---------------------------------------------------------------------

Signals = dict[str, dict[str, float]]  # frame name -> signal name -> physical value


def _thr(i: int | None) -> int:
    return NO_THRUSTER if i is None else i


def _thr_back(v: int) -> int | None:
    return None if v == NO_THRUSTER else int(v)


@dataclass(frozen=True)
class Sync:
    """SYNC: the plant starts lockstep tick ``tick`` at plant sim time ``sim_time_ms``."""

    SET: ClassVar[str] = "SYNC"
    tick: int
    sim_time_ms: int

    @property
    def sim_time_s(self) -> float:
        return self.sim_time_ms / 1000.0

    def to_signals(self) -> Signals:
        return {"SYNC": {"tick": self.tick, "sim_time_ms": self.sim_time_ms}}

    @classmethod
    def from_signals(cls, sig: Signals) -> Sync:
        s = sig["SYNC"]
        return cls(int(s["tick"]), int(s["sim_time_ms"]))


@dataclass(frozen=True)
class Gyro:
    """GYRO: measured body rate [rad/s] about x, y, z (body frame B), 1e-7 rad/s quantum.

    ``sample_seq`` counts the plant's gyro samples modulo 65536; the plant keeps the sample
    time of each sequence number (sensor-to-actuator latency via ``ThrCmd.gyro_seq``).
    ``status``: bit flags of ``bus.catalog.GyroStatus``.
    """

    SET: ClassVar[str] = "GYRO"
    sample_seq: int
    omega_B_rad_s: tuple[float, float, float]
    status: int = 1

    def to_signals(self) -> Signals:
        wx, wy, wz = self.omega_B_rad_s
        return {
            "GYRO_1": {"rate_x": wx, "rate_y": wy, "seq_lo": self.sample_seq & 0xFF},
            "GYRO_2": {"rate_z": wz, "sample_seq": self.sample_seq, "status": self.status},
        }

    @classmethod
    def from_signals(cls, sig: Signals) -> Gyro:
        a, b = sig["GYRO_1"], sig["GYRO_2"]
        return cls(int(b["sample_seq"]), (a["rate_x"], a["rate_y"], b["rate_z"]), int(b["status"]))


@dataclass(frozen=True)
class ThrCmd:
    """THR_CMD: the thruster command of tick ``tick``, applied atomically.

    ``on_quanta[i]``: on-duration of thruster i (0-based) in 10 ms quanta, one of
    ``bus.catalog.ALLOWED_ON_QUANTA``; its length is the vehicle's thruster count (1..32).
    ``manifold_enable``: bit m set = manifold m open. ``gyro_seq``: GYRO sample it was
    computed from.
    """

    SET: ClassVar[str] = "THR_CMD"
    tick: int
    on_quanta: tuple[int, ...]
    manifold_enable: int
    gyro_seq: int

    def to_signals(self) -> Signals:
        n = len(self.on_quanta)
        if not 1 <= n <= N_THRUSTERS_MAX:
            raise EncodeError(
                f"THR_CMD.on_quanta: expected 1..{N_THRUSTERS_MAX} thrusters, got {n}"
            )
        out: Signals = {
            "THR_CMD_0": {
                "tick": self.tick,
                "manifold_enable": self.manifold_enable,
                "gyro_seq": self.gyro_seq,
                "n_thrusters": n,
            }
        }
        q = list(self.on_quanta) + [0] * (N_THRUSTERS_MAX - n)
        for k in range(N_THRUSTERS_MAX // 8):
            fs: dict[str, float] = {"tick_lo": self.tick & 0xFF}
            for j in range(8):
                fs[f"on_q_{8 * k + j:02d}"] = q[8 * k + j]
            out[f"THR_CMD_{k + 1}"] = fs
        return out

    @classmethod
    def from_signals(cls, sig: Signals) -> ThrCmd:
        h = sig["THR_CMD_0"]
        n = int(h["n_thrusters"])
        q = []
        for k in range(N_THRUSTERS_MAX // 8):
            fs = sig[f"THR_CMD_{k + 1}"]
            q.extend(int(fs[f"on_q_{8 * k + j:02d}"]) for j in range(8))
        return cls(int(h["tick"]), tuple(q[:n]), int(h["manifold_enable"]), int(h["gyro_seq"]))

    @staticmethod
    def set_problem(sig: Signals) -> str | None:
        """Consistency the single frames cannot check (used by the assembler)."""
        n = int(sig["THR_CMD_0"]["n_thrusters"])
        if n < 1:
            return f"THR_CMD.n_thrusters: expected 1..{N_THRUSTERS_MAX}, got {n}"
        for k in range(N_THRUSTERS_MAX // 8):
            fs = sig[f"THR_CMD_{k + 1}"]
            for j in range(8):
                i = 8 * k + j
                if i >= n and fs[f"on_q_{i:02d}"] != 0:
                    return (
                        f"THR_CMD.on_q_{i:02d}: expected 0 (n_thrusters {n}), "
                        f"got {int(fs[f'on_q_{i:02d}'])}"
                    )
        return None


@dataclass(frozen=True)
class FdirStatus:
    """FDIR_STATUS: detection (tick, type, thruster or 'one of {a, b}'), recovery state."""

    SET: ClassVar[str] = "FDIR_STATUS"
    detect_tick: int
    fault_type: DetectedFault
    thruster_a: int | None
    thruster_b: int | None
    closed_manifolds: int
    safe_mode: bool
    config_id: int

    def to_signals(self) -> Signals:
        return {
            "FDIR_STATUS": {
                "detect_tick": self.detect_tick,
                "fault_type": int(self.fault_type),
                "thruster_a": _thr(self.thruster_a),
                "thruster_b": _thr(self.thruster_b),
                "closed_manifolds": self.closed_manifolds,
                "safe_mode": int(self.safe_mode),
                "config_id": self.config_id,
            }
        }

    @classmethod
    def from_signals(cls, sig: Signals) -> FdirStatus:
        s = sig["FDIR_STATUS"]
        return cls(
            int(s["detect_tick"]),
            DetectedFault(int(s["fault_type"])),
            _thr_back(s["thruster_a"]),
            _thr_back(s["thruster_b"]),
            int(s["closed_manifolds"]),
            bool(s["safe_mode"]),
            int(s["config_id"]),
        )


@dataclass(frozen=True)
class FaultCmd:
    """FAULT_CMD: inject or clear a fault. Times are plant sim time, 10 ms quantum.

    ``thruster``: thruster index (node id for node_silent), None if not applicable.
    ``clear_time_s`` None: never cleared by time.
    """

    SET: ClassVar[str] = "FAULT_CMD"
    request_id: int
    action: FaultAction
    kind: FaultKind
    thruster: int | None = None
    fraction: float = 1.0
    start_time_s: float = 0.0
    clear_time_s: float | None = None
    message: int = 0  # bus faults: 0 every frame, k the k-th of bus.faults.MESSAGE_NAMES

    def to_signals(self) -> Signals:
        return {
            "FAULT_CMD_0": {
                "request_id": self.request_id,
                "action": int(self.action),
                "kind": int(self.kind),
                "thruster": _thr(self.thruster),
                "fraction": self.fraction,
                "message": self.message,
            },
            "FAULT_CMD_1": {
                "request_id": self.request_id,
                "start_time": self.start_time_s,
                "clear_time": 0.0 if self.clear_time_s is None else self.clear_time_s,
            },
        }

    @classmethod
    def from_signals(cls, sig: Signals) -> FaultCmd:
        a, b = sig["FAULT_CMD_0"], sig["FAULT_CMD_1"]
        return cls(
            int(a["request_id"]),
            FaultAction(int(a["action"])),
            FaultKind(int(a["kind"])),
            _thr_back(a["thruster"]),
            a["fraction"],
            b["start_time"],
            None if b["clear_time"] == 0 else b["clear_time"],
            int(a["message"]),
        )


@dataclass(frozen=True)
class FaultAck:
    SET: ClassVar[str] = "FAULT_ACK"
    request_id: int
    status: AckStatus
    reason: AckReason = AckReason.NONE
    kind: FaultKind = FaultKind.NONE

    def to_signals(self) -> Signals:
        return {
            "FAULT_ACK": {
                "request_id": self.request_id,
                "status": int(self.status),
                "reason": int(self.reason),
                "kind": int(self.kind),
            }
        }

    @classmethod
    def from_signals(cls, sig: Signals) -> FaultAck:
        s = sig["FAULT_ACK"]
        return cls(
            int(s["request_id"]),
            AckStatus(int(s["status"])),
            AckReason(int(s["reason"])),
            FaultKind(int(s["kind"])),
        )


@dataclass(frozen=True)
class FlightTiming:
    """FLIGHT_TIMING: compute time of tick ``tick`` [s, 1 us quantum], overruns mod 256."""

    SET: ClassVar[str] = "FLIGHT_TIMING"
    tick: int
    compute_time_s: float
    overrun_count: int

    def to_signals(self) -> Signals:
        return {
            "FLIGHT_TIMING": {
                "tick": self.tick,
                "compute_time": self.compute_time_s,
                "overrun_count": self.overrun_count,
            }
        }

    @classmethod
    def from_signals(cls, sig: Signals) -> FlightTiming:
        s = sig["FLIGHT_TIMING"]
        return cls(int(s["tick"]), s["compute_time"], int(s["overrun_count"]))


@dataclass(frozen=True)
class Heartbeat:
    """HEARTBEAT of ``node``; counters are modulo the field size (16, 16, 12 bits)."""

    SET: ClassVar[str] = "HEARTBEAT"
    node: Node
    state: NodeState
    rx_ok: int = 0
    rx_bad: int = 0
    deadline_miss: int = 0

    def to_signals(self) -> Signals:
        return {
            f"HEARTBEAT_{Node(self.node).name}": {
                "state": int(self.state),
                "rx_ok": self.rx_ok,
                "rx_bad": self.rx_bad,
                "deadline_miss": self.deadline_miss,
            }
        }

    @classmethod
    def from_signals(cls, sig: Signals) -> Heartbeat:
        ((name, s),) = sig.items()
        return cls(
            Node[name.removeprefix("HEARTBEAT_")],
            NodeState(int(s["state"])),
            int(s["rx_ok"]),
            int(s["rx_bad"]),
            int(s["deadline_miss"]),
        )


@dataclass(frozen=True)
class ThrCmdMac:
    """THR_CMD_MAC: the authenticator of THR_CMD (``bus.secoc``): key low 8 bits, freshness
    low 16 bits, 24-bit truncated MAC."""

    SET: ClassVar[str] = "THR_CMD_MAC"
    key_lo: int
    fresh_lo: int
    mac: int

    def to_signals(self) -> Signals:
        return {self.SET: {"key_lo": self.key_lo, "fresh_lo": self.fresh_lo, "mac": self.mac}}

    @classmethod
    def from_signals(cls, sig: Signals):
        s = sig[cls.SET]
        return cls(int(s["key_lo"]), int(s["fresh_lo"]), int(s["mac"]))


@dataclass(frozen=True)
class FaultCmdMac(ThrCmdMac):
    """FAULT_CMD_MAC: the authenticator of FAULT_CMD (fields as ``ThrCmdMac``)."""

    SET: ClassVar[str] = "FAULT_CMD_MAC"


@dataclass(frozen=True)
class SyncMac(ThrCmdMac):
    """SYNC_MAC: the authenticator of SYNC (fields as ``ThrCmdMac``; key and freshness from
    the tick, as THR_CMD)."""

    SET: ClassVar[str] = "SYNC_MAC"


@dataclass(frozen=True)
class HeartbeatMac(ThrCmdMac):
    """HEARTBEAT_<NODE>_MAC: the authenticator of a node's heartbeat (fields as ``ThrCmdMac``;
    the key is the node id, the freshness the sender's clock)."""

    SET: ClassVar[str] = "HEARTBEAT_MAC"

    def to_signals(self) -> Signals:
        return {f"HEARTBEAT_{Node(self.key_lo).name}_MAC": {
            "key_lo": self.key_lo, "fresh_lo": self.fresh_lo, "mac": self.mac}}

    @classmethod
    def from_signals(cls, sig: Signals) -> HeartbeatMac:
        ((_, s),) = sig.items()
        return cls(int(s["key_lo"]), int(s["fresh_lo"]), int(s["mac"]))


@dataclass(frozen=True)
class GyroMac(ThrCmdMac):
    """GYRO_MAC: the authenticator of GYRO (fields as ``ThrCmdMac``; the key is the sample
    sequence's low 8 bits, the freshness the sender's clock)."""

    SET: ClassVar[str] = "GYRO_MAC"


Message = (Sync | Gyro | ThrCmd | FdirStatus | FaultCmd | FaultAck | FlightTiming | Heartbeat
           | ThrCmdMac | FaultCmdMac | GyroMac | HeartbeatMac | SyncMac)
MESSAGE_TYPES: dict[str, type] = {
    c.SET: c for c in (Sync, Gyro, ThrCmd, FdirStatus, FaultCmd, FaultAck, FlightTiming, Heartbeat,
                       ThrCmdMac, FaultCmdMac, GyroMac, HeartbeatMac, SyncMac)
}


def set_name_of(f: FrameDef) -> str:
    """Logical message of a frame (the HEARTBEAT_<NODE> frames all map to HEARTBEAT, their
    authenticators HEARTBEAT_<NODE>_MAC to HEARTBEAT_MAC)."""
    if f.name.startswith("HEARTBEAT_"):
        return "HEARTBEAT_MAC" if f.name.endswith("_MAC") else "HEARTBEAT"
    return f.set_name or f.name


def encode(msg: Message) -> list[Frame]:
    """Frames of ``msg`` in set order, E2E header zero. EncodeError on an illegal value."""
    out = []
    for name, values in msg.to_signals().items():
        f = CATALOG.frame(name)
        raws = {s.name: to_raw(f, s, values[s.name]) for s in f.signals}
        out.append(Frame(f.frame_id, pack(f, raws)))
    return out


def decode(frames: list[Frame]) -> Message:
    """Inverse of ``encode`` for trusted input (tests, tools); the receiver checks first."""
    sig: Signals = {}
    for fr in frames:
        f = CATALOG.by_id[fr.arbitration_id]
        sig[f.name] = to_physical(f, unpack(f, fr.data))
    first = CATALOG.by_id[frames[0].arbitration_id]
    return MESSAGE_TYPES[set_name_of(first)].from_signals(sig)
