"""The one binding between the cores' types and the bus messages (house style, habit 14).

Every path that connects the flight and the plant uses these functions: the process shells
(``hil.plant_shell``, ``hil.flight_shell``), the fault panel (``hil.panel``) and the in-process
lockstep (``hil.sim``, which also passes each message through ``over_the_wire``), so the
in-process run equals the lockstep run over the bus by construction, and a second bus (LCM) can
reuse them.

* gyro sample (``plant.gyro.GyroSample``) -> GYRO: sequence modulo 65536, the rate clipped to
  the GYRO signal's range (``bus.catalog.GYRO_RATE_LIMIT_RAD_S``) with the ``SATURATED`` status
  bit set when it was, status (0 read as 1, valid); ``saturated`` reads that bit;
* flight output (``flight.software.TickOutput``) -> THR_CMD (on-times in
  ``bus.catalog.ON_QUANTUM_MS`` quanta, manifold bit mask, the gyro sample it came from) and
  FDIR_STATUS (the newest detection, the closed manifolds, the safe flag);
* THR_CMD -> the plant's command (on-times in ms, manifold open flags);
* fault specs (``common.scenario.FaultSpec``) <-> FAULT_CMD kinds.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from bus.catalog import (
    GYRO_RATE_LIMIT_RAD_S,
    ON_QUANTUM_MS,
    DetectedFault,
    FaultAction,
    FaultKind,
    GyroStatus,
)
from bus.codec import FaultCmd, FdirStatus, Gyro, Message, ThrCmd, decode, encode
from common.scenario import FaultSpec

# FAULT_CMD kind <-> the scenario's fault kind names.
FAULT_KIND_FROM_BUS = {
    FaultKind.STUCK_ON: "stuck_on", FaultKind.FAIL_TO_FIRE: "fail_to_fire",
    FaultKind.DEGRADED: "degraded", FaultKind.GYRO_SPIKE: "gyro_spike",
    FaultKind.GYRO_BIAS_STEP: "gyro_bias_step", FaultKind.GYRO_FROZEN: "gyro_frozen",
    FaultKind.GYRO_NOISE: "gyro_noise", FaultKind.BUS_DROP: "bus_drop",
    FaultKind.BUS_DELAY: "bus_delay", FaultKind.BUS_CORRUPT: "bus_corrupt",
    FaultKind.NODE_SILENT: "node_silent", FaultKind.BUS_BABBLE: "bus_babble",
}
FAULT_KIND_TO_BUS = {name: kind for kind, name in FAULT_KIND_FROM_BUS.items()}
# A panel-injected gyro fault's magnitude (FAULT_CMD carries none), rad/s.
PANEL_GYRO_MAGNITUDE_RAD_S = 1e-3

_DETECTED = {"stuck_on": DetectedFault.STUCK_ON, "fail_to_fire": DetectedFault.FAIL_TO_FIRE,
             "degraded": DetectedFault.DEGRADED, "gyro_fault": DetectedFault.GYRO_FAULT}


def over_the_wire(msg: Message) -> Message:
    """``msg`` as the receiver gets it: encoded to frames and decoded (the bus's quantisation
    and ranges), for the in-process path."""
    return decode(encode(msg))


# ----------------------------------------------------------------------------- plant -> flight


def gyro_message(sample) -> Gyro:
    """GYRO of one ``plant.gyro.GyroSample`` (``rate_B_rad_s`` (3,), rad/s, body axes)."""
    raw = np.asarray(sample.rate_B_rad_s, dtype=float)
    rate = np.clip(raw, -GYRO_RATE_LIMIT_RAD_S, GYRO_RATE_LIMIT_RAD_S)
    status = int(sample.status) or 1
    if bool((np.abs(raw) > GYRO_RATE_LIMIT_RAD_S).any()):
        status |= GyroStatus.SATURATED
    return Gyro(sample.seq & 0xFFFF, tuple(float(x) for x in rate), status)


def saturated(gyro: Gyro | None) -> bool:
    """The sample was clipped to the GYRO range on some axis (``GyroStatus.SATURATED``): the
    rate it gives is not the craft's, and neither is the rate change to or from it."""
    return gyro is not None and bool(gyro.status & GyroStatus.SATURATED)


# ----------------------------------------------------------------------------- flight -> plant


