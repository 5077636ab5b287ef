"""Broken copies of every shipped vehicle and of several shipped scenarios (docs/style.md habit 5).

Each copy is the shipped YAML with one mutation. ``hil config check COPY`` must exit 2 and
print exactly one line on stderr, ``error: <file>: <field path>: expected ..., got <value>``,
naming the copy, the path of the broken field and the bad value (nothing on stdout). The
mutations are written against the structure of each file (the index of a thruster in the
middle, the last one...), so a message that names the wrong list element fails.
"""

from __future__ import annotations

import copy
import functools
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from hil.cli import main
from hil.config import SCENARIO_DIR, VEHICLE_DIR

VEHICLES = sorted(p.stem for p in VEHICLE_DIR.glob("*.yaml"))
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # libyaml when present: faster

# A mutation edits the loaded data in place and returns (field path, bad value as printed).
Mutation = Callable[[dict[str, Any]], tuple[str, str]]


def _negative_thrust(d: dict) -> tuple[str, str]:
    k = len(d["thrusters"]) // 2
    d["thrusters"][k]["thrust_n"] = -abs(d["thrusters"][k]["thrust_n"])
    return f"thrusters[{k}].thrust_n", repr(d["thrusters"][k]["thrust_n"])


def _unknown_manifold(d: dict) -> tuple[str, str]:
    k = len(d["thrusters"]) - 1
    d["thrusters"][k]["manifold"] = "NO_SUCH_MANIFOLD"
    return f"thrusters[{k}].manifold", "'NO_SUCH_MANIFOLD'"


def _missing_position(d: dict) -> tuple[str, str]:
    del d["thrusters"][1]["position_m"]
    return "thrusters[1].position_m", "nothing"


def _missing_mass(d: dict) -> tuple[str, str]:
    del d["mass_kg"]
    return "mass_kg", "nothing"


def _gyro_rate_wrong_type(d: dict) -> tuple[str, str]:
    d.setdefault("gyro", {})["rate_hz"] = "fast"
    return "gyro.rate_hz", "'fast'"


def _manifolds_not_a_list(d: dict) -> tuple[str, str]:
    d["manifolds"] = d["manifolds"][0]
    return "manifolds", repr(d["manifolds"])


def _negative_gyro_noise(d: dict) -> tuple[str, str]:
    d.setdefault("gyro", {})["noise_std_rad_s"] = -2.0e-5
    return "gyro.noise_std_rad_s", "-2e-05"


def _unknown_thruster_key(d: dict) -> tuple[str, str]:
    k = len(d["thrusters"]) - 2
    d["thrusters"][k]["thrust_newtons"] = 100.0
    return f"thrusters[{k}].thrust_newtons", "100.0"


def _duplicate_name(d: dict) -> tuple[str, str]:
    d["thrusters"][2]["name"] = d["thrusters"][0]["name"]
    return "thrusters[2].name", repr(d["thrusters"][0]["name"])


def _long_direction(d: dict) -> tuple[str, str]:
    d["thrusters"][0]["direction"] = [0.0, 2.0, 0.0]
    return "thrusters[0].direction", "[0.0, 2.0, 0.0]"


def _negative_disturbance_std(d: dict) -> tuple[str, str]:
    d.setdefault("disturbance", {})["random_torque_std_Nm"] = -0.5
    return "disturbance.random_torque_std_Nm", "-0.5"


COMMON: dict[str, Mutation] = {
    "negative-thrust": _negative_thrust,
    "unknown-manifold": _unknown_manifold,
    "missing-position": _missing_position,
    "missing-mass": _missing_mass,
    "gyro-rate-type": _gyro_rate_wrong_type,
    "manifolds-type": _manifolds_not_a_list,
    "gyro-noise-negative": _negative_gyro_noise,
    "unknown-key": _unknown_thruster_key,
    "duplicate-name": _duplicate_name,
    "direction-norm": _long_direction,
    "disturbance-negative": _negative_disturbance_std,
}


def _flex_unknown_thruster(d: dict) -> tuple[str, str]:
    k = len(d["flex_modes"]) - 1
    d["flex_modes"][k].setdefault("thrusters", {})["DPO99"] = {"f": [0.0, 0.0, 0.0]}
    return f"flex_modes[{k}].thrusters", "'DPO99'"


def _flex_zero_frequency(d: dict) -> tuple[str, str]:
    d["flex_modes"][0]["freq_hz"] = 0.0
    return "flex_modes[0].freq_hz", "0.0"


