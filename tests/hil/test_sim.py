"""In-process lockstep (hil/sim.py): the cores on seed scenarios, no bus.

Oracles: seed 000's latency (4.6 s) for S000-stuck; seed 004's Orel polar correction
([10, 0, 0] m/s, angle error < 0.8 deg) checked against the plant's truth, not the flight's
own prediction.
"""

from __future__ import annotations

import pytest

from hil.config import SCENARIO_DIR, ConfigError, load_scenario, load_vehicle
from hil.sim import simulate


def test_s000_stuck_in_process_matches_the_seed_and_repeats_exactly() -> None:
    a = simulate(SCENARIO_DIR / "S000-stuck.yaml")
    b = simulate(SCENARIO_DIR / "S000-stuck.yaml")
    det = [d for d in a.summary["detections"] if d["correct"]]
    assert det and (det[0]["thruster"], det[0]["type"]) == ("X+", "stuck_on")
    assert det[0]["latency_s"] <= 4.6 and a.summary["false_alarms"] == []
    assert a.plant_records == b.plant_records and a.flight_records == b.flight_records


def test_polar_orbit_correction_gives_the_delta_v_in_truth() -> None:
    run = simulate(SCENARIO_DIR / "S004-polar.yaml")
    dv = run.summary["delta_v_B_m_s"]
    assert dv[0] == pytest.approx(10.0, abs=0.3)
    assert abs(dv[1]) < 0.3 and abs(dv[2]) < 0.3
    assert run.summary["max_attitude_error_deg"] < 0.8
    assert run.summary["expectations_met"], run.summary["expectation_failures"]


def test_orbit_correction_burn_names_are_checked(tmp_path) -> None:
    bad = tmp_path / "s.yaml"
    bad.write_text("name: s\nvehicle: orel\nduration_s: 1.0\nflight:\n  orbit_correction:\n"
                   "    delta_v_B_m_s: [1.0, 0.0, 0.0]\n    burn: ['1', '99']\n")
    with pytest.raises(ConfigError) as err:
        load_scenario(bad)
    assert "flight.orbit_correction.burn[1]" in str(err.value) and "'99'" in str(err.value)
    assert load_vehicle("orel").flight.orbit_correction is None
