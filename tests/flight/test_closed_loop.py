"""Closed loop in plain Python (flight core + plant core), seed 000's two cases on `generic`.

Seed 000: start 22.5 deg about X; X+ stuck on at 18.0 s (entering the dead zone), detected
4.6 s later; an X thruster fails to fire at 12.4 s (leaving the dead zone), detected 4.6 s later.
We require the right thruster and type within 4.6 s and no detection before the fault.
"""

from __future__ import annotations

import numpy as np
import pytest

from flight.software import FlightSoftware
from hil.config import AttitudeCfg, FaultSpec, InitialCfg, load_vehicle
from plant.core import Plant

SEED_LATENCY_S = 4.6


def _run(fault: FaultSpec | None, duration_s: float, seed: int = 1, vehicle: str = "generic",
         init: InitialCfg | None = None):
    v = load_vehicle(vehicle)
    init = init or InitialCfg(attitude=AttitudeCfg(axis=(1, 0, 0), angle_deg=22.5))
    plant = Plant(v, seed=seed, initial=init)
    fs = FlightSoftware(v, initial_attitude=init.attitude)
    if fault is not None:
        plant.inject(fault)
    h = v.timing.tick_s
    outs = []
    for n in range(int(round(duration_s / h)) + 1):
        t = n * h
        plant.advance_to(t)
        sample = plant.gyro_samples_until(t)[-1]
        out = fs.step(n, np.array(sample.rate_B_rad_s))
        plant.apply_command(n, plant.apply_time(t), out.on_ms, out.manifold_open)
        outs.append(out)
    return outs


def _detections(outs, h=0.2):
    return [(o.tick * h, o.detection) for o in outs if o.detection is not None]


@pytest.mark.parametrize("seed", [1, 2])
def test_no_false_alarm_without_fault(seed: int) -> None:
    outs = _run(None, 60.0, seed)
    assert _detections(outs) == []
    assert abs(np.degrees(outs[-1].att_err_rad)).max() < 1.5


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_s000_stuck_on_x_plus(seed: int) -> None:
    outs = _run(FaultSpec(kind="stuck_on", t_s=18.0, thruster="X+"), 24.0, seed)
    dets = _detections(outs)
    assert dets, "not detected"
    t, det = dets[0]
    assert (det.names, det.kind) == (("X+",), "stuck_on")
    assert 18.0 < t <= 18.0 + SEED_LATENCY_S


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_s000_fail_to_fire_of_the_x_thruster_commanded_at_12_4_s(seed: int) -> None:
    clean = _run(None, 12.4, seed)
    fired = [n for n, on in zip(("X+", "X-"), clean[-1].on_ms[:2], strict=True) if on > 0]
    name = fired[0] if fired else "X+"
    outs = _run(FaultSpec(kind="fail_to_fire", t_s=12.4, thruster=name), 18.0, seed)
    dets = _detections(outs)
    assert dets, "not detected"
    t, det = dets[0]
    assert (det.names, det.kind) == ((name,), "fail_to_fire")
    assert 12.4 < t <= 12.4 + SEED_LATENCY_S


def test_kalman_cube_runs_without_false_alarm() -> None:
    init = InitialCfg(rate_B_deg_s=(3.0, 0.0, 0.0))
    outs = _run(None, 60.0, 1, "kalman_cube", init)
    assert _detections(outs) == []