def _roll_pair_unknown(d: dict) -> tuple[str, str]:
    d["flight"]["allocator"]["roll_pairs"][1] = ["17", "99"]
    return "flight.allocator.roll_pairs[1]", "'99'"


SPECIFIC: list[tuple[str, str, Mutation]] = [
    ("orel", "flex-unknown-thruster", _flex_unknown_thruster),
    ("iss_rs", "flex-unknown-thruster", _flex_unknown_thruster),
    ("orel", "flex-zero-frequency", _flex_zero_frequency),
    ("iss_rs", "flex-zero-frequency", _flex_zero_frequency),
    ("orel", "roll-pair-unknown", _roll_pair_unknown),
]


@functools.cache
def _shipped(src: Path) -> dict[str, Any]:
    return yaml.safe_load(src.read_text())


def _write_copy(tmp_path: Path, src: Path, tag: str, mutate: Mutation) -> tuple[Path, str, str]:
    data = copy.deepcopy(_shipped(src))
    field, bad = mutate(data)
    out = tmp_path / f"{src.stem}-{tag}.yaml"
    out.write_text(yaml.dump(data, Dumper=_DUMPER, sort_keys=False))
    return out, field, bad


def _check_one_line(capsys, broken: Path, field: str, bad: str) -> str:
    """Run ``hil config check COPY``: exit 2, one stderr line naming file, field and value."""
    rc = main(["config", "check", str(broken)])
    cap = capsys.readouterr()
    assert rc == 2, cap.out
    assert cap.out == ""
    lines = cap.err.splitlines()
    assert len(lines) == 1, cap.err
    line = lines[0]
    assert line.startswith("error: ")
    shown_file, rest = line[len("error: "):].split(": ", 1)
    assert Path(shown_file).resolve() == broken.resolve()  # names the broken copy itself
    assert rest.startswith(f"{field}: expected "), line
    assert line.endswith(f", got {bad}"), line
    return rest


@pytest.mark.parametrize("tag", sorted(COMMON))
@pytest.mark.parametrize("vehicle", VEHICLES)
def test_broken_vehicle_copy_gives_one_line(capsys, tmp_path, vehicle: str, tag: str) -> None:
    broken, field, bad = _write_copy(tmp_path, VEHICLE_DIR / f"{vehicle}.yaml", tag, COMMON[tag])
    _check_one_line(capsys, broken, field, bad)


@pytest.mark.parametrize("vehicle, tag, mutate", SPECIFIC, ids=[f"{v}-{t}" for v, t, _ in SPECIFIC])
def test_broken_vehicle_specific_sections(capsys, tmp_path, vehicle, tag, mutate) -> None:
    broken, field, bad = _write_copy(tmp_path, VEHICLE_DIR / f"{vehicle}.yaml", tag, mutate)
    _check_one_line(capsys, broken, field, bad)


def test_every_shipped_vehicle_is_covered() -> None:
    """The parametrisation above runs on every file in configs/vehicles (and they are 4)."""
    assert VEHICLES == ["generic", "iss_rs", "kalman_cube", "orel"]


# --------------------------------------------------------------------------- scenarios


def _fault_thruster(name: str) -> Mutation:
    def m(d: dict) -> tuple[str, str]:
        d["faults"][0]["thruster"] = name
        return "faults[0].thruster", repr(name)
    return m


def _fault_field(key: str, value: Any) -> Mutation:
    def m(d: dict) -> tuple[str, str]:
        d["faults"][0][key] = value
        return f"faults[0].{key}", repr(value)
    return m


def _top(key: str, value: Any) -> Mutation:
    def m(d: dict) -> tuple[str, str]:
        d[key] = value
        return key, repr(value)
    return m


def _drop_name(d: dict) -> tuple[str, str]:
    del d["name"]
    return "name", "nothing"


def _burn_unknown(d: dict) -> tuple[str, str]:
    d["flight"]["orbit_correction"]["burn"][2] = "99"
    return "flight.orbit_correction.burn[2]", "'99'"


def _scale_unknown(d: dict) -> tuple[str, str]:
    d["plant"]["thrust_scale_per_thruster"] = {"SM+yaw_IX": 0.9}
    return "plant.thrust_scale_per_thruster", "'SM+yaw_IX'"


def _detection_unknown(d: dict) -> tuple[str, str]:
    d["expect"]["detections"][0]["thruster"] = "SM-yaw_III"
    return "expect.detections[0].thruster", "'SM-yaw_III'"


