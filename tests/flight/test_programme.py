"""Programmed turns (``programme:`` of a scenario, ``FlightSoftware(programme=...)``).

Oracles: the tick a turn takes effect on is the first at or after its time (ceil); the plant's
truth quaternion against the programme's attitude (closed form, ``AttitudeCfg.quaternion``) for
a turn flown by the closed loop; seed 003 fig. 2 for the S003 pair: pulsing in step with a
dominant tone raises a false alarm with the rigid onboard model and none with the self-tuning
observer, at the lockstep and the real-time actuation phase.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.scenario import AttitudeCfg, turn_tick
from flight.attitude import error_quaternion, small_angle_vector
from flight.software import FlightSoftware
from hil.config import SCENARIO_DIR, ConfigError, load_scenario, load_vehicle
from hil.sim import simulate


def _yaw(deg: float) -> AttitudeCfg:
    return AttitudeCfg(axis=(0.0, 0.0, 1.0), angle_deg=deg)


def test_a_turn_takes_effect_on_the_first_tick_at_or_after_its_time() -> None:
    assert turn_tick(1.0, 0.2) == 5 and turn_tick(1.1, 0.2) == 6 and turn_tick(0.0, 0.2) == 0
    v = load_vehicle("generic")
    prog = [(5, _yaw(10.0).quaternion()), (8, _yaw(-5.0).quaternion())]
    fs = FlightSoftware(v, target=_yaw(1.0), programme=prog)
    seen = []
    for n in range(10):
        fs.step(n, np.zeros(3))
        seen.append(round(2.0 * math.degrees(math.atan2(fs.target_TO[3], fs.target_TO[0])), 9))
    assert seen == [1.0] * 5 + [10.0] * 3 + [-5.0] * 2


def test_the_flight_refuses_turns_out_of_order() -> None:
    with pytest.raises(ValueError, match="tick order"):
        FlightSoftware(load_vehicle("generic"),
                       programme=[(5, _yaw(1.0).quaternion()), (4, _yaw(2.0).quaternion())])


def test_of_two_turns_on_one_tick_the_later_is_flown(tmp_path) -> None:
    # 1.0 s and 1.1 s both take effect on tick 6 (0.2 s ticks): valid times, one tick
    p = tmp_path / "s.yaml"
    p.write_text("name: s\nvehicle: generic\nduration_s: 3.0\nprogramme:\n"
                 "  - {at_s: 1.1, attitude: {axis: [0, 0, 1], angle_deg: 1.0}}\n"
                 "  - {at_s: 1.15, attitude: {axis: [0, 0, 1], angle_deg: 2.0}}\n")
    sc = load_scenario(p)
    fs = FlightSoftware(sc.vehicle, programme=sc.cfg.programme_ticks(0.2))
    for n in range(7):
        fs.step(n, np.zeros(3))
    assert np.allclose(fs.target_TO, _yaw(2.0).quaternion())
    assert simulate(sc).summary["run_failures"] == []


@pytest.mark.parametrize("turns, where, expected", [
    ("[{at_s: 2.0, attitude: {angle_deg: 1}}, {at_s: 1.0, attitude: {angle_deg: 2}}]",
     "programme[1].at_s", "a time after the previous turn's 2.0 s, got 1.0"),
    ("[{at_s: 12.0, attitude: {angle_deg: 1}}]",
     "programme[0].at_s", "a time within the run (< duration_s 10.0), got 12.0"),
    ("[{at_s: -1.0, attitude: {angle_deg: 1}}]", "programme[0].at_s", "got -1.0"),
])
def test_a_bad_programme_is_refused_with_the_one_line_error(tmp_path, turns, where,
                                                            expected) -> None:
    p = tmp_path / "s.yaml"
    p.write_text(f"name: s\nvehicle: generic\nduration_s: 10.0\nprogramme: {turns}\n")
    with pytest.raises(ConfigError) as err:
        load_scenario(p)
    msg = str(err.value)
    assert "\n" not in msg and where in msg and expected in msg


def test_the_closed_loop_flies_the_programme_and_the_records_measure_against_it(
        tmp_path) -> None:
    p = tmp_path / "turns.yaml"
    p.write_text("name: turns\nvehicle: generic\nduration_s: 60.0\nseed: 3\n"
                 "programme:\n"
                 "  - {at_s: 5.0, attitude: {axis: [0, 0, 1], angle_deg: 10.0}}\n"
                 "  - {at_s: 30.1, attitude: {axis: [0, 0, 1], angle_deg: -5.0}}\n")
    run = simulate(p, keep=True)
    assert run.summary["detections"] == []
    q1, q2 = _yaw(10.0).quaternion(), _yaw(-5.0).quaternion()

    def off(q, n) -> float:
        return float(np.linalg.norm(small_angle_vector(error_quaternion(q, run.truth[n].q_BO))))

    # before the first turn the craft holds the default target (identity) ...
    assert off(np.array([1.0, 0, 0, 0]), 24) < math.radians(1.0)
    # ... flies the first turn to 10 deg about z and the second (tick 151) to -5 deg, each
    # within the hold's limit cycle (under 1 deg here)
    assert off(q1, 149) < math.radians(1.0) and off(q2, 299) < math.radians(1.0)
    assert off(q2, 149) > math.radians(14.0)
    # the records' attitude error is to the target flown on that tick: 10 deg just after the
    # first turn, 15 deg just after the second (and the limit cycle), small once flown
    att = [float(np.linalg.norm(r["att_err_deg"])) for r in run.plant_records]
    assert att[25] == pytest.approx(10.0, abs=0.3) and att[149] < 1.0
    assert att[151] == pytest.approx(15.0, abs=1.0) and att[299] < 1.0


@pytest.mark.parametrize("phase_s", [0.0, 0.03])
def test_s003_pulsing_in_step_with_the_tone_alarms_only_the_rigid_model(phase_s) -> None:
    sc = load_scenario(SCENARIO_DIR / "S003-flex-rigid.yaml")
    turns = [t.at_s for t in sc.cfg.programme]
    rigid = simulate(sc, actuation_phase_s=phase_s).summary
    # a false alarm while the thrusters pulse in step with the tone (not only the start's)
    assert any(turns[0] < d["t_s"] <= turns[-1] for d in rigid["false_alarms"]), rigid
    adaptive = simulate(SCENARIO_DIR / "S003-flex.yaml", actuation_phase_s=phase_s).summary
    assert adaptive["false_alarms"] == [] and adaptive["expectations_met"]
    assert load_scenario(SCENARIO_DIR / "S003-flex.yaml").cfg.programme == sc.cfg.programme
