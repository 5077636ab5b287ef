"""Both process shells in the test's process over python-can's ``virtual`` bus, lockstep: the
plant in the test's thread, the flight in another (the tests of the loop share this runner)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path

from hil.flight_shell import FlightShell
from hil.node_shell import open_port
from hil.plant_shell import PlantShell
from hil.recorder import read_jsonl


def run_lockstep_pair(sc, out: Path, settings: Callable[[str], object],
                      attacker: Callable | None = None, channel: str | None = None
                      ) -> tuple[list, list]:
    """Run scenario ``sc`` to its end; ``settings(node)`` the parsed node settings of
    ``"plant"`` and ``"flight"``; ``attacker(channel, done)`` an optional third node on its own
    thread. Returns the plant's and the flight's records."""
    fs = settings("flight")
    flight = FlightShell(sc, open_port(fs, out, "flight"), out, fs)
    ps = settings("plant")
    plant = PlantShell(sc, open_port(ps, out, "plant"), out, ps)
    done = threading.Event()
    th = threading.Thread(target=flight.run_lockstep, args=(done.is_set,), daemon=True)
    th.start()
    if attacker is not None:
        threading.Thread(target=attacker, args=(channel, done), daemon=True).start()
    try:
        plant.run_lockstep(lambda: False)
    finally:
        done.set()
        th.join(10)
        plant.port.close()
        flight.port.close()
    return list(read_jsonl(out / "plant.jsonl")), list(read_jsonl(out / "flight.jsonl"))
