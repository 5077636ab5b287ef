"""Thruster and manifold faults, fault validation (docs/design.md 5.5, 5.6)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_vehicle

from hil.config import FaultSpec, PlantOverridesCfg, ThrustProfileCfg
from hil.errors import FaultCommandError
from plant.core import Plant
from plant.faults import validate_fault
from plant.thruster import ThrustProfile

P_N = 10.0
PROF = ThrustProfile.calibrate(ThrustProfileCfg())


def _fire(plant: Plant, j: int, on_ms: int, ticks: range) -> None:
    for n in ticks:
        on = np.zeros(6)
        on[j] = on_ms
        plant.apply_command(n, n * 0.2, on)


def test_stuck_on_keeps_thrusting_and_manifold_closure_stops_it() -> None:
    plant = Plant(make_vehicle(), step_s=0.01)
    _fire(plant, 0, 100, range(0, 3))
    plant.inject(FaultSpec(kind="stuck_on", t_s=0.05, thruster="X+"))
    plant.apply_command(3, 0.6, np.zeros(6))
    plant.advance_to(2.0)
    assert plant.thrust_now_n()[0] == pytest.approx(P_N, rel=1e-12)  # commanded off, still lit
    i0 = plant.truth.impulse_Ns[0]
    plant.advance_to(3.0)
    assert plant.truth.impulse_Ns[0] - i0 == pytest.approx(P_N * 1.0, rel=1e-9)
    # Close manifold A (X+ is on it) at 3.0 s: same decay as an off command.
    plant.apply_command(4, 3.0, np.zeros(6), manifold_open=np.array([False, True]))
    plant.advance_to(3.0 + PROF.decay_time_s(0.01))
    assert plant.thrust_now_n()[0] == pytest.approx(0.01 * P_N, rel=1e-9)
    i1 = plant.truth.impulse_Ns[0]
    plant.advance_to(6.0)
    assert plant.thrust_now_n()[0] < 1e-6
    # Added area after the closure = P tau_off (within the tail below 0.01 P).
    tail_total = plant.truth.impulse_Ns[0] - i0 - P_N * 1.0
    assert tail_total == pytest.approx(P_N * 0.027, abs=P_N * 0.0002)
    assert i1 > i0


def test_partial_leak_gives_fraction_of_thrust() -> None:
    plant = Plant(make_vehicle(), step_s=0.01)
    plant.inject(FaultSpec(kind="stuck_on", t_s=1.0, thruster="Y-", fraction=0.15))
    plant.advance_to(3.0)
    assert plant.thrust_now_n()[3] == pytest.approx(0.15 * P_N, rel=1e-9)
    i0 = plant.truth.impulse_Ns[3]
    plant.advance_to(5.0)
    assert plant.truth.impulse_Ns[3] - i0 == pytest.approx(0.15 * P_N * 2.0, rel=1e-9)
    # Commanded on it gives full thrust; commanded off it returns to the leak.
    _fire(plant, 3, 200, range(25, 27))
    plant.apply_command(27, 5.4, np.zeros(6))
    plant.advance_to(5.35)
    assert plant.thrust_now_n()[3] == pytest.approx(P_N, rel=1e-6)
    plant.advance_to(8.0)
    assert plant.thrust_now_n()[3] == pytest.approx(0.15 * P_N, rel=1e-9)
    # Clearing the fault lets it decay to zero.
    plant.clear_faults("Y-")
    plant.advance_to(10.0)
    assert plant.thrust_now_n()[3] < 1e-9


def test_fail_to_fire_gives_no_impulse() -> None:
    plant = Plant(make_vehicle(), step_s=0.01)
    plant.inject({"kind": "fail_to_fire", "t_s": 0.0, "thruster": "Z+"})
    _fire(plant, 4, 150, range(0, 10))
    plant.apply_command(10, 2.0, np.zeros(6))
    plant.advance_to(3.0)
    assert plant.truth.impulse_Ns[4] == 0.0
    assert plant.truth.fuel_kg[4] == 0.0


def test_degraded_fraction_scales_impulse() -> None:
    a = Plant(make_vehicle(), step_s=0.01)
    b = Plant(make_vehicle(), step_s=0.01)
    b.inject(FaultSpec(kind="degraded", t_s=0.0, thruster="X-", fraction=0.4))
    for p in (a, b):
        _fire(p, 1, 120, range(0, 5))
        p.apply_command(5, 1.0, np.zeros(6))
        p.advance_to(3.0)
    assert b.truth.impulse_Ns[1] == pytest.approx(0.4 * a.truth.impulse_Ns[1], rel=1e-12)


def test_thrust_scale_override() -> None:
    ov = PlantOverridesCfg(thrust_scale=0.85, thrust_scale_per_thruster={"X+": 0.5})
    a = Plant(make_vehicle(), step_s=0.01)
    b = Plant(make_vehicle(), step_s=0.01, overrides=ov)
    for p in (a, b):
        p.apply_command(0, 0.0, np.array([100, 100, 0, 0, 0, 0]))
        p.apply_command(1, 0.2, np.zeros(6))
        p.advance_to(2.0)
    assert b.truth.impulse_Ns[0] == pytest.approx(0.85 * 0.5 * a.truth.impulse_Ns[0], rel=1e-12)
    assert b.truth.impulse_Ns[1] == pytest.approx(0.85 * a.truth.impulse_Ns[1], rel=1e-12)


def test_direction_error_is_exact_angle_and_seeded() -> None:
    ov = PlantOverridesCfg(direction_error_deg=2.0)
    a = Plant(make_vehicle(), seed=5, overrides=ov)
    b = Plant(make_vehicle(), seed=5, overrides=ov)
    c = Plant(make_vehicle(), seed=6, overrides=ov)
    cosang = np.sum(a.d_actual_B * a.arrays.d_B, axis=1)
    assert np.degrees(np.arccos(np.clip(cosang, -1, 1))) == pytest.approx(np.full(6, 2.0))
    assert np.array_equal(a.d_actual_B, b.d_actual_B)
    assert not np.array_equal(a.d_actual_B, c.d_actual_B)


def test_close_all_valves() -> None:
    plant = Plant(make_vehicle(), step_s=0.01)
    plant.apply_command(0, 0.0, np.full(6, 200))
    plant.close_all_valves(0.1)
    plant.advance_to(2.0)
    assert np.allclose(plant.truth.impulse_Ns, P_N * PROF.pulse_impulse_s(0.1), rtol=1e-9)


@pytest.mark.parametrize("raw, text", [
    ({"kind": "stuck_on", "t_s": 1.0, "thruster": "X9"},
     "fault: thruster: expected one of ['X+', 'X-', 'Y+', 'Y-', 'Z+', 'Z-'], got 'X9'"),
    ({"kind": "stuck_on", "t_s": 1.0, "thruster": "X+", "fraction": 1.5},
     "fault: fraction: expected a fraction in [0, 1], got 1.5"),
    ({"kind": "degraded", "t_s": 1.0, "thruster": "X+", "fraction": -0.1},
     "fault: fraction: expected a fraction in [0, 1], got -0.1"),
    ({"kind": "fail_to_fire", "t_s": -2.0, "thruster": "X+"},
     "fault: t_s: expected >= 0, got -2.0"),
    ({"kind": "melt", "t_s": 1.0, "thruster": "X+"},
     "fault: kind: expected one of 'stuck_on', 'fail_to_fire', 'degraded', 'gyro_spike', "
     "'gyro_bias_step', 'gyro_frozen', 'gyro_noise', 'bus_drop', 'bus_delay', 'bus_corrupt', "
     "'node_silent' or 'bus_babble', got 'melt'"),
    ({"kind": "stuck_on", "t_s": 1.0},
     "fault: thruster: expected a thruster name for a stuck_on fault, got None"),
])
def test_invalid_faults_rejected_with_exact_text(raw: dict, text: str) -> None:
    plant = Plant(make_vehicle())
    with pytest.raises(FaultCommandError) as exc:
        plant.inject(raw)
    assert str(exc.value) == text


def test_validate_accepts_spec_and_unknown_clear() -> None:
    v = make_vehicle()
    spec = FaultSpec(kind="gyro_spike", t_s=1.0, magnitude_rad_s=0.01, axis=1)
    assert validate_fault(v, spec) is spec
    plant = Plant(v)
    with pytest.raises(FaultCommandError, match=r"^fault: thruster: expected one of .*got 'Q'$"):
        plant.clear_faults("Q")


def test_bus_faults_are_kept_without_physics() -> None:
    plant = Plant(make_vehicle(), step_s=0.01)
    ref = Plant(make_vehicle(), step_s=0.01)
    plant.inject(FaultSpec(kind="bus_drop", t_s=0.5, node="flight", probability=0.5))
    for p in (plant, ref):
        p.apply_command(0, 0.0, np.array([100, 0, 50, 0, 0, 0]))
        p.advance_to(1.0)
    assert [f.kind for f in plant.faults.active_bus_faults(1.0)] == ["bus_drop"]
    assert np.array_equal(plant.truth.omega_B_rad_s, ref.truth.omega_B_rad_s)
    assert [f.kind for f in plant.truth.faults] == ["bus_drop"]
