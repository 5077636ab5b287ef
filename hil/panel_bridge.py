"""Fault requests through the run folder: `hil fault` reaches a system inside user-mode Linux.

Where the kernel has no CAN, ``hil up`` runs its processes inside user-mode Linux, whose vcan0
no host process can open. What the host and that instance share is the disk (hostfs), so the
run folder carries the requests: ``hil up`` starts a panel bridge (``python -m
hil.panel_server``) beside the plant and flight, in the same instance, on the same bus. It
serves ``RUN/control/``:

* ``bridge.json``: written when the bridge starts and again every ``HEARTBEAT_S``; its
  modification time says the bridge is alive (a file older than ``STALE_S`` is a bridge that
  is gone). It names the bus and where the bridge runs.
* ``req-<id>.json``: one request, written whole by the panel (beside, then renamed): the
  FAULT_CMD's fields and how long to wait for the acknowledgement.
* ``ack-<id>.json``: the answer, written whole by the bridge: the plant's FAULT_ACK (request
  id, status, reason) or the error text of the bridge's ``hil.panel.send_and_wait`` (no
  FAULT_ACK in time, a bus that cannot be opened).

The bridge sends the FAULT_CMD with ``hil.panel.send_and_wait``, the very function the panel
uses on the bus, so the plant sees the same frames and answers with the same FAULT_ACK, and
the panel prints the same lines and exit codes either way. Everything a request can get
wrong (a thruster name, a fraction) is checked by the panel before the request is written.

``RUN/control/stop`` is the other request the folder carries: ``hil up``/``hil run`` on the
host write it on Ctrl-C or SIGTERM, and the supervisor inside (``hil.run.supervise``) ends the
run as it would on its own Ctrl-C (summary written, processes stopped, ``run.rrd`` closed).
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import time
from pathlib import Path

from bus.catalog import AckReason, AckStatus, FaultAction, FaultKind
from bus.codec import FaultAck, FaultCmd
from hil.errors import BusError

CONTROL = "control"
HEARTBEAT_S = 1.0
STALE_S = 10.0
POLL_S = 0.02  # how often the bridge and the panel look at the folder


def control_dir(run: Path) -> Path:
    return Path(run) / CONTROL


def stop_path(run: Path) -> Path:
    return control_dir(run) / "stop"


def request_stop(run: Path, why: str) -> None:
    """Ask the supervisor that writes ``run`` to end the run (see the module doc)."""
    d = control_dir(run)
    with contextlib.suppress(OSError):
        d.mkdir(parents=True, exist_ok=True)
        _write_whole(stop_path(run), {"why": why, "t_unix_s": time.time()})


def bridge_info(run: Path) -> dict | None:
    """The live bridge's ``bridge.json`` for ``run``, or None when there is none or it is
    stale (older than ``STALE_S``: the bridge has stopped)."""
    path = control_dir(run) / "bridge.json"
    try:
        age = time.time() - path.stat().st_mtime
        info = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if age > STALE_S or not isinstance(info, dict):
        return None
    return info


def _write_whole(path: Path, obj: dict) -> None:
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    tmp.write_text(json.dumps(obj))
    os.replace(tmp, path)


def cmd_to_json(cmd: FaultCmd) -> dict:
    return {"request_id": cmd.request_id, "action": int(cmd.action), "kind": int(cmd.kind),
            "thruster": cmd.thruster, "fraction": cmd.fraction,
            "start_time_s": cmd.start_time_s, "clear_time_s": cmd.clear_time_s}


def cmd_from_json(d: dict) -> FaultCmd:
    return FaultCmd(int(d["request_id"]), FaultAction(int(d["action"])),
                    FaultKind(int(d["kind"])),
                    None if d.get("thruster") is None else int(d["thruster"]),
                    float(d["fraction"]), float(d["start_time_s"]),
                    None if d.get("clear_time_s") is None else float(d["clear_time_s"]))


def send_via_run(cmd: FaultCmd, run: Path, timeout_s: float) -> FaultAck:
    """The panel's side: write the request, wait for the bridge's answer; the FAULT_ACK, or
    ``BusError`` with the same text the bus path gives (or saying the bridge is gone)."""
    info = bridge_info(run)
    if info is None:
        raise BusError(f"fault: no panel bridge serving {run} (no fresh {CONTROL}/bridge.json):"
                       f" is `hil up --out {run}` running?")
    d = control_dir(run)
    name = f"{cmd.request_id:03d}-{secrets.token_hex(4)}"
    req, ack = d / f"req-{name}.json", d / f"ack-{name}.json"
    _write_whole(req, {**cmd_to_json(cmd), "timeout_s": timeout_s})
    # The bridge's own wait is timeout_s; allow it that long plus the folder's round trips.
    t_end = time.monotonic() + timeout_s + 2.0
    try:
        while time.monotonic() < t_end:
            if ack.exists():
                answer = json.loads(ack.read_text())
                if answer.get("error"):
                    raise BusError(answer["error"])
                return FaultAck(int(answer["request_id"]), AckStatus(int(answer["status"])),
                                AckReason(int(answer["reason"])),
                                FaultKind(int(answer.get("kind", 0))))
            time.sleep(POLL_S)
        taken = not req.exists()
        raise BusError(f"fault: no FAULT_ACK for request {cmd.request_id} within "
                       f"{timeout_s:g} s: the panel bridge of {run} "
                       + ("took the request but did not answer" if taken
                          else "did not take the request (stopped?)"))
    finally:
        for p in (req, ack, d / f"req-{name}.json.taken"):
            with contextlib.suppress(OSError):
                p.unlink()


def serve(run: Path, interface: str, channel: str, stop, send_and_wait, log=None) -> int:
    """The bridge's loop: answer every request in ``run/control`` until ``stop()``, each sent
    with ``send_and_wait(cmd, interface, channel, timeout_s)`` (``hil.panel.send_and_wait``:
    ``hil.panel_server`` runs it so); ``log(text)``, when given, gets a line per request."""
    d = control_dir(run)
    d.mkdir(parents=True, exist_ok=True)
    info = {"interface": interface, "channel": channel, "pid": os.getpid(),
            "where": "user-mode Linux" if os.environ.get("HIL_UML") else "native"}
    beat = 0.0
    served = 0
    while not stop():
        now = time.monotonic()
        if now - beat >= HEARTBEAT_S:
            _write_whole(d / "bridge.json", {**info, "served": served})
            beat = now
        for entry in sorted(os.scandir(d), key=lambda e: e.name):
            if not (entry.name.startswith("req-") and entry.name.endswith(".json")):
                continue
            taken = Path(entry.path + ".taken")
            try:
                os.replace(entry.path, taken)  # one bridge takes it, once
                body = json.loads(taken.read_text())
                cmd = cmd_from_json(body)
                timeout_s = float(body.get("timeout_s", 5.0))
            except (OSError, ValueError, KeyError, TypeError) as exc:
                _answer(d, entry.name, {"error": f"fault: request {entry.name}: expected a "
                                                 f"panel request, got {exc}"})
                continue
            try:
                t0 = time.monotonic()
                ack = send_and_wait(cmd, interface, channel, timeout_s)
                _answer(d, entry.name, {"request_id": ack.request_id, "status": int(ack.status),
                                        "reason": int(ack.reason), "kind": int(ack.kind),
                                        "bus_s": round(time.monotonic() - t0, 4)})
                if log is not None:
                    log(f"panel bridge: request {cmd.request_id}: FAULT_ACK after "
                        f"{time.monotonic() - t0:.3f} s on the bus")
            except BusError as exc:
                _answer(d, entry.name, {"error": str(exc)})
            except Exception as exc:  # noqa: BLE001 - a request never kills the bridge
                _answer(d, entry.name, {"error": f"fault: the panel bridge failed: {exc}"})
            served += 1
            with contextlib.suppress(OSError):
                taken.unlink()
        time.sleep(POLL_S)
    with contextlib.suppress(OSError):
        (d / "bridge.json").unlink()
    return 0


def _answer(d: Path, req_name: str, body: dict) -> None:
    with contextlib.suppress(OSError):
        _write_whole(d / ("ack-" + req_name[len("req-"):]), body)
