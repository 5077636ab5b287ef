"""In-process lockstep: the plant core and the flight core in one Python process, no bus.

The same tick as the processes' lockstep (``hil/nodes.py``), without sockets: at tick n the
plant integrates to ``t_n``, the newest gyro sample available by then goes through the GYRO
codec (so the flight sees the bus's quantisation and range), the flight computes its tick, the
command goes through the THR_CMD codec and is applied at ``t_n`` plus the configured command
latency, and the plant integrates on. A scenario gives the same detections here as over vcan
in lockstep (the integration tests check both); this path exists to tune and test the cores in
a fraction of the time (``hil sim S.yaml``), and it is what the unit tests of the reference
scenarios run. The verdict is built by ``hil.summary.summarise`` from the same record fields
the processes write.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bus.codec import Gyro, ThrCmd, decode, encode
from hil.config import Scenario, load_scenario
from hil.recorder import newly_active_faults
from hil.summary import summarise

DEG = 180.0 / math.pi
GYRO_RANGE_RAD_S = 0.2  # the GYRO signal's range (bus catalog); the plant shell clips to it


@dataclass
class SimRun:
    """A finished in-process run: per-tick records (the fields ``summarise`` reads) and the
    summary. ``outputs`` keeps every flight ``TickOutput`` and ``truth`` the plant's truth per
    tick when ``keep`` was set."""

    summary: dict[str, Any]
    plant_records: list[dict[str, Any]]
    flight_records: list[dict[str, Any]]
    outputs: list[Any] = field(default_factory=list)
    truth: list[Any] = field(default_factory=list)


def simulate(sc: Scenario | str | Path, *, keep: bool = False,
             on_tick: Callable[[int, Any, Any], None] | None = None) -> SimRun:
    """Run scenario ``sc`` to its end in this process; see the module doc."""
    from flight.attitude import error_quaternion, rotation_angle
    from flight.software import FlightSoftware
    from plant.core import Plant

    if not isinstance(sc, Scenario):
        sc = load_scenario(sc)
    cfg, v = sc.cfg, sc.vehicle
    h = v.timing.tick_s
    plant = Plant(v, seed=cfg.seed, overrides=cfg.plant, initial=cfg.initial)
    for f in cfg.faults:
        if not (f.kind.startswith("bus_") or f.kind == "node_silent"):
            plant.inject(f)
    fs = FlightSoftware(v, target=cfg.target, initial_attitude=cfg.initial.attitude)
    names = plant.arrays.names
    target = cfg.target.quaternion()
    n_ticks = int(round(cfg.duration_s / h))
    reported: set[int] = set()
    plant_recs: list[dict[str, Any]] = []
    flight_recs: list[dict[str, Any]] = []
    outputs, truths = [], []
    gyro: Gyro | None = None
    wall0 = time.perf_counter()
    for n in range(n_ticks):
        t_n = n * h
        plant.advance_to(t_n)
        ready = plant.gyro_samples_until(t_n)
        if ready:
            s = ready[-1]
            rate = np.clip(np.asarray(s.rate_B_rad_s, dtype=float),
                           -GYRO_RANGE_RAD_S, GYRO_RANGE_RAD_S)
            gyro = decode(encode(Gyro(s.seq & 0xFFFF, tuple(float(x) for x in rate),
                                      int(s.status) or 1)))
        omega = np.zeros(3) if gyro is None else np.asarray(gyro.omega_B_rad_s)
        out = fs.step(n, omega)
        mask = sum(1 << m for m, o in enumerate(out.manifold_open) if o)
        cmd = decode(encode(ThrCmd(n, tuple(int(x) // 10 for x in out.on_ms), mask,
                                   gyro.sample_seq if gyro else 0)))
        on_ms = np.asarray(cmd.on_quanta, dtype=float) * 10.0
        man = np.array([(cmd.manifold_enable >> m) & 1 for m in range(len(out.manifold_open))],
                       dtype=bool)
        plant.apply_command(n, plant.apply_time(t_n), on_ms, man)
        plant.advance_to(t_n + h)

        tr = plant.truth
        injected = newly_active_faults(plant.faults.entries, reported, tr.t_s)
        plant_recs.append({
            "tick": n, "t_s": round(tr.t_s, 9), "faults_injected": injected,
            "att_err_deg": float(rotation_angle(error_quaternion(target, tr.q_BO)) * DEG),
            "rate_err_deg_s": float(np.linalg.norm(tr.omega_BO_B_rad_s) * DEG),
            "omega_deg_s": [float(x) * DEG for x in tr.omega_BO_B_rad_s],
            "fuel_kg": float(np.sum(tr.fuel_kg)),
            "dv_B_m_s": [float(x) for x in tr.dv_B_m_s],
        })
        det = None
        if out.detection is not None:
            d = out.detection
            grp = [names[i] for i in d.group]
            det = {"t_s": round(t_n, 6), "tick": n,
                   "thruster": (grp[0] if len(grp) == 1 else grp) if grp else None,
                   "type": d.kind, "source": d.source, "rho": float(d.rho)}
            if d.fraction is not None:
                det["fraction"] = round(float(d.fraction), 4)
            if d.kind == "gyro_fault":
                det["gyro"] = d.names[0]
        flight_recs.append({"tick": n, "t_s": round(t_n, 6), "detection": det})
        if keep:
            outputs.append(out)
            truths.append(tr)
        if on_tick is not None:
            on_tick(n, out, tr)
    wall = time.perf_counter() - wall0
    summary = summarise(
        scenario=cfg.name, vehicle=cfg.vehicle, mode="in-process", plant_records=plant_recs,
        flight_records=flight_recs, expect=cfg.expect,
        extra={"wall_s": round(wall, 3), "sim_s": n_ticks * h,
               "speed_x_realtime": round(n_ticks * h / max(wall, 1e-9), 1),
               "where": "in-process (no bus)"})
    return SimRun(summary, plant_recs, flight_recs, outputs, truths)
