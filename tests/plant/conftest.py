"""Vehicles built in code for the plant tests (independent of the YAML files in configs/)."""

from __future__ import annotations

import pytest

from hil.config import VehicleCfg


def make_vehicle(**over) -> VehicleCfg:
    """Six thrusters on two manifolds, no orbit, no noise: a clean test article.

    Thruster k applies a force of 10 N at a 1 m lever arm, so each gives 10 N m about one
    body axis (A = manifold A: X+, Y+, Z+; B: X-, Y-, Z-).
    """
    data = {
        "name": "testcraft",
        "mass_kg": 500.0,
        "inertia_B_kg_m2": [[100.0, 0.0, 0.0], [0.0, 200.0, 0.0], [0.0, 0.0, 300.0]],
        "orbit": {"rate_rad_s": 0.0, "gravity_gradient": False},
        "gyro": {"noise_std_rad_s": 0.0, "rate_hz": 5.0},
        "manifolds": ["A", "B"],
        "thrusters": [
            {"name": "X+", "position_m": [0, 1, 0], "direction": [0, 0, 1], "thrust_n": 10.0,
             "manifold": "A"},
            {"name": "X-", "position_m": [0, 1, 0], "direction": [0, 0, -1], "thrust_n": 10.0,
             "manifold": "B"},
            {"name": "Y+", "position_m": [0, 0, 1], "direction": [1, 0, 0], "thrust_n": 10.0,
             "manifold": "A"},
            {"name": "Y-", "position_m": [0, 0, 1], "direction": [-1, 0, 0], "thrust_n": 10.0,
             "manifold": "B"},
            {"name": "Z+", "position_m": [1, 0, 0], "direction": [0, 1, 0], "thrust_n": 10.0,
             "manifold": "A"},
            {"name": "Z-", "position_m": [1, 0, 0], "direction": [0, -1, 0], "thrust_n": 10.0,
             "manifold": "B"},
        ],
    }
    data.update(over)
    return VehicleCfg.model_validate(data)


@pytest.fixture
def vehicle() -> VehicleCfg:
    return make_vehicle()
