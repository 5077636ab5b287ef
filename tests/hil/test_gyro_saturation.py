"""A craft turning faster than the GYRO frame can carry (+/-0.2 rad/s): the sample is clipped
and flagged ``SATURATED``, and neither it nor the tick after it is thruster evidence.

Oracles: the catalog's range (``bus.catalog.GYRO_RATE_LIMIT_RAD_S``); the plant's truth (the
rate did exceed the range); the closed loop against what the plant was given (no thruster
fault: nothing may be named). Before this, a fault-free kalman_cube run starting at 16 and
-14 deg/s named Z+ failing to fire at 1.2 s (the clipped rate did not move as the thrusters
pushed it), and kalman_cube-gyro run 78 named Z+ after a 9 s freeze had let the craft spin up.
"""

from __future__ import annotations

import uuid

import numpy as np

from bus.catalog import GYRO_RATE_LIMIT_RAD_S, GyroStatus
from hil.binding import gyro_message, over_the_wire, saturated
from hil.config import load_scenario
from hil.node_settings import parse_settings
from hil.sim import simulate
from plant.gyro import GyroSample
from tests.hil.shell_pair import run_lockstep_pair

FAST = ("name: fast\nvehicle: kalman_cube\nduration_s: {d}\nseed: 0\n"
        "initial: {{rate_B_deg_s: [16.0, 0.0, -14.0]}}\n")


def _sample(rate) -> GyroSample:
    return GyroSample(seq=70000, t_meas_s=1.0, t_avail_s=1.0, rate_B_rad_s=tuple(rate),
                      delta_angle_B_rad=None, status=GyroStatus.VALID)


def test_a_rate_beyond_the_frame_is_clipped_and_flagged() -> None:
    over = over_the_wire(gyro_message(_sample([0.3, -0.25, 0.01])))
    # the 1e-7 rad/s quantum of the frame
    assert abs(over.omega_B_rad_s[0] - GYRO_RATE_LIMIT_RAD_S) < 1e-7
    assert abs(over.omega_B_rad_s[1] + GYRO_RATE_LIMIT_RAD_S) < 1e-7
    assert abs(over.omega_B_rad_s[2] - 0.01) < 1e-7
    assert over.status & GyroStatus.SATURATED and over.status & GyroStatus.VALID
    assert saturated(over) and over.sample_seq == 70000 & 0xFFFF
    inside = over_the_wire(gyro_message(_sample([0.2, -0.2, 0.0])))  # at the limit: carried
    assert not saturated(inside) and inside.status == GyroStatus.VALID


def test_in_process_a_fast_start_names_no_thruster(tmp_path) -> None:
    path = tmp_path / "fast.yaml"
    path.write_text(FAST.format(d=30.0))
    r = simulate(path)
    fastest = max(max(abs(x) for x in p["omega_deg_s"]) for p in r.plant_records)
    assert np.radians(fastest) > GYRO_RATE_LIMIT_RAD_S  # the truth went beyond the range
    assert r.summary["detections"] == []


def test_over_the_bus_the_flight_counts_the_clipped_ticks_and_names_nothing(tmp_path) -> None:
    """Both process shells in this process over python-can's ``virtual`` bus, lockstep: the
    flight records the clipped ticks and the event, and names nothing, as in-process."""
    scen = tmp_path / "s.yaml"
    scen.write_text(FAST.format(d=10.0))
    sc = load_scenario(scen)
    channel = f"sat-{uuid.uuid4().hex[:12]}"
    out = tmp_path / "run"
    out.mkdir()

    def settings(node):
        return parse_settings([node, "--scenario", str(scen), "--out", str(out), "--mode",
                               "lockstep", "--interface", "virtual", "--channel", channel])

    _, frecs = run_lockstep_pair(sc, out, settings)
    ticks = [f for f in frecs if "gyro_saturated_ticks" in f]
    assert ticks and 0 < ticks[-1]["gyro_saturated_ticks"] < len(ticks)
    assert ticks[-1]["no_evidence_ticks"] >= ticks[-1]["gyro_saturated_ticks"] + 1
    events = [e for f in frecs for e in f.get("events", [])]
    assert "gyro saturated (GYRO range): no thruster evidence" in events
    assert "gyro back inside its range" in events
    assert not any(f.get("detection") for f in frecs)