SCENARIO_CASES: list[tuple[str, str, Mutation]] = [
    ("S000-stuck", "fault-unknown-thruster", _fault_thruster("X9")),
    ("REC-stuck", "fault-unknown-thruster", _fault_thruster("31")),
    ("S003-progress", "fault-unknown-thruster", _fault_thruster("P3+roll_I")),
    ("S003-progress", "fault-fraction", _fault_field("fraction", 1.5)),
    ("S002-15", "fault-negative-time", _fault_field("t_s", -3.0)),
    ("REC-nofire", "fault-kind", _fault_field("kind", "explode")),
    ("S002-50", "duration-type", _top("duration_s", "long")),
    ("S000-nofire", "missing-name", _drop_name),
    ("S004-cart+x", "unknown-vehicle", _top("vehicle", "nosuch")),
    ("S004-polar", "burn-unknown-thruster", _burn_unknown),
    ("S003-flex", "scale-unknown-thruster", _scale_unknown),
    ("S003-sm", "detection-unknown-thruster", _detection_unknown),
]


@pytest.mark.parametrize("scenario, tag, mutate", SCENARIO_CASES,
                         ids=[f"{s}-{t}" for s, t, _ in SCENARIO_CASES])
def test_broken_scenario_copy_gives_one_line(capsys, tmp_path, scenario, tag, mutate) -> None:
    broken, field, bad = _write_copy(tmp_path, SCENARIO_DIR / f"{scenario}.yaml", tag, mutate)
    _check_one_line(capsys, broken, field, bad)


def test_one_bad_file_among_good_ones(capsys, tmp_path) -> None:
    """Several files: each good one gets its ``ok:`` line, the bad one its single error line,
    and the exit code is 2."""
    broken, field, bad = _write_copy(tmp_path, VEHICLE_DIR / "orel.yaml", "neg", _negative_thrust)
    good = [VEHICLE_DIR / "generic.yaml", SCENARIO_DIR / "S000-stuck.yaml"]
    rc = main(["config", "check", str(good[0]), str(broken), str(good[1])])
    cap = capsys.readouterr()
    assert rc == 2
    assert len(cap.out.splitlines()) == 2 and all(ln.startswith("ok: ")
                                                  for ln in cap.out.splitlines())
    assert len(cap.err.splitlines()) == 1
    assert f": {field}: expected > 0, got {bad}" in cap.err


# --------------------------------------------------------------------------- known gaps


def _infinite_thrust(d: dict) -> tuple[str, str]:
    d["thrusters"][0]["thrust_n"] = math.inf
    return "thrusters[0].thrust_n", "inf"


def _non_oscillatory_mode(d: dict) -> tuple[str, str]:
    # delta >= 2 pi makes sigma = delta lambda >= W = 2 pi lambda: no ringing at all, and
    # plant.flex.transition raises ValueError (a traceback) at the first step.
    d["flex_modes"][0]["log_decrement"] = 7.0
    return "flex_modes[0].log_decrement", "7.0"


def _on_lag_below_delay(d: dict) -> tuple[str, str]:
    # ThrustProfile.calibrate rejects this, but only when a Plant is built, not on load.
    d.setdefault("thrust_profile", {})["on_lag_ms"] = 8.0
    return "thrust_profile.on_lag_ms", "8.0"


def _scenario_without_vehicle(d: dict) -> tuple[str, str]:
    del d["vehicle"]
    return "vehicle", "nothing"


def test_infinite_thrust_is_rejected(capsys, tmp_path) -> None:
    broken, field, bad = _write_copy(tmp_path, VEHICLE_DIR / "orel.yaml", "inf", _infinite_thrust)
    _check_one_line(capsys, broken, field, bad)


def test_non_oscillatory_flex_mode_is_rejected_on_load(capsys, tmp_path) -> None:
    broken, field, bad = _write_copy(tmp_path, VEHICLE_DIR / "iss_rs.yaml", "overdamped",
                                   _non_oscillatory_mode)
    _check_one_line(capsys, broken, field, bad)


def test_on_lag_not_above_electrical_delay_is_rejected_on_load(capsys, tmp_path) -> None:
    broken, field, bad = _write_copy(tmp_path, VEHICLE_DIR / "generic.yaml", "lag",
                                   _on_lag_below_delay)
    _check_one_line(capsys, broken, field, bad)


def test_scenario_missing_vehicle_names_the_vehicle_field(capsys, tmp_path) -> None:
    broken, field, bad = _write_copy(tmp_path, SCENARIO_DIR / "S000-nofire.yaml", "novehicle",
                                   _scenario_without_vehicle)
    _check_one_line(capsys, broken, field, bad)
