"""`hil fault`: the fault panel, a third node on the bus (docs/design.md section 2).

``hil fault inject --thruster NAME --type stuck_on|fail_to_fire|degraded [--fraction F]
[--at T] [--clear-at T]`` sends FAULT_CMD to the running plant and waits for its FAULT_ACK;
``hil fault clear [--thruster NAME]`` ends faults; ``hil fault list`` shows the faults the
running plant has made active and not yet ended (from its per-tick record in the run folder)
and the thruster names of the vehicle. Everything is checked before anything is sent: an
unknown thruster, a bad type or a fraction outside [0, 1] gets one line and exit 2, and no
frame goes out.

How the panel finds the running system: over the bus (``--interface``/``--channel``, vcan0 by
default) for FAULT_CMD and FAULT_ACK, and through the run folder (``--run``, default
``runs/up``, the default ``--out`` of ``hil up``) for everything else. The plant's first
record in ``RUN/plant.jsonl`` names its vehicle (``config``, see ``hil.nodes``), so thruster
names are checked against the vehicle actually flying; ``--vehicle`` overrides it (and is
needed when no run folder is there). Where the kernel has no CAN, ``hil up`` runs inside
user-mode Linux with its own vcan0, which no host process can open: there ``hil up`` runs a
panel bridge beside the plant, and the request goes through the run folder to it
(``hil.panel_bridge``); it sends the same FAULT_CMD with ``send_and_wait`` and hands back the
plant's FAULT_ACK. ``--via auto`` (the default) takes the bridge when the run folder has a live
one, else the bus; ``--via bus`` / ``--via run`` force one.
"""

from __future__ import annotations

import itertools
import sys
import time
from pathlib import Path

from bus.catalog import AckReason, AckStatus, FaultAction, FaultKind, Node
from bus.codec import FaultAck, FaultCmd
from bus.faults import MESSAGE_NAMES
from hil.argtypes import number
from hil.binding import FAULT_KIND_TO_BUS, PANEL_BABBLE_FULL_HZ, fault_cmd_inject
from hil.config import MAX_DURATION_S, THRUSTER_FAULTS, VehicleCfg, load_vehicle
from hil.errors import BusError, FaultCommandError, UsageError
from hil.recorder import read_jsonl
from hil.secoc_key import KEY_FILE, read_key
from hil.summary import apply_clear

BUS_TYPES = ("bus_drop", "bus_delay", "bus_corrupt", "bus_babble", "node_silent")
TYPES = THRUSTER_FAULTS + BUS_TYPES  # what the panel injects (gyro faults: scenarios)


def build_bus_command(action: str, kind: str, node: str | None, probability: float | None,
                      delay_ms: float | None, rate_hz: float | None, message: str | None,
                      at_s: float | None, clear_at_s: float | None,
                      request_id: int) -> FaultCmd:
    """FAULT_CMD of a bus fault on ``node``'s send path (``bus.faults``): the node id in
    ``thruster``, the probability (bus_delay: the delay in s, bus_babble: rate / 20 kHz) in
    ``fraction``, the message index in ``message``. Checked before anything is sent."""
    if node not in ("plant", "flight"):
        raise FaultCommandError(f"fault: --node: expected 'plant' or 'flight' for {kind}, "
                                f"got {node!r}")
    msg = 0
    if message is not None:
        if message not in MESSAGE_NAMES:
            raise FaultCommandError(f"fault: --message: expected one of {list(MESSAGE_NAMES)}, "
                                    f"got {message!r}")
        msg = MESSAGE_NAMES.index(message) + 1
    nid = int(Node[node.upper()])
    if action == "clear":
        return FaultCmd(request_id, FaultAction.CLEAR, FAULT_KIND_TO_BUS[kind], nid)
    if kind == "bus_delay":
        if delay_ms is None or not 0 < delay_ms <= 1000:
            raise FaultCommandError(f"fault: --delay-ms: expected a delay in (0, 1000] ms, got "
                                    f"{delay_ms}")
        value = delay_ms / 1e3
    elif kind == "bus_babble":
        rate = 1000.0 if rate_hz is None else rate_hz
        if not 1 <= rate <= PANEL_BABBLE_FULL_HZ:
            raise FaultCommandError(f"fault: --rate-hz: expected 1..{PANEL_BABBLE_FULL_HZ:g}, "
                                    f"got {rate}")
        value = rate / PANEL_BABBLE_FULL_HZ
    else:
        value = 1.0 if probability is None else probability
    if at_s is not None and clear_at_s is not None and clear_at_s <= at_s:
        raise FaultCommandError(f"fault: --clear-at: expected a time after --at, got {clear_at_s}")
    return FaultCmd(request_id, FaultAction.INJECT, FAULT_KIND_TO_BUS[kind], nid, value,
                    at_s or 0.0, clear_at_s, msg)


