"""The plant and flight processes: thin shells around the pure cores, talking only over CAN.

``python -m hil.nodes plant --scenario S.yaml --out DIR [--mode lockstep|realtime] ...``
``python -m hil.nodes flight --scenario S.yaml --out DIR [--mode lockstep|realtime] ...``

Each shell owns a clock, a ``bus.transport.Port`` and a per-tick JSON lines file in ``DIR``
(``plant.jsonl`` / ``flight.jsonl``, flushed every tick, see ``hil.recorder``). ``hil run`` and
``hil up`` start them; they can also be started by hand on two machines sharing a CAN bus.

This module is the entry point only; the parts live beside it:

* ``hil.node_settings``: the typed settings (``NodeSettings``) from the command line;
* ``hil.plant_shell`` / ``hil.flight_shell``: one shell per process (lockstep and real time,
  docs/design.md section 3);
* ``hil.safe_states``: the peer-loss watches (docs/design.md section 4), counts from the
  scenario's ``safety:`` block (``--lost-after``, ``--heartbeat-lost-s`` and
  ``--gyro-lost-after`` override them);
* ``hil.process_policy``: garbage collection out of the tick, the scheduler class (without
  ``--rt-priority`` the plant SCHED_BATCH, the flight SCHED_OTHER, so on one CPU the plant does
  not interrupt a flight tick), SCHED_FIFO and locked memory with ``--rt-priority``;
* ``hil.node_shell``: what both shells share (stop flag, port, first record).

``--start-after FILE``: the process sets up (imports, core, port), writes its ready file and
waits for FILE before its first tick; ``hil run`` starts both processes at once and gives the
plant the flight's ready file.

Each node's first record carries ``config`` (scenario, vehicle and its file, thruster names,
mode, bus, the safe-state settings it uses): ``hil fault`` learns the vehicle of a running
``hil up`` from it, and ``hil.summary`` puts the settings in ``summary.json``. With
``--rt-priority`` (``hil run --rt``, ``hil up --rt``) the first record also has an event that
says what was granted or refused.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import replace
from pathlib import Path

from hil.config import load_scenario
from hil.errors import HilError
from hil.flight_shell import FlightShell
from hil.node_settings import parse_settings
from hil.node_shell import Stop, open_port, say
from hil.plant_shell import PlantShell
from hil.process_policy import quiet_gc, realtime_event, set_policy, try_realtime_priority
from hil.recorder import OutputLost
from hil.verdict import EXIT_OUTPUT_LOST


def wait_for_file(path: Path, stop: Stop, poll_s: float = 0.005) -> bool:
    """Wait until ``path`` exists (True) or a stop signal came (False)."""
    while not path.exists():
        if stop():
            return False
        time.sleep(poll_s)
    return True


def main(argv: list[str] | None = None) -> int:
    settings = parse_settings(argv)
    out = Path(settings.out)
    out.mkdir(parents=True, exist_ok=True)
    stop = Stop()
    try:
        sc = load_scenario(settings.scenario)
        port = open_port(settings, out, settings.node)
    except HilError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if settings.rt_priority:
        note = try_realtime_priority(settings.node)
        settings = replace(settings, sched_note=note, rt_event=realtime_event(note))
        say(settings.node, settings.rt_event)
    else:
        settings = replace(settings, sched_note=set_policy(settings.node, settings.sched))
    shell = (PlantShell if settings.node == "plant" else FlightShell)(sc, port, out, settings)
    if settings.telemetry_url:
        from hil.telemetry import Telemetry

        try:
            shell.telemetry = Telemetry(settings.node, settings.telemetry_url,
                                        lc=getattr(port, "lc", None)
                                        if getattr(port, "url", None) == settings.telemetry_url
                                        else None)
        except HilError as exc:
            print(f"error: {exc}", file=sys.stderr)
            port.close()
            return 2
    quiet_gc()
    (out / f"{settings.node}.ready").write_text(str(os.getpid()))
    if settings.start_after and not wait_for_file(Path(settings.start_after), stop):
        port.close()
        return 0
    try:
        run = shell.run_lockstep if settings.mode == "lockstep" else shell.run_realtime
        return run(stop)
    except OutputLost as exc:
        # Disk full, read-only or failing: the node's records end with the last whole line.
        # The plant closes every valve; either node then stops and says why in its exit code.
        if settings.node == "plant":
            shell.plant.close_all_valves(shell.plant.t, manifolds=True)
        say(settings.node, f"output lost, stopping (safe): {exc.strerror}")
        return EXIT_OUTPUT_LOST
    finally:
        port.close()


if __name__ == "__main__":
    sys.exit(main())
