"""In-process lockstep: the plant core and the flight core in one Python process, no bus.

The same tick as the processes' lockstep (``hil.plant_shell``, ``hil.flight_shell``), without
sockets: at tick n the plant integrates to ``t_n``, the newest gyro sample available by then goes
through the GYRO codec (so the flight sees the bus's quantisation and range), the flight computes
its tick, the command goes through the THR_CMD codec (both conversions are the process shells'
own, ``hil.binding``) and is applied at ``t_n`` plus the configured command latency, and the
plant integrates on. A scenario gives the same detections here as over vcan
in lockstep (the integration tests check both); this path exists to tune and test the cores in
a fraction of the time (``hil sim S.yaml``), and it is what the unit tests of the reference
scenarios run. The verdict is built by ``hil.summary.summarise`` from the same record fields
the processes write.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bus.codec import Gyro
from common.scenario import target_at
from common.units import DEG
from hil.binding import gyro_message, over_the_wire, plant_command, saturated, thr_cmd
from hil.config import Scenario, load_scenario
from hil.records import detection_record, newly_active_faults, truth_fields
from hil.summary import summarise


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
             on_tick: Callable[[int, Any, Any], None] | None = None,
             actuation_phase_s: float = 0.0) -> SimRun:
    """Run scenario ``sc`` to its end in this process; see the module doc.

    ``actuation_phase_s``: every command takes effect that much later than in lockstep, as in
    real time (``NodeSettings.actuation_phase_s``): the plant applies THR_CMD(n) at ``t_n``
    plus the command latency plus the phase, and the flight is built as its real-time shell
    builds it (onboard model and controller lead told of the phase), so a real-time run's
    actuation timing can be reproduced bit for bit in this process."""
    from flight.attitude import error_quaternion
    from hil.flight_shell import flight_software
    from plant.core import Plant

    if not isinstance(sc, Scenario):
        sc = load_scenario(sc)
    cfg, v = sc.cfg, sc.vehicle
    h = v.timing.tick_s
    phase = float(actuation_phase_s)
    if not 0.0 <= phase < h:
        raise ValueError(f"simulate: actuation_phase_s: expected 0 <= s < the tick {h}, "
                         f"got {actuation_phase_s}")
    plant = Plant(v, seed=cfg.seed, overrides=cfg.plant, initial=cfg.initial)
    for f in cfg.faults:
        if not (f.kind.startswith("bus_") or f.kind == "node_silent"):
            plant.inject(f)
    fs = flight_software(sc, phase)
    names = plant.arrays.names
    target = cfg.target.quaternion()
    programme = cfg.programme_ticks(h)
    n_ticks = int(round(cfg.duration_s / h))
    reported: set[int] = set()
    plant_recs: list[dict[str, Any]] = []
    flight_recs: list[dict[str, Any]] = []
    outputs, truths = [], []
    gyro: Gyro | None = None
    sat_prev = False
    wall0 = time.perf_counter()
    for n in range(n_ticks):
        t_n = n * h
        plant.advance_to(t_n)
        ready = plant.gyro_samples_until(t_n)
        if ready:
            gyro = over_the_wire(gyro_message(ready[-1]))
        omega = np.zeros(3) if gyro is None else np.asarray(gyro.omega_B_rad_s)
        # A clipped sample, or the first after one, is no evidence about the thrusters (the
        # flight shell does the same from the sample's status).
        sat = saturated(gyro)
        out = fs.step(n, omega, evidence=not (sat or sat_prev))
        sat_prev = sat
        cmd = over_the_wire(thr_cmd(n, out, gyro.sample_seq if gyro else 0))
        on_ms, man = plant_command(cmd, len(out.manifold_open))
        plant.apply_command(n, plant.apply_time(t_n) + phase, on_ms, man)
        plant.advance_to(t_n + h)

        tr = plant.truth
        injected = newly_active_faults(plant.faults.entries, reported, tr.t_s)
        plant_recs.append({
            "tick": n, "t_s": round(tr.t_s, 9), "faults_injected": injected,
            **truth_fields(tr, error_quaternion(target_at(target, programme, n), tr.q_BO)),
            "omega_deg_s": [float(x) * DEG for x in tr.omega_BO_B_rad_s],
        })
        det = (None if out.detection is None
               else detection_record(out.detection, n, h, names))
        rec: dict[str, Any] = {"tick": n, "t_s": round(t_n, 6), "detection": det}
        if fs.detector.cfg.pulse_test_below is not None:
            rec["pulse_tests"] = dict(fs.pulse_tests)
        flight_recs.append(rec)
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
               "where": "in-process (no bus)"}, expected_ticks=n_ticks)
    return SimRun(summary, plant_recs, flight_recs, outputs, truths)