def build_command(vehicle: str | VehicleCfg, action: str, thruster: str | None,
                  kind: str | None, fraction: float | None, at_s: float | None,
                  clear_at_s: float | None, request_id: int) -> FaultCmd:
    """Validate a panel request against the vehicle (a name, a path or a loaded one) and
    build its FAULT_CMD (pure apart from reading the vehicle file)."""
    v = vehicle if isinstance(vehicle, VehicleCfg) else load_vehicle(vehicle)
    names = [t.name for t in v.thrusters]
    idx = None
    if thruster is not None:
        if thruster not in names:
            raise FaultCommandError(f"fault: --thruster: expected one of {names}, got {thruster!r}")
        idx = names.index(thruster)
    if action == "clear":
        # A CLEAR ends every fault of the thruster (or every fault): its kind is "none".
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
    return fault_cmd_inject(request_id, kind, idx, fraction, at_s or 0.0, clear_at_s)


RESEND_S = 0.25  # no FAULT_ACK after this long: send the request again (see send_and_wait)


def send_and_wait(cmd: FaultCmd, interface: str, channel: str, timeout_s: float,
                  key: bytes | None = None) -> FaultAck:
    """Send ``cmd`` and return the plant's FAULT_ACK; BusError when none comes in time.

    Every panel run is a new process whose E2E alive counters start at 0, so the plant's
    receiver may refuse its first frames as a repeated counter or a jump (it follows the
    counter even so). Without an answer the request goes out again every ``RESEND_S``, with
    the next counter, which the receiver takes; the plant acknowledges a repeated request
    again without applying it twice (``hil.nodes.PlantShell.on_fault_cmd``).
    """
    from bus.transport import BusConfig, Port, node_filters, open_bus

    if interface == "lcm":  # the channel is the LCM URL (docs/lcm.md)
        from bus.lcm_transport import LcmPort

        port: Port = LcmPort(channel)
    else:
        port = Port(open_bus(BusConfig(interface=interface, channel=channel,
                                       kwargs={"can_filters": node_filters(Node.PANEL)})))
    if key is not None:  # FAULT_CMD authenticated (bus.secoc), on CAN and over LCM
        from bus.secoc import Authenticator

        port.auth = Authenticator(key)
    try:
        port.send(cmd)
        now = time.monotonic()
        t_end, t_resend = now + timeout_s, now + RESEND_S
        while time.monotonic() < t_end:
            for msg, _ in port.poll(0.05):
                if isinstance(msg, FaultAck) and msg.request_id == cmd.request_id:
                    return msg
            if time.monotonic() >= t_resend:
                port.send(cmd)
                t_resend += RESEND_S
        hint = "" if key is not None else " (and given its key, --key-file?)"
        raise BusError(f"fault: no FAULT_ACK for request {cmd.request_id} within "
                       f"{timeout_s:g} s: is the plant running on {interface} {channel}"
                       f"{hint}?")
    finally:
        port.close()


def deliver(cmd: FaultCmd, run: Path, via: str, interface: str, channel: str,
            timeout_s: float, key: bytes | None = None) -> FaultAck:
    """Send ``cmd`` by the path ``via`` names (auto: the run folder's live panel bridge when
    there is one, else the bus) and return the plant's FAULT_ACK (BusError when none). The
    bridge signs with the run's own key (it runs beside the plant, ``hil.panel_server``)."""
    from hil.panel_bridge import bridge_info, send_via_run

    if via == "run" or (via == "auto" and bridge_info(run) is not None):
        return send_via_run(cmd, run, timeout_s)
    return send_and_wait(cmd, interface, channel, timeout_s, key)


def _request_id() -> int:
    return (int(time.time() * 1000) + next(_SEQ)) % 256  # FAULT_CMD.request_id is 8 bits


_SEQ = itertools.count()


def running_config(run: Path) -> dict | None:
    """The ``config`` of the plant's first record in ``run`` (None when there is none)."""
    first = next(iter(read_jsonl(Path(run) / "plant.jsonl")), None)
    return None if first is None else first.get("config")


