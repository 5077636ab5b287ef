"""The CAN message catalog: the single source of truth for the bus (docs/design.md section 4).

Everything else is generated from the tables below: the DBC file (``bus/dbc.py``), the codecs
(``bus/codec.py``), the receiver's checks (``bus/receiver.py``) and the bus-load figures.

Choice of frame format: classic CAN, 8-byte data frames, 11-bit identifiers, 1 Mbit/s.

* Every python-can interface carries classic frames (vcan, udp_multicast, PCAN, Kvaser, ...);
  CAN FD needs FD adapters, ``mtu 72`` on vcan and FD-aware tools along the whole chain.
* The load is small anyway (about 2 % of 1 Mbit/s at the nominal cycle times, ``hil dbc
  --load``), so the larger FD payload buys nothing but coupling.
* The price is that three logical messages do not fit one frame. They are sent as *frame sets*
  (THR_CMD: 5 frames, GYRO: 2, FAULT_CMD: 2). Every frame of a set carries the set's key (the
  tick for THR_CMD, the sample sequence for GYRO, the request id for FAULT_CMD; the first
  frame the full key, the others its low 8 bits) and its own E2E header. The receiver
  assembles a set and hands it over only when every frame of one key is present and valid; a
  set that is superseded or times out is dropped and counted as ``incomplete_set``
  (``bus/receiver.py``). The frame index of a set is its identifier (consecutive IDs), so
  cantools and SavvyCAN decode each frame from the DBC alone.

E2E header (every frame, ``bus/e2e.py``): byte 0 is CRC-8/SAE-J1850 over the 16-bit data ID
and bytes 1..7; bits 8..11 (low nibble of byte 1) are a 4-bit alive counter. Signals start at
bit 12. Byte order is little endian (Intel) for all signals.

Rates: 1e-7 rad/s per LSB in a 22-bit signed field, range +-0.2 rad/s (11.5 deg/s): 3.5 deg/s
(0.061 rad/s) fits with margin, and the quantum is 100 times below the ~1e-5 rad/s rate
residuals the detector works with (seeds 000, 003).

Identifiers are ordered by urgency: SYNC and THR_CMD first (the lockstep loop), then GYRO,
FDIR, faults, telemetry, heartbeats (0x700 + node id, as in CANopen).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

from bus.errors import CatalogError

BITRATE_BPS = 1_000_000
FRAME_BYTES = 8
TICK_S = 0.2  # flight tick (major frame), docs/design.md section 3
GYRO_PERIOD_S = 0.02  # GYRO output period in real-time mode (50 Hz)
HEARTBEAT_PERIOD_S = 0.5
N_THRUSTERS_MAX = 32
N_MANIFOLDS_MAX = 4
THRUSTERS_PER_FRAME = 8
# Allowed on-durations per tick in 10 ms quanta: {0, 30..170, 200} ms (docs/design.md section 3):
# 180 and 190 ms would leave less than the 30 ms minimum pause, 10 and 20 ms are below the
# 30 ms minimum on-time.
ALLOWED_ON_QUANTA = (0, *range(3, 18), 20)
ON_QUANTUM_MS = 10  # THR_CMD on-durations are counted in these
GYRO_RATE_LSB_RAD_S = 1e-7
GYRO_RATE_LIMIT_RAD_S = 0.2
NO_THRUSTER = 63  # "no thruster" in 6-bit thruster index fields
E2E_HEADER_BITS = 12


class Node(IntEnum):
    """Bus nodes; the value is the node id carried in heartbeats (HEARTBEAT id = 0x700 + id)."""

    PLANT = 1
    FLIGHT = 2
    PANEL = 3


class FaultKind(IntEnum):
    """Fault kinds a FAULT_CMD can inject (docs/design.md section 5.6). 0 is reserved for 'none'."""

    NONE = 0
    STUCK_ON = 1
    FAIL_TO_FIRE = 2
    DEGRADED = 3
    GYRO_SPIKE = 4
    GYRO_BIAS_STEP = 5
    GYRO_FROZEN = 6
    GYRO_NOISE = 7
    BUS_DROP = 8
    BUS_DELAY = 9
    BUS_CORRUPT = 10
    NODE_SILENT = 11
    BUS_BABBLE = 12


class FaultAction(IntEnum):
    INJECT = 1
    CLEAR = 2


class AckStatus(IntEnum):
    ACCEPTED = 1
    REJECTED = 2


class AckReason(IntEnum):
    """Why a FAULT_CMD was rejected (0 when accepted)."""

    NONE = 0
    UNKNOWN_KIND = 1
    BAD_THRUSTER = 2
    BAD_FRACTION = 3
    BAD_TIME = 4
    NOT_ACTIVE = 5  # clear of a fault that is not active
    BUSY = 6


class DetectedFault(IntEnum):
    """Fault type in FDIR_STATUS (docs/design.md section 6.4)."""

    NONE = 0
    STUCK_ON = 1
    FAIL_TO_FIRE = 2
    DEGRADED = 3
    GYRO_FAULT = 4  # a sensor fault: thruster_a / thruster_b are 63 (none)


class NodeState(IntEnum):
    INIT = 0
    RUN = 1
    SAFE = 2
    STOPPING = 3


class GyroStatus(IntEnum):
    """Bit flags of GYRO status."""

    VALID = 0x01
    SATURATED = 0x02
    FROZEN = 0x04  # plant-side test flag; the flight must not rely on it
    # The plant did not apply the flight's last command (missing, late, refused, or the plant
    # is safe): the rate change up to this sample is no evidence about the thrusters.
    CMD_NOT_APPLIED = 0x08


def _enum_choices(enum: type[IntEnum]) -> dict[int, str]:
    return {int(m): m.name.lower() for m in enum}


@dataclass(frozen=True)
class SignalDef:
    """One signal of one frame. ``start_bit``/``length`` in bits, little endian.

    Physical value = raw * scale + offset; ``minimum``/``maximum`` are physical limits that
    both the encoder and the receiver enforce; ``allowed`` (raw values) narrows them further.
    """

    name: str
    start_bit: int
    length: int
    scale: float = 1.0
    offset: float = 0.0
    minimum: float = 0.0
    maximum: float | None = None  # None: the largest value the field holds
    signed: bool = False
    unit: str = ""
    comment: str = ""
    choices: dict[int, str] | None = None
    allowed: tuple[int, ...] | None = None

    @property
    def raw_min(self) -> int:
        return -(1 << (self.length - 1)) if self.signed else 0

    @property
    def raw_max(self) -> int:
        return (1 << (self.length - 1)) - 1 if self.signed else (1 << self.length) - 1

    @property
    def phys_max(self) -> float:
        if self.maximum is not None:
            return self.maximum
        return self.raw_max * self.scale + self.offset


@dataclass(frozen=True)
class FrameDef:
    """One CAN frame (one DBC message). ``cycle_s`` None means 'on demand'."""

    name: str
    frame_id: int
    data_id: int  # 16-bit E2E data ID
    sender: Node
    receivers: tuple[Node, ...]
    signals: tuple[SignalDef, ...]
    cycle_s: float | None
    deadline_s: float  # a frame older than this on arrival at the application is stale
    comment: str = ""
    set_name: str | None = None  # logical message this frame belongs to
    set_index: int = 0
    key_signal: str | None = None  # signal carrying the set key (full or low 8 bits)

    def signal(self, name: str) -> SignalDef:
        for s in self.signals:
            if s.name == name:
                return s
        raise KeyError(name)


@dataclass(frozen=True)
class Catalog:
    frames: tuple[FrameDef, ...]
    by_id: dict[int, FrameDef] = field(init=False, repr=False, compare=False)
    by_name: dict[str, FrameDef] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        by_id: dict[int, FrameDef] = {}
        by_name: dict[str, FrameDef] = {}
        data_ids: set[int] = set()
        for f in self.frames:
            if f.frame_id in by_id:
                raise CatalogError(
                    f"catalog: {f.name}: expected a unique frame id, got "
                    f"0x{f.frame_id:03X} (also {by_id[f.frame_id].name})"
                )
            if f.name in by_name:
                raise CatalogError(f"catalog: expected unique frame names, got {f.name} twice")
            if f.data_id in data_ids:
                raise CatalogError(
                    f"catalog: {f.name}: expected a unique data id, got 0x{f.data_id:04X}"
                )
            if not 0 <= f.frame_id <= 0x7FF:
                raise CatalogError(f"catalog: {f.name}: expected an 11-bit id, got {f.frame_id}")
            used = (1 << E2E_HEADER_BITS) - 1
            for s in f.signals:
                mask = ((1 << s.length) - 1) << s.start_bit
                if s.start_bit < E2E_HEADER_BITS or s.start_bit + s.length > 8 * FRAME_BYTES:
                    raise CatalogError(
                        f"catalog: {f.name}.{s.name}: expected bits 12..63, got "
                        f"{s.start_bit}..{s.start_bit + s.length - 1}"
                    )
                if used & mask:
                    raise CatalogError(
                        f"catalog: {f.name}.{s.name}: expected no overlap, got "
                        f"bits {s.start_bit}..{s.start_bit + s.length - 1}"
                    )
                used |= mask
            by_id[f.frame_id] = f
            by_name[f.name] = f
            data_ids.add(f.data_id)
        object.__setattr__(self, "by_id", by_id)
        object.__setattr__(self, "by_name", by_name)

    def frame(self, name: str) -> FrameDef:
        return self.by_name[name]

    def set_frames(self, set_name: str) -> tuple[FrameDef, ...]:
        """Frames of a logical message, in set order."""
        fs = [f for f in self.frames if (f.set_name or f.name) == set_name]
        return tuple(sorted(fs, key=lambda f: f.set_index))


def _sig(name, start, length, **kw) -> SignalDef:
    return SignalDef(name, start, length, **kw)


_rate = dict(
    scale=GYRO_RATE_LSB_RAD_S,
    minimum=-GYRO_RATE_LIMIT_RAD_S,
    maximum=GYRO_RATE_LIMIT_RAD_S,
    signed=True,
    unit="rad/s",
)
_tick = dict(unit="tick", comment="flight tick number n (t_n = n * 0.2 s)")
_tick_lo = dict(unit="tick", comment="tick number modulo 256 (set key)")
_all = (Node.PLANT, Node.FLIGHT, Node.PANEL)


def _mac_frame(name: str, frame_id: int, sender: Node, receivers: tuple[Node, ...],
               cycle_s: float | None, deadline_s: float, of: str) -> FrameDef:
    """The authenticator of a secured message (``bus.secoc``, AUTOSAR SecOC's secured PDU
    trailer sent as a frame of its own): the message's key (low 8 bits), the freshness value
    (low 16 bits) and a 24-bit truncated HMAC-SHA256."""
    return FrameDef(
        name, frame_id, 0x1000 + frame_id, sender, receivers,
        (
            _sig("key_lo", 12, 8, comment=f"low 8 bits of the {of} set key"),
            _sig("fresh_lo", 20, 16, comment="freshness value, low 16 bits"),
            _sig("mac", 36, 24, comment="HMAC-SHA256 truncated to 24 bits"),
        ),
        cycle_s=cycle_s, deadline_s=deadline_s,
        comment=f"SecOC authenticator of {of} (bus.secoc)",
    )


def _thr_frame(k: int) -> FrameDef:
    sigs = [_sig("tick_lo", 12, 8, **_tick_lo)]
    for j in range(THRUSTERS_PER_FRAME):
        i = k * THRUSTERS_PER_FRAME + j
        sigs.append(
            _sig(
                f"on_q_{i:02d}",
                20 + 5 * j,
                5,
                maximum=20,
                unit="10ms",
                allowed=ALLOWED_ON_QUANTA,
                comment=f"on-duration of thruster index {i} (0-based) in 10 ms quanta",
            )
        )
    return FrameDef(
        f"THR_CMD_{k + 1}",
        0x0A1 + k,
        0x10A1 + k,
        Node.FLIGHT,
        (Node.PLANT,),
        tuple(sigs),
        cycle_s=TICK_S,
        deadline_s=0.1,
        set_name="THR_CMD",
        set_index=k + 1,
        key_signal="tick_lo",
        comment=f"thruster on-durations, thrusters {8 * k}..{8 * k + 7}; frame {k + 1} of the "
        "THR_CMD set",
    )


def _heartbeat(node: Node) -> FrameDef:
    return FrameDef(
        f"HEARTBEAT_{node.name}",
        0x700 + int(node),
        0x1700 + int(node),
        node,
        tuple(n for n in _all if n != node),
        (
            _sig("state", 12, 4, maximum=3, choices=_enum_choices(NodeState)),
            _sig("rx_ok", 16, 16, comment="frames received and accepted, modulo 65536"),
            _sig("rx_bad", 32, 16, comment="frames rejected, modulo 65536"),
            _sig("deadline_miss", 48, 12, comment="lockstep deadline misses, modulo 4096"),
        ),
        cycle_s=HEARTBEAT_PERIOD_S,
        deadline_s=HEARTBEAT_PERIOD_S,
        comment=f"heartbeat of node {node.name.lower()} (id {int(node)})",
    )


CATALOG = Catalog(
    (
        FrameDef(
            "SYNC",
            0x080,
            0x1080,
            Node.PLANT,
            (Node.FLIGHT, Node.PANEL),
            (
                _sig("tick", 12, 24, **_tick),
                _sig("sim_time_ms", 36, 28, unit="ms", comment="plant simulation time at t_n"),
            ),
            cycle_s=TICK_S,
            deadline_s=0.1,
            comment="lockstep: the plant (time master) starts tick n",
        ),
        _mac_frame("SYNC_MAC", 0x081, Node.PLANT, (Node.FLIGHT, Node.PANEL), TICK_S, 0.1, "SYNC"),
        FrameDef(
            "THR_CMD_0",
            0x0A0,
            0x10A0,
            Node.FLIGHT,
            (Node.PLANT,),
            (
                _sig("tick", 12, 24, **_tick),
                _sig(
                    "manifold_enable", 36, 4, comment="bit m set: manifold m isolation valve open"
                ),
                _sig("gyro_seq", 40, 16, comment="GYRO sample_seq the command was computed from"),
                _sig(
                    "n_thrusters",
                    56,
                    6,
                    maximum=N_THRUSTERS_MAX,
                    comment="thrusters the vehicle has (indices above are 0)",
                ),
            ),
            cycle_s=TICK_S,
            deadline_s=0.1,
            set_name="THR_CMD",
            set_index=0,
            key_signal="tick",
            comment="thruster command header; frame 0 of the THR_CMD set (applied atomically)",
        ),
        *(_thr_frame(k) for k in range(N_THRUSTERS_MAX // THRUSTERS_PER_FRAME)),
        _mac_frame("THR_CMD_MAC", 0x0A8, Node.FLIGHT, (Node.PLANT,), TICK_S, 0.1, "THR_CMD"),
        FrameDef(
            "GYRO_1",
            0x110,
            0x1110,
            Node.PLANT,
            (Node.FLIGHT,),
            (
                _sig("rate_x", 12, 22, comment="measured body rate about x", **_rate),
                _sig("rate_y", 34, 22, comment="measured body rate about y", **_rate),
                _sig("seq_lo", 56, 8, comment="sample_seq modulo 256 (set key)"),
            ),
            cycle_s=GYRO_PERIOD_S,
            deadline_s=0.05,
            set_name="GYRO",
            set_index=0,
            key_signal="seq_lo",
            comment="gyro sample, x and y; frame 0 of the GYRO set",
        ),
        FrameDef(
            "GYRO_2",
            0x111,
            0x1111,
            Node.PLANT,
            (Node.FLIGHT,),
            (
                _sig("rate_z", 12, 22, comment="measured body rate about z", **_rate),
                _sig("sample_seq", 34, 16, comment="gyro sample sequence, modulo 65536"),
                _sig(
                    "status",
                    50,
                    8,
                    maximum=15,
                    comment="bit 0 valid, bit 1 saturated, bit 2 frozen (test flag), "
                            "bit 3 last command not applied",
                ),
            ),
            cycle_s=GYRO_PERIOD_S,
            deadline_s=0.05,
            set_name="GYRO",
            set_index=1,
            key_signal="sample_seq",
            comment="gyro sample, z, sequence and status; frame 1 of the GYRO set",
        ),
        _mac_frame("GYRO_MAC", 0x112, Node.PLANT, (Node.FLIGHT,), GYRO_PERIOD_S, 0.05, "GYRO"),
        FrameDef(
            "FDIR_STATUS",
            0x140,
            0x1140,
            Node.FLIGHT,
            (Node.PLANT, Node.PANEL),
            (
                _sig("detect_tick", 12, 24, **{**_tick, "comment": "tick of the detection"}),
                _sig("fault_type", 36, 3, maximum=4, choices=_enum_choices(DetectedFault)),
                _sig("thruster_a", 39, 6, comment="detected thruster index, 63 = none"),
                _sig(
                    "thruster_b",
                    45,
                    6,
                    comment="second candidate (report 'one of {a, b}'), 63 = none",
                ),
                _sig("closed_manifolds", 51, 4, comment="bit m set: manifold m closed by FDIR"),
                _sig("safe_mode", 55, 1),
                _sig("config_id", 56, 8, comment="active thruster configuration id"),
            ),
            cycle_s=TICK_S,
            deadline_s=0.4,
            comment="fault detection, isolation and recovery status",
        ),
        FrameDef(
            "FAULT_CMD_0",
            0x180,
            0x1180,
            Node.PANEL,
            (Node.PLANT, Node.FLIGHT),
            (
                _sig("request_id", 12, 8),
                _sig("action", 20, 2, minimum=1, maximum=2, choices=_enum_choices(FaultAction)),
                _sig("kind", 22, 4, maximum=12, choices=_enum_choices(FaultKind),
                     comment="none (0) with a clear; the plant rejects an inject of none"),
                _sig(
                    "thruster",
                    26,
                    6,
                    comment="thruster index (or node id for node_silent), 63 = n/a",
                ),
                _sig(
                    "fraction",
                    32,
                    14,
                    scale=1e-4,
                    maximum=1.0,
                    comment="residual or degraded thrust fraction, or fault magnitude 0..1; "
                            "bus faults: probability (bus_delay: delay in s, bus_babble: "
                            "rate / 20000 Hz)",
                ),
                _sig("message", 46, 6, comment="bus faults: 0 every frame, k the k-th name "
                                               "of bus.faults.MESSAGE_NAMES"),
            ),
            cycle_s=None,
            deadline_s=1.0,
            set_name="FAULT_CMD",
            set_index=0,
            key_signal="request_id",
            comment="fault to inject or clear; frame 0 of the FAULT_CMD set",
        ),
        FrameDef(
            "FAULT_CMD_1",
            0x181,
            0x1181,
            Node.PANEL,
            (Node.PLANT, Node.FLIGHT),
            (
                _sig("request_id", 12, 8),
                _sig("start_time", 20, 22, scale=0.01, unit="s", comment="sim time to start"),
                _sig(
                    "clear_time",
                    42,
                    22,
                    scale=0.01,
                    unit="s",
                    comment="sim time to clear, 0 = never",
                ),
            ),
            cycle_s=None,
            deadline_s=1.0,
            set_name="FAULT_CMD",
            set_index=1,
            key_signal="request_id",
            comment="fault timing; frame 1 of the FAULT_CMD set",
        ),
        _mac_frame("FAULT_CMD_MAC", 0x182, Node.PANEL, (Node.PLANT, Node.FLIGHT), None, 1.0,
                   "FAULT_CMD"),
        FrameDef(
            "FAULT_ACK",
            0x1C0,
            0x11C0,
            Node.PLANT,
            (Node.PANEL,),
            (
                _sig("request_id", 12, 8),
                _sig("status", 20, 2, minimum=1, maximum=2, choices=_enum_choices(AckStatus)),
                _sig("reason", 22, 8, maximum=6, choices=_enum_choices(AckReason)),
                _sig("kind", 30, 4, maximum=12, choices=_enum_choices(FaultKind)),
            ),
            cycle_s=None,
            deadline_s=1.0,
            comment="plant's answer to a FAULT_CMD",
        ),
        FrameDef(
            "FLIGHT_TIMING",
            0x300,
            0x1300,
            Node.FLIGHT,
            (Node.PANEL,),
            (
                _sig("tick", 12, 24, **_tick),
                _sig(
                    "compute_time",
                    36,
                    20,
                    scale=1e-6,
                    unit="s",
                    comment="flight compute time of the tick, all stages",
                ),
                _sig("overrun_count", 56, 8, comment="scheduler overruns, modulo 256"),
            ),
            cycle_s=TICK_S,
            deadline_s=0.4,
            comment="flight tick timing telemetry",
        ),
        *(_heartbeat(n) for n in Node),
        *(_mac_frame(f"HEARTBEAT_{n.name}_MAC", 0x708 + int(n), n,
                     tuple(m for m in _all if m != n), HEARTBEAT_PERIOD_S, HEARTBEAT_PERIOD_S,
                     f"HEARTBEAT_{n.name}") for n in Node),
    )
)

# Identifiers, for code that needs them (one place: the table above).
SYNC_ID = CATALOG.frame("SYNC").frame_id
THR_CMD_IDS = tuple(f.frame_id for f in CATALOG.set_frames("THR_CMD"))
GYRO_IDS = tuple(f.frame_id for f in CATALOG.set_frames("GYRO"))
FDIR_STATUS_ID = CATALOG.frame("FDIR_STATUS").frame_id
def consumed_ids(node: Node, catalog: Catalog | None = None) -> tuple[int, ...]:
    """Identifiers of the frames ``node`` receives (the catalog's ``receivers``), sorted: what
    its kernel-side receive filter lets through (``bus.transport.node_filters``)."""
    cat = catalog or CATALOG
    return tuple(sorted(f.frame_id for f in cat.frames if node in f.receivers))


FAULT_CMD_IDS = tuple(f.frame_id for f in CATALOG.set_frames("FAULT_CMD"))
FAULT_ACK_ID = CATALOG.frame("FAULT_ACK").frame_id
FLIGHT_TIMING_ID = CATALOG.frame("FLIGHT_TIMING").frame_id
HEARTBEAT_IDS = {n: CATALOG.frame(f"HEARTBEAT_{n.name}").frame_id for n in Node}


def classic_frame_bits(n_bytes: int) -> int:
    """Bits on the wire of a classic standard-ID data frame with worst-case stuffing.

    47 fixed bits + 8n data bits; of the 34 + 8n bits subject to stuffing at most
    floor((34 + 8n - 1) / 4) stuff bits (one after every 4 equal bits but the first 5).
    """
    return 47 + 8 * n_bytes + (34 + 8 * n_bytes - 1) // 4


def bus_load(bitrate_bps: int = BITRATE_BPS) -> list[tuple[str, float, float]]:
    """Load per cyclic frame at the nominal cycle times: (name, bits/s, fraction of bitrate).

    On-demand frames (cycle None) are left out; they are rare and short.
    """
    rows = []
    for f in CATALOG.frames:
        if f.cycle_s is None:
            continue
        bps = classic_frame_bits(FRAME_BYTES) / f.cycle_s
        rows.append((f.name, bps, bps / bitrate_bps))
    return rows
