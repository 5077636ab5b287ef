"""Configuration loading: every shipped file loads; broken copies give exact one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from hil.cli import main
from hil.config import (
    SCENARIO_DIR,
    VEHICLE_DIR,
    VehicleArrays,
    load_any,
    load_scenario,
    load_vehicle,
)
from hil.errors import ConfigError

VEHICLES = sorted(VEHICLE_DIR.glob("*.yaml"))
SCENARIOS = sorted(SCENARIO_DIR.glob("*.yaml"))


@pytest.mark.parametrize("path", VEHICLES + SCENARIOS, ids=lambda p: p.name)
def test_every_shipped_file_loads(path: Path) -> None:
    load_any(path)


def _broken_copy(tmp_path: Path, src: str, mutate) -> Path:
    data = yaml.safe_load((VEHICLE_DIR / f"{src}.yaml").read_text())
    mutate(data)
    out = tmp_path / f"{src}.yaml"
    out.write_text(yaml.safe_dump(data))
    return out


def _err(path: Path) -> str:
    with pytest.raises(ConfigError) as info:
        load_vehicle(path)
    text = str(info.value)
    assert "\n" not in text
    return text.split(": ", 1)[1]  # drop the (machine-dependent) file part


@pytest.mark.parametrize(
    ("mutate", "expected"),
    [
        (lambda d: d["thrusters"][3].__setitem__("thrust_n", 0.0),
         "thrusters[3].thrust_n: expected > 0, got 0.0"),
        (lambda d: d["thrusters"][0].__setitem__("direction", [0.0, 0.0, 2.0]),
         "thrusters[0].direction: expected a unit vector (norm 1 within 1e-3), norm is 2, "
         "got [0.0, 0.0, 2.0]"),
        (lambda d: d["thrusters"][1].__setitem__("manifold", "B"),
         "thrusters[1].manifold: expected one of ['main'], got 'B'"),
        (lambda d: d["thrusters"][2].__setitem__("name", "X+"),
         "thrusters[2].name: expected a unique thruster name, got 'X+'"),
        (lambda d: d.__setitem__("mass_kg", "heavy"), "mass_kg: expected a number, got 'heavy'"),
        (lambda d: d.pop("mass_kg"),
         "mass_kg: expected this field (it is required), got nothing"),
        (lambda d: d.__setitem__("colour", "red"),
         "colour: expected no such field (unknown key), got 'red'"),
        (lambda d: d["inertia_B_kg_m2"][0].__setitem__(1, 5.0),
         "inertia_B_kg_m2: expected a symmetric 3x3 matrix, got [[1000.0, 5.0, 0.0], "
         "[0.0, 1200.0, 0.0], [0.0, 0.0, 1400.0]]"),
        (lambda d: d["flight"]["controller"].__setitem__("law", "bang_bang"),
         "flight.controller.law: expected one of 'phase_plane' or 's_law', got 'bang_bang'"),
    ],
)
def test_broken_vehicle_gives_one_line_error(tmp_path, mutate, expected) -> None:
    assert _err(_broken_copy(tmp_path, "generic", mutate)) == expected


def test_bad_yaml_and_missing_file(tmp_path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("name: [unclosed\n")
    with pytest.raises(ConfigError, match=r"line \d+: expected valid YAML"):
        load_vehicle(p)
    with pytest.raises(ConfigError, match="expected an existing file, got no such file"):
        load_vehicle(tmp_path / "nope.yaml")


def _scenario(tmp_path: Path, body: dict) -> Path:
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump({"name": "t", "vehicle": "generic", "duration_s": 10.0, **body}))
    return p


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        ({"faults": [{"kind": "stuck_on", "t_s": 1.0, "thruster": "X9"}]},
         "faults[0].thruster: expected a thruster of vehicle generic, got 'X9'"),
        ({"faults": [{"kind": "stuck_on", "t_s": -1.0, "thruster": "X+"}]},
         "faults[0].t_s: expected >= 0, got -1.0"),
        ({"faults": [{"kind": "stuck_on", "t_s": 1.0, "thruster": "X+", "fraction": 1.5}]},
         "faults[0].fraction: expected <= 1, got 1.5"),
        ({"faults": [{"kind": "melted", "t_s": 1.0}]},
         "faults[0].kind: expected one of 'stuck_on', 'fail_to_fire', 'degraded', 'gyro_spike', "
         "'gyro_bias_step', 'gyro_frozen', 'gyro_noise', 'bus_drop', 'bus_delay', "
         "'bus_corrupt', 'node_silent' or 'bus_babble', got 'melted'"),
        ({"faults": [{"kind": "degraded", "t_s": 1.0, "thruster": "X+"}]},
         "faults[0].fraction: expected a thrust fraction in [0, 1] for a degraded fault, got None"),
        ({"faults": [{"kind": "fail_to_fire", "t_s": 5.0, "clear_t_s": 2.0, "thruster": "X+"}]},
         "faults[0].clear_t_s: expected a time after t_s=5.0, got 2.0"),
        ({"flight": {"detector": {"forgetting_on": 1.0}}},
         "flight.detector.forgetting_on: expected < 1, got 1.0"),
        ({"vehicle": "nosuch"},
         "vehicle: expected a vehicle name or YAML path that exists, got 'nosuch'"),
    ],
)
def test_broken_scenario_gives_one_line_error(tmp_path, body, expected) -> None:
    with pytest.raises(ConfigError) as info:
        load_scenario(_scenario(tmp_path, body))
    assert str(info.value).split(": ", 1)[1] == expected


def test_scenario_flight_override_reaches_vehicle(tmp_path) -> None:
    s = load_scenario(_scenario(tmp_path, {"flight": {"observer": {"kind": "rigid"}}}))
    assert s.vehicle.flight.observer.kind == "rigid"
    assert s.vehicle.flight.controller.rate_deadband_deg_s == 0.12


def test_vehicle_arrays_match_hand_computation() -> None:
    v = load_vehicle("generic")
    a = VehicleArrays.from_vehicle(v)
    # X+ at (0, 1, 0) pushing +z: torque (1, 0, 0) * 10 N about x, J_xx = 1000.
    assert np.allclose(a.mu_B_rad_s2[0], [0.01, 0.0, 0.0])
    assert np.allclose(a.mdot_kg_s[0], 10.0 / (290.0 * 9.80665))


def test_cli_config_check(capsys, tmp_path) -> None:
    assert main(["config", "check", str(VEHICLE_DIR / "generic.yaml")]) == 0
    assert "vehicle generic, 6 thrusters" in capsys.readouterr().out
    bad = _broken_copy(tmp_path, "generic", lambda d: d.__setitem__("mass_kg", -1))
    assert main(["config", "check", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and err.endswith("mass_kg: expected > 0, got -1")
    assert len(err.splitlines()) == 1