def resolve_vehicle(vehicle: str | None, run: Path) -> tuple[VehicleCfg, str]:
    """The vehicle to check names against and where it came from (for the output).

    ``--vehicle`` when given; otherwise the one the plant in the run folder flies.
    """
    if vehicle is not None:
        return load_vehicle(vehicle), "--vehicle"
    cfg = running_config(run)
    if not cfg or not cfg.get("vehicle"):
        raise UsageError(f"fault: --vehicle: expected the vehicle of a running `hil up`, got "
                         f"no plant record in {run}: give --run DIR (the --out of hil up) "
                         f"or --vehicle V")
    vfile = cfg.get("vehicle_file")
    v = load_vehicle(vfile if vfile and Path(vfile).exists() else cfg["vehicle"])
    return v, f"the plant in {run}"


def _lcm_route(args) -> int | None:
    """``--bus lcm``: the URL as the channel, and the run's network namespace joined (the
    ``hil up`` over LCM runs in a private one, ``hil.netns``); None: go on here."""
    from bus.lcm_transport import DEFAULT_URL
    from hil.netns import join_run_namespace

    if args.bus != "lcm":
        if args.lcm_url is not None:
            raise UsageError(f"fault: --lcm-url: expected it with --bus lcm, got "
                             f"{args.lcm_url!r} with the can bus")
        return None
    args.interface, args.channel = "lcm", args.lcm_url or DEFAULT_URL
    argv = ["fault", args.action, "--run", str(Path(args.run).resolve()),
            "--timeout", str(args.timeout), "--interface", "lcm", "--channel", args.channel]
    for flag, v in (("--thruster", args.thruster), ("--type", args.type),
                    ("--fraction", args.fraction), ("--at", args.at),
                    ("--clear-at", args.clear_at), ("--vehicle", args.vehicle)):
        if v is not None:
            argv += [flag, str(v)]
    return join_run_namespace(Path(args.run), argv)


def _cmd(args) -> int:
    if args.action != "list":
        rc = _lcm_route(args)
        if rc is not None:
            return rc
    run = Path(args.run)
    vehicle, source = resolve_vehicle(args.vehicle, run)
    if args.action == "list":
        return _list(vehicle, source, run)
    if args.type in BUS_TYPES:
        cmd = build_bus_command(args.action, args.type, args.node, args.fraction, args.delay_ms,
                                args.rate_hz, args.message, args.at, args.clear_at,
                                _request_id())
        args.thruster = args.node
    else:
        cmd = build_command(vehicle, args.action, args.thruster, args.type, args.fraction,
                            args.at, args.clear_at, _request_id())
    late = past_start_warning(args.at, run)
    if late:
        print(late, file=sys.stderr)
    key_file = args.key_file or (run / KEY_FILE if (run / KEY_FILE).exists() else None)
    key = None if key_file is None else read_key(key_file)
    ack = deliver(cmd, run, args.via, args.interface, args.channel, args.timeout, key)
    print(ack_line(ack, args.action, args.type, args.thruster, vehicle.name))
    return 0 if ack.status == AckStatus.ACCEPTED else 1


def ack_line(ack: FaultAck, action: str, kind: str | None, thruster: str | None,
             vehicle_name: str) -> str:
    """What the panel prints for the plant's FAULT_ACK (also the console's fault panel)."""
    what = f"{action} {kind + ' ' if kind else ''}{thruster or 'all'}"
    if ack.status == AckStatus.ACCEPTED:
        return f"ok: plant accepted {what} (request {ack.request_id}, vehicle {vehicle_name})"
    return (f"error: plant rejected {what} (request {ack.request_id}): "
            f"{AckReason(ack.reason).name.lower()}")


def past_start_warning(at_s: float | None, run: Path) -> str | None:
    """A warning when ``--at`` is already behind the running plant's time (its last record):
    the plant then applies the fault at once, not at ``--at``."""
    if at_s is None:
        return None
    _, now = active_faults(read_jsonl(Path(run) / "plant.jsonl"))
    if now is None or at_s >= now:
        return None
    return (f"warning: fault: --at {at_s:g} s is in the past (plant time {now:.1f} s in {run}): "
            f"the plant applies it at once")


def active_faults(records) -> tuple[list[dict], float | None]:
    """Faults the plant made active and that have not ended by its last record, and the time
    of that record (``faults_injected`` less panel clears and scheduled ends)."""
    faults: list[dict] = []
    now = None
    for r in records:
        now = r.get("t_s", now)
        faults.extend(dict(f) for f in r.get("faults_injected", []))
        for c in r.get("faults_cleared", []):
            apply_clear(faults, c)
    if now is None:
        return [], None
    return [f for f in faults if f.get("clear_t_s") is None or f["clear_t_s"] > now], now