def command_quanta(on_ms: Sequence[int], safe: bool = False) -> tuple[int, ...]:
    """THR_CMD on-durations (quanta) of the allocator's on-times ``on_ms`` (N,) in ms; all zero
    in the flight's safe mode."""
    quanta = tuple(int(x) // ON_QUANTUM_MS for x in on_ms)
    return (0,) * len(quanta) if safe else quanta


def manifold_mask(manifold_open: Sequence[bool]) -> int:
    """THR_CMD ``manifold_enable``: bit m set = manifold m open."""
    return sum(1 << m for m, o in enumerate(manifold_open) if o)


def thr_cmd(tick: int, out, gyro_seq: int, safe: bool = False) -> ThrCmd:
    """THR_CMD of flight tick ``tick`` from its ``TickOutput`` and the GYRO sample it used."""
    return ThrCmd(tick, command_quanta(out.on_ms, safe), manifold_mask(out.manifold_open),
                  gyro_seq)


def fdir_status(last_detection, out, safe: bool) -> FdirStatus:
    """FDIR_STATUS: the newest detection so far (``flight.detector.Detection`` or None), the
    manifolds the output closes, and the safe flag (the shell's or the flight's own)."""
    last = last_detection
    g = last.group if last else ()
    closed = sum(1 << m for m, o in enumerate(out.manifold_open) if not o)
    return FdirStatus(
        last.tick if last else 0, _DETECTED.get(last.kind, DetectedFault.NONE) if last else 0,
        g[0] if g else None, g[1] if len(g) > 1 else None,
        closed, safe or out.safe_mode, 0)


def plant_command(cmd: ThrCmd, n_manifolds: int) -> tuple[np.ndarray, np.ndarray]:
    """The plant's command of a THR_CMD: on-times (N,) in ms and manifold open flags (M,)."""
    on_ms = np.asarray(cmd.on_quanta, dtype=float) * ON_QUANTUM_MS
    man = np.array([(cmd.manifold_enable >> m) & 1 for m in range(n_manifolds)], dtype=bool)
    return on_ms, man


# ----------------------------------------------------------------------------- faults


def fault_cmd_inject(request_id: int, kind: str, thruster_index: int | None, fraction: float,
                     start_s: float, clear_s: float | None) -> FaultCmd:
    """FAULT_CMD injecting fault ``kind`` (a scenario fault kind name)."""
    return FaultCmd(request_id, FaultAction.INJECT, FAULT_KIND_TO_BUS[kind], thruster_index,
                    fraction, start_s, clear_s)


# A panel bus_babble's rate is FAULT_CMD.fraction times this (fraction's range is 0..1).
PANEL_BABBLE_FULL_HZ = 20_000.0


def _bus_fields(cmd: FaultCmd, kind: str) -> dict:
    """FaultSpec fields of a bus FAULT_CMD: ``fraction`` is the probability (bus_delay: the
    delay in seconds, bus_babble: the rate over PANEL_BABBLE_FULL_HZ), ``message`` an index
    into ``bus.faults.MESSAGE_NAMES`` (0: every frame)."""
    from bus.faults import MESSAGE_NAMES

    if not 0 <= cmd.message <= len(MESSAGE_NAMES):
        raise ValueError(f"fault: message: expected 0..{len(MESSAGE_NAMES)}, got {cmd.message}")
    out: dict = {"message": MESSAGE_NAMES[cmd.message - 1] if cmd.message else None}
    if kind == "bus_delay":
        out["delay_ms"] = cmd.fraction * 1e3
    elif kind == "bus_babble":
        out["rate_hz"] = max(cmd.fraction * PANEL_BABBLE_FULL_HZ, 1.0)
    elif kind != "node_silent":
        out["probability"] = cmd.fraction
    return out


def fault_spec(cmd: FaultCmd, thruster_names: Sequence[str], now_s: float,
               node: str | None = None) -> FaultSpec:
    """The ``FaultSpec`` of an injecting FAULT_CMD (its kind known, its thruster index valid),
    starting no earlier than ``now_s`` (plant time). Raises ``ValueError`` (pydantic) when the
    fields do not make a valid fault."""
    kind = FAULT_KIND_FROM_BUS[cmd.kind]
    return FaultSpec(
        kind=kind, t_s=max(cmd.start_time_s, now_s),
        clear_t_s=cmd.clear_time_s,
        thruster=None if cmd.thruster is None or node is not None
        else thruster_names[cmd.thruster],
        fraction=cmd.fraction if kind in ("stuck_on", "degraded") else None,
        **(_bus_fields(cmd, kind) if node is not None else {}),
        magnitude_rad_s=PANEL_GYRO_MAGNITUDE_RAD_S
        if kind.startswith("gyro") and kind != "gyro_frozen" else None,
        node=node or ("flight" if kind.startswith("bus") or kind == "node_silent" else None),
    )
