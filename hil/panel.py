"""`hil fault`: the fault panel, a third node on the bus (DESIGN.md section 2).

``hil fault inject --thruster NAME --type stuck_on|fail_to_fire|degraded [--fraction F]
[--at T] [--clear-at T]`` sends FAULT_CMD to the running plant and waits for its FAULT_ACK;
``hil fault clear [--thruster NAME]`` ends faults; ``hil fault list`` shows the faults the
running plant has made active (from its per-tick record in the run folder) and the thruster
names of the vehicle. Everything is checked before anything is sent: an unknown thruster, a
bad type or a fraction outside [0, 1] gets one line and exit 2, and no frame goes out.
"""

from __future__ import annotations

import itertools
import json
import time
from pathlib import Path

from bus.catalog import AckReason, AckStatus, FaultAction, FaultKind
from bus.codec import FaultAck, FaultCmd
from hil.config import load_vehicle
from hil.errors import BusError, FaultCommandError
from hil.recorder import read_jsonl

TYPES = {"stuck_on": FaultKind.STUCK_ON, "fail_to_fire": FaultKind.FAIL_TO_FIRE,
         "degraded": FaultKind.DEGRADED}


def build_command(vehicle: str, action: str, thruster: str | None, kind: str | None,
                  fraction: float | None, at_s: float | None, clear_at_s: float | None,
                  request_id: int) -> FaultCmd:
    """Validate a panel request against the vehicle and build its FAULT_CMD (pure)."""
    v = load_vehicle(vehicle)
    names = [t.name for t in v.thrusters]
    idx = None
    if thruster is not None:
        if thruster not in names:
            raise FaultCommandError(f"fault: --thruster: expected one of {names}, got {thruster!r}")
        idx = names.index(thruster)
    if action == "clear":
        return FaultCmd(request_id, FaultAction.CLEAR, FaultKind.NONE, idx)
    if kind not in TYPES:
        raise FaultCommandError(f"fault: --type: expected one of {list(TYPES)}, got {kind!r}")
    if idx is None:
        raise FaultCommandError("fault: --thruster: expected a thruster name, got nothing")
    if fraction is None:
        if kind == "degraded":
            raise FaultCommandError("fault: --fraction: expected a value in [0, 1] for a "
                                    "degraded thruster, got nothing")
        fraction = 1.0
    if not 0.0 <= fraction <= 1.0:
        raise FaultCommandError(f"fault: --fraction: expected a value in [0, 1], got {fraction}")
    if at_s is not None and at_s < 0:
        raise FaultCommandError(f"fault: --at: expected a time >= 0 s, got {at_s}")
    if clear_at_s is not None and clear_at_s <= (at_s or 0.0):
        raise FaultCommandError(f"fault: --clear-at: expected a time after --at, got {clear_at_s}")
    return FaultCmd(request_id, FaultAction.INJECT, TYPES[kind], idx, fraction,
                    at_s or 0.0, clear_at_s)


def send_and_wait(cmd: FaultCmd, interface: str, channel: str, timeout_s: float) -> FaultAck:
    from bus.transport import BusConfig, Port, open_bus

    port = Port(open_bus(BusConfig(interface=interface, channel=channel)))
    try:
        port.send(cmd)
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            for msg, _ in port.poll(0.05):
                if isinstance(msg, FaultAck) and msg.request_id == cmd.request_id:
                    return msg
        raise BusError(f"fault: no FAULT_ACK for request {cmd.request_id} within "
                       f"{timeout_s:g} s: is the plant running on {interface} {channel}?")
    finally:
        port.close()


def _request_id() -> int:
    return (int(time.time() * 1000) + next(_SEQ)) % 256  # FAULT_CMD.request_id is 8 bits


_SEQ = itertools.count()


def _cmd(args) -> int:
    if args.action == "list":
        return _list(args)
    cmd = build_command(args.vehicle, args.action, args.thruster, args.type, args.fraction,
                        args.at, args.clear_at, _request_id())
    ack = send_and_wait(cmd, args.interface, args.channel, args.timeout)
    if ack.status == AckStatus.ACCEPTED:
        print(f"ok: plant accepted {args.action} {args.type or ''} {args.thruster or 'all'} "
              f"(request {ack.request_id})")
        return 0
    print(f"error: plant rejected request {ack.request_id}: {AckReason(ack.reason).name.lower()}")
    return 1


def _list(args) -> int:
    v = load_vehicle(args.vehicle)
    print(f"vehicle {v.name}: thrusters {', '.join(t.name for t in v.thrusters)}")
    active = []
    for r in read_jsonl(Path(args.run) / "plant.jsonl"):
        active.extend(r.get("faults_injected", []))
    if not active:
        print(f"no fault active in the run at {args.run}")
    for f in active:
        print(json.dumps(f))
    return 0


def register(sub) -> None:
    p = sub.add_parser("fault", help="fault panel: inject, clear or list faults (running system)")
    p.add_argument("action", choices=("inject", "clear", "list"))
    p.add_argument("--thruster", help="thruster name (see `hil fault list`)")
    p.add_argument("--type", choices=list(TYPES), help="fault type (inject)")
    p.add_argument("--fraction", type=float,
                   help="stuck_on: residual thrust; degraded: remaining thrust (0..1)")
    p.add_argument("--at", type=float, help="plant time [s] to start (default: now)")
    p.add_argument("--clear-at", type=float, help="plant time [s] to end the fault")
    p.add_argument("--vehicle", default="generic", help="vehicle of the running system")
    p.add_argument("--run", default="runs/up", help="run folder of the running system (list)")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for FAULT_ACK")
    p.add_argument("--interface", default="socketcan")
    p.add_argument("--channel", default="vcan0")
    p.set_defaults(func=_cmd)