def _list(vehicle: VehicleCfg, source: str, run: Path) -> int:
    print(f"vehicle {vehicle.name} ({source}): thrusters "
          f"{', '.join(t.name for t in vehicle.thrusters)}")
    active, now = active_faults(read_jsonl(run / "plant.jsonl"))
    if not active:
        print(f"no fault active in the run at {run}"
              + ("" if now is None else f" (plant time {now:.1f} s)"))
        return 0
    print(f"faults active at plant time {now:.1f} s in {run}:")
    for line in fault_table(active):
        print(line)
    return 0


FAULT_COLUMNS = (("thruster", "thruster", "{}"), ("type", "type", "{}"),
                 ("fraction", "fraction", "{:g}"), ("t_s", "from [s]", "{:.2f}"),
                 ("clear_t_s", "until [s]", "{:.2f}"))


def fault_table(faults: list[dict]) -> list[str]:
    """Active faults as an aligned text table (header first); ``-`` for no value."""
    rows = [[h for _, h, _ in FAULT_COLUMNS]]
    for f in faults:
        rows.append(["-" if f.get(k) is None else fmt.format(f[k]) for k, _, fmt in FAULT_COLUMNS])
    widths = [max(len(r[i]) for r in rows) for i in range(len(FAULT_COLUMNS))]
    return ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in rows]


def register(sub) -> None:
    import argparse

    summary = "fault panel: inject, clear or list faults in the running system (hil up)"
    p = sub.add_parser("fault", help=summary, description=summary,
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog="""examples:
  hil fault list                                     thrusters and active faults of runs/up
  hil fault inject --thruster X+ --type stuck_on     now, full thrust
  hil fault inject --thruster 17 --type degraded --fraction 0.4 --at 30 --clear-at 60
  hil fault clear --thruster X+                      (no --thruster: every fault)

exit codes: 0 the plant accepted (FAULT_ACK), 1 it rejected (the reason is printed),
2 bad request or no FAULT_ACK in time (nothing applied).""")
    p.add_argument("action", choices=("inject", "clear", "list"))
    p.add_argument("--thruster", help="thruster name (see `hil fault list`)")
    p.add_argument("--type", choices=list(TYPES), help="fault type (inject)")
    p.add_argument("--fraction", type=number(ge=0, le=1),
                   help="stuck_on: residual thrust; degraded: remaining thrust; bus_drop, "
                        "bus_corrupt: probability per frame (0..1)")
    p.add_argument("--node", choices=("plant", "flight"),
                   help="bus faults: the node whose send path gets the fault")
    p.add_argument("--message", help="bus faults: only this message's frames (e.g. GYRO)")
    p.add_argument("--delay-ms", type=number(gt=0, le=1000), help="bus_delay: the delay [ms]")
    p.add_argument("--rate-hz", type=number(ge=1, le=20000),
                   help="bus_babble: frames per second (default 1000)")
    p.add_argument("--at", type=number(ge=0, le=MAX_DURATION_S),
                   help="plant time [s] to start (default: now)")
    p.add_argument("--clear-at", type=number(ge=0, le=MAX_DURATION_S),
                   help="plant time [s] to end the fault")
    p.add_argument("--vehicle",
                   help="vehicle to check thruster names against (default: the one the plant "
                        "in --run flies)")
    p.add_argument("--run", default="runs/up",
                   help="run folder of the running system, the --out of `hil up` (default "
                        "runs/up): its vehicle and, for list, its faults")
    p.add_argument("--timeout", type=number(gt=0, le=3600), default=5.0,
                   help="seconds to wait for FAULT_ACK")
    p.add_argument("--via", choices=("auto", "bus", "run"), default="auto",
                   help="how the request reaches the plant: run = through the panel bridge of "
                        "--run (hil up runs one; it works into user-mode Linux), bus = "
                        "directly on --interface/--channel, auto (default) = run when --run has "
                        "a live bridge, else bus")
    p.add_argument("--key-file", help="the run's SecOC key (default RUN/secoc.key, made by "
                                      "hil run / hil up)")
    p.add_argument("--interface", default="socketcan")
    p.add_argument("--channel", default="vcan0")
    p.add_argument("--bus", choices=("can", "lcm"), default="can",
                   help="can (--interface/--channel) or lcm: the running `hil up --bus lcm` "
                        "in --run is reached in its private network namespace")
    p.add_argument("--lcm-url", metavar="URL", help="LCM provider (default that of hil up)")
    p.set_defaults(func=_cmd)
