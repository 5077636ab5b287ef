"""What the plant and flight process shells share: the stop flag, the CAN port, the first
record's fields, the console line, and the small converters of the per-tick records.
"""

from __future__ import annotations

import signal
from dataclasses import replace
from pathlib import Path

from bus.catalog import CATALOG, Catalog, Node
from bus.faults import KINDS as BUS_FAULT_KINDS
from bus.faults import SendFaults
from bus.receiver import Receiver
from bus.transport import BusConfig, BusLogger, Port, node_filters, open_bus
from hil.config import Scenario, resolve_vehicle_path
from hil.node_settings import NodeSettings
from hil.process_policy import idle_gc

XYZ = ("x", "y", "z")
# Frames one poll takes from the socket at most (bus.transport.Port): a flood waits in the
# kernel's queue instead of holding a tick; nominal traffic is a few frames per poll.
MAX_FRAMES_PER_POLL = 32


def round6(x: float | None) -> float | None:
    """A time for a record, to the microsecond (None stays None)."""
    return None if x is None else round(x, 6)


def xyz_values(v, scale: float = 1.0) -> dict[str, float]:
    """A 3-vector times ``scale`` as a series' ``{"x", "y", "z"}`` values."""
    return {k: float(v[i]) * scale for i, k in enumerate(XYZ)}


def named_values(names, values) -> dict[str, float]:
    """Per-thruster values as a series' ``{name: value}``."""
    return {n: float(x) for n, x in zip(names, values, strict=True)}


class Stop:
    """SIGTERM/SIGINT set a flag; loops finish the current tick and exit cleanly."""

    def __init__(self) -> None:
        self.flag = False
        signal.signal(signal.SIGTERM, self._set)
        signal.signal(signal.SIGINT, self._set)

    def _set(self, *_: object) -> None:
        self.flag = True

    def __call__(self) -> bool:
        return self.flag


def lockstep_receiver(reply_timeout_s: float) -> Receiver:
    """A receiver whose age limits follow the lockstep, not the wall clock.

    In lockstep the plant is the time master and the lockstep protocol enforces the THR_CMD
    deadline; a frame that waited in the socket while its reader computed (a slow or loaded
    machine) is not stale in simulated time, and dropping it would make a run depend on the
    machine. CRC, counter, length, range and completeness checks stay as they are.
    """
    limit = max(10 * reply_timeout_s, 5.0)
    cat = Catalog(tuple(replace(f, deadline_s=max(f.deadline_s, limit)) for f in CATALOG.frames))
    return Receiver(catalog=cat)


def open_port(settings: NodeSettings, out: Path, name: str) -> Port:
    """The node's port: CAN, or LCM for interface ``lcm`` (``bus.lcm_transport.LcmPort``)
    (lockstep: age limits of ``lockstep_receiver``; ``NAME.bus.log`` when
    ``settings.bus_log``). On CAN: receive filters from the catalog (only the identifiers the
    node consumes; in the kernel on SocketCAN) and at most ``MAX_FRAMES_PER_POLL`` frames per
    poll. With a key file, the secured messages (``bus.secoc.SECURED``) are signed and
    checked (on both buses: over LCM the authenticator is a message of its own channel, as it
    is a frame of its own on CAN)."""
    s = settings
    receiver = lockstep_receiver(s.reply_timeout) if s.mode == "lockstep" else None
    if s.interface == "lcm":  # LCM: the channel is the provider URL (docs/lcm.md)
        from bus.lcm_transport import LcmPort

        logger = BusLogger(out / f"{name}.bus.log", channel="lcm") if s.bus_log else None
        port = LcmPort(s.channel, receiver=receiver, logger=logger)
    else:
        cfg = BusConfig(interface=s.interface, channel=s.channel,
                        kwargs={"can_filters": node_filters(Node[name.upper()])})
        logger = BusLogger(out / f"{name}.bus.log", channel=s.channel) if s.bus_log else None
        port = Port(open_bus(cfg), receiver=receiver, logger=logger,
                    max_frames_per_poll=MAX_FRAMES_PER_POLL)
    if s.key_file is not None:  # SecOC on both buses (docs/hostile-bus.md, docs/lcm.md)
        from bus.secoc import Authenticator
        from hil.secoc_key import read_key

        port.auth = Authenticator(read_key(s.key_file))
    return port


def attach_bus_faults(port: Port, sc: Scenario, node: str) -> SendFaults:
    """The node's send-path bus faults (``bus.faults``), seeded from the scenario's seed, with
    the scenario's bus faults of this node; set as the port's send hook (the panel adds and
    clears faults on it live)."""
    faults = SendFaults(sc.cfg.seed, node, clock=port.now_s)
    for f in sc.cfg.faults:
        if f.kind in BUS_FAULT_KINDS and f.node == node:
            faults.add(f)
    port.send_hook = faults
    return faults


def bus_fault_fields(shell, t_s: float) -> list[dict]:
    """This tick's newly active bus faults of the shell's node (``faults_injected``
    entries); their events go to the shell's events."""
    bf: SendFaults = shell.bus_faults
    bf.t_s = t_s
    new = bf.newly_active()
    shell.events.extend(bf.events)
    bf.events.clear()
    return new


def say(name: str, text: str) -> None:
    print(f"[{name}] {text}", flush=True)




def node_config(sc: Scenario, settings: NodeSettings, safety: dict) -> dict:
    """The ``config`` field of a node's first record (see the module doc)."""
    vfile = resolve_vehicle_path(sc.cfg.vehicle, relative_to=sc.path.parent)
    return {"scenario": sc.cfg.name, "vehicle": sc.vehicle.name,
            "vehicle_file": str(vfile.resolve()),
            "thrusters": [t.name for t in sc.vehicle.thrusters], "mode": settings.mode,
            "bus": f"{settings.interface} {settings.channel}", "safety": safety,
            # the secured messages authenticated (bus.secoc.SECURED): only with --key-file
            "secoc": settings.key_file is not None,
            # THR_CMD(n) takes effect this long after tick n's sample (0: on arrival)
            "actuation_phase_ms": round(1000.0 * settings.actuation_phase_s(), 3)}


def first_record(sc: Scenario, settings: NodeSettings, safety: dict) -> dict:
    """Fields only the first record of a node carries (``config``, ``sched``, --rt events)."""
    first: dict = {"config": node_config(sc, settings, safety)}
    if settings.sched_note is not None:
        first["sched"] = settings.sched_note
    first["events"] = [settings.rt_event] if settings.rt_event else []
    return first


def write_record(shell, rec: dict) -> None:
    """A shell's tick record out: the first record's extras merged in once, one line written
    (``JsonlWriter``), published as telemetry when the shell has a ``telemetry`` publisher,
    the tick's events reset, and the garbage collector's slot after it."""
    if shell.first:
        rec.update(shell.first)
        shell.first = {}
    auth = getattr(shell.port, "auth", None)
    if auth is not None and auth.events:  # authentication failures (bus.secoc)
        rec["events"] = [*rec.get("events", []), *auth.events]
        auth.events.clear()
    shell.rec.write(rec)
    telemetry = getattr(shell, "telemetry", None)
    if telemetry is not None and not rec.get("final"):
        telemetry.publish(rec)  # HIL_TRUTH / HIL_FLIGHT_VIEW on LCM (hil.telemetry)
    shell.events = []
    idle_gc(rec["tick"])
