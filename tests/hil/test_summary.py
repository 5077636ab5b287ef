"""Verdict logic: detections matched to faults, false alarms, misses, expectations."""

from __future__ import annotations

from hil.config import ExpectationsCfg, ExpectedDetection
from hil.summary import check_expectations, match_detections, summarise

FAULT = {"t_s": 18.0, "thruster": "X+", "type": "stuck_on", "fraction": 1.0}


def test_right_thruster_and_type_is_correct_with_latency() -> None:
    det = [{"t_s": 20.4, "thruster": "X+", "type": "stuck_on"}]
    rows, fa, missed = match_detections([FAULT], det)
    assert rows[0]["correct"] and abs(rows[0]["latency_s"] - 2.4) < 1e-9
    assert fa == [] and missed == []


def test_wrong_type_before_fault_or_wrong_thruster_are_false_alarms() -> None:
    det = [
        {"t_s": 10.0, "thruster": "X+", "type": "stuck_on"},      # before the fault
        {"t_s": 19.0, "thruster": "X-", "type": "stuck_on"},      # wrong thruster
        {"t_s": 19.5, "thruster": "X+", "type": "fail_to_fire"},  # wrong type
    ]
    rows, fa, missed = match_detections([FAULT], det)
    assert [r["correct"] for r in rows] == [False, False, False]
    assert len(fa) == 3 and missed == [FAULT]


def test_a_detection_after_the_fault_was_cleared_is_a_false_alarm() -> None:
    # X+ stuck on from 18 s to 20 s; a detection at 25 s is not of this fault (before the
    # fix the clear time was compared with the fault's own start and this counted as correct).
    cleared = dict(FAULT, clear_t_s=20.0)
    rows, fa, missed = match_detections(
        [cleared], [{"t_s": 25.0, "thruster": "X+", "type": "stuck_on"}])
    assert rows[0]["correct"] is False and rows[0]["latency_s"] is None
    assert fa == rows and missed == [cleared]


def test_a_detection_while_the_fault_is_active_or_at_its_clear_time_counts() -> None:
    cleared = dict(FAULT, clear_t_s=20.0)
    for t in (19.0, 20.0):
        rows, fa, missed = match_detections(
            [cleared], [{"t_s": t, "thruster": "X+", "type": "stuck_on"}])
        assert rows[0]["correct"] and fa == [] and missed == [], t


def test_a_fault_cleared_by_the_panel_ends_at_the_clear_record() -> None:
    # `hil fault clear` at 20 s: the plant records it in `faults_cleared`; a detection at
    # 25 s is then a false alarm and the fault missed, as for a scheduled clear.
    plant = _plant([18.0, 20.0], [0.1, 0.1], [0.0, 0.0], faults=[FAULT])
    plant[1]["faults_cleared"] = [{"thruster": "X+", "type": "stuck_on", "t_on_s": 18.0,
                                   "t_s": 20.0}]
    flight = [{"t_s": 25.0, "detection": {"t_s": 25.0, "thruster": "X+", "type": "stuck_on"}}]
    s = summarise(scenario="s", vehicle="generic", mode="realtime", plant_records=plant,
                  flight_records=flight, expect=None)
    assert s["faults"] == [dict(FAULT, clear_t_s=20.0)]
    assert len(s["false_alarms"]) == 1 and len(s["missed_faults"]) == 1


def test_safety_settings_and_scheduler_policy_come_from_the_first_records() -> None:
    plant = _plant([0.0, 0.2], [0.1, 0.1], [0.0, 0.0])
    plant[0].update(config={"safety": {"thr_cmd_lost_ticks": 4, "heartbeat_lost_s": 2.0}},
                    sched="SCHED_FIFO 40, memory locked")
    flight = [{"tick": 0, "t_s": 0.0, "config": {"safety": {"gyro_lost_ticks": 5}},
               "sched": "SCHED_OTHER, SCHED_FIFO refused (PermissionError: x)"}]
    s = summarise(scenario="s", vehicle="generic", mode="realtime", plant_records=plant,
                  flight_records=flight, expect=None)
    assert s["safety"] == {"thr_cmd_lost_ticks": 4, "heartbeat_lost_s": 2.0,
                           "gyro_lost_ticks": 5}
    assert s["sched"] == {"plant": "SCHED_FIFO 40, memory locked",
                          "flight": "SCHED_OTHER, SCHED_FIFO refused (PermissionError: x)"}
    bare = summarise(scenario="s", vehicle="generic", mode="lockstep",
                     plant_records=_plant([0.0], [0.1], [0.0]), flight_records=[], expect=None)
    assert "safety" not in bare and "sched" not in bare


def test_group_report_and_degraded_as_fail_to_fire() -> None:
    faults = [{"t_s": 5.0, "thruster": "B", "type": "degraded", "fraction": 0.3}]
    rows, fa, _ = match_detections(faults, [{"t_s": 6.0, "thruster": ["A", "B"],
                                             "type": "fail_to_fire"}])
    assert rows[0]["correct"] and fa == []


def test_expectations() -> None:
    exp = ExpectationsCfg(detections=[ExpectedDetection(thruster="X+", type="stuck_on",
                                                        within_s=4.6)],
                          max_attitude_error_deg=1.0)
    s = summarise(scenario="s", vehicle="generic", mode="lockstep",
                  plant_records=[{"tick": 0, "t_s": 0.0, "att_err_deg": 0.5, "rate_err_deg_s": 0.1,
                                  "faults_injected": [FAULT]}],
                  flight_records=[{"tick": 0, "t_s": 23.0, "detection":
                                   {"t_s": 23.0, "thruster": "X+", "type": "stuck_on"}}],
                  expect=exp)
    assert not s["expectations_met"]                       # 5.0 s > 4.6 s
    assert "within 4.6 s: expected" in s["expectation_failures"][0]
    s["detections"][0]["latency_s"] = 4.0
    assert check_expectations(s, exp) == []


def _plant(ts, att, rate, dv=(0.0, 0.0, 0.0), faults=()):
    recs = [{"tick": k, "t_s": t, "att_err_deg": a, "rate_err_deg_s": r, "dv_B_m_s": list(dv),
             "faults_injected": []} for k, (t, a, r) in enumerate(zip(ts, att, rate, strict=True))]
    recs[0]["faults_injected"] = list(faults)
    return recs


def _flight(n_ticks, detections=()):
    """Flight records of a sound run (one per tick), with ``detections`` at their ticks."""
    recs = [{"tick": k, "t_s": round(0.2 * k, 6), "detection": None} for k in range(n_ticks)]
    for d in detections:
        recs[round(d["t_s"] / 0.2)]["detection"] = d
    return recs


def test_longest_excursion_counts_from_the_last_sample_inside() -> None:
    from hil.summary import longest_excursion_s

    s = [(0.0, 0.0), (0.2, 0.2), (0.4, 0.2), (0.6, 0.0), (0.8, 0.3), (1.0, 0.0)]
    assert longest_excursion_s(s, 0.12) == 0.4   # out from after 0.0 until 0.4
    assert longest_excursion_s([(0.0, 0.0)], 0.12) == 0.0


def test_orbit_correction_expectations_delta_v_and_excursions() -> None:
    ts = [0.2 * k for k in range(50)]
    rate = [0.05] * 50
    rate[10:20] = [0.2] * 10                      # 2 s out of the band
    exp = ExpectationsCfg(delta_v_B_m_s=(7.0, -2.0, -1.0), rate_band_deg_s=0.12,
                          max_excursion_s=1.0)
    s = summarise(scenario="s", vehicle="orel", mode="lockstep",
                  plant_records=_plant(ts, [0.1] * 50, rate, dv=(7.1, -2.5, -1.0)),
                  flight_records=_flight(50), expect=exp)
    assert s["delta_v_B_m_s"] == [7.1, -2.5, -1.0] and s["longest_rate_excursion_s"] == 2.0
    assert len(s["expectation_failures"]) == 2     # y off by 0.5 m/s; a 2 s excursion
    exp_ok = ExpectationsCfg(delta_v_B_m_s=(7.0, -2.4, -1.0), rate_band_deg_s=0.12,
                             max_excursion_s=3.0)
    s = summarise(scenario="s", vehicle="orel", mode="lockstep",
                  plant_records=_plant(ts, [0.1] * 50, rate, dv=(7.1, -2.5, -1.0)),
                  flight_records=_flight(50), expect=exp_ok)
    assert s["expectations_met"], s["expectation_failures"]


def test_recovery_is_judged_after_the_first_correct_detection() -> None:
    ts = [0.2 * k for k in range(100)]
    att = [0.3] * 100
    att[60] = 1.5                                  # 12 s: inside the recovery window
    fault = dict(FAULT, t_s=1.0)
    flight = _flight(100, [{"t_s": 2.0, "thruster": "X+", "type": "stuck_on"}])
    exp = ExpectationsCfg(recover_after_s=5.0, recovered_attitude_deg=0.8)
    s = summarise(scenario="s", vehicle="generic", mode="lockstep",
                  plant_records=_plant(ts, att, [0.01] * 100, faults=[fault]),
                  flight_records=flight, expect=exp)
    assert s["recovery"]["from_t_s"] == 7.0 and s["recovery"]["max_attitude_error_deg"] == 1.5
    assert not s["expectations_met"]
    exp_late = ExpectationsCfg(recover_after_s=11.0, recovered_attitude_deg=0.8)
    s = summarise(scenario="s", vehicle="generic", mode="lockstep",
                  plant_records=_plant(ts, att, [0.01] * 100, faults=[fault]),
                  flight_records=flight, expect=exp_late)
    assert s["expectations_met"], s["expectation_failures"]


def test_a_demonstration_run_must_raise_its_false_alarm() -> None:
    exp = ExpectationsCfg(no_false_alarm=False, false_alarm_expected=True)
    quiet = summarise(scenario="s", vehicle="iss_rs", mode="lockstep",
                      plant_records=_plant([0.0], [0.1], [0.0]), flight_records=_flight(1),
                      expect=exp)
    assert quiet["expectation_failures"] == [
        "false alarm: expected one (demonstration run), got none"]
    flight = [{"tick": 0, "t_s": 4.2,
               "detection": {"t_s": 4.2, "thruster": "P", "type": "stuck_on"}}]
    loud = summarise(scenario="s", vehicle="iss_rs", mode="lockstep",
                     plant_records=_plant([0.0], [0.1], [0.0]), flight_records=flight,
                     expect=exp)
    assert loud["expectations_met"]


def test_a_gyro_fault_detection_matches_an_active_gyro_fault_only() -> None:
    """A gyro_fault detection names no thruster: it is correct when a gyro fault is active,
    a false alarm before one (and never matches a thruster fault)."""
    faults = [{"t_s": 20.0, "thruster": None, "type": "gyro_bias_step"},
              {"t_s": 5.0, "thruster": "X+", "type": "stuck_on"}]
    det = {"t_s": 20.4, "thruster": None, "type": "gyro_fault"}
    out, fa, missed = match_detections(faults, [det])
    assert out[0]["correct"] and out[0]["latency_s"] == 0.4 and fa == []
    assert [f["thruster"] for f in missed] == ["X+"]
    out, fa, _ = match_detections(faults, [{**det, "t_s": 10.0}])
    assert not out[0]["correct"] and len(fa) == 1


def test_the_test_pulses_of_the_run_are_its_last_flight_records() -> None:
    """``pulse_tests`` (cumulative in each flight record when test pulses are configured):
    the summary keeps the last record's; a run without them has none."""
    plant = _plant([0.0, 0.2], [0.1, 0.1], [0.0, 0.0])
    flight = _flight(2)
    flight[0]["pulse_tests"] = {"started": 1, "healthy": 0, "named": 0, "void": 0, "ticks": 2}
    flight[1]["pulse_tests"] = {"started": 1, "healthy": 1, "named": 0, "void": 0, "ticks": 4}
    s = summarise(scenario="s", vehicle="orel", mode="lockstep", plant_records=plant,
                  flight_records=flight, expect=None)
    assert s["pulse_tests"] == flight[1]["pulse_tests"]
    bare = summarise(scenario="s", vehicle="generic", mode="lockstep", plant_records=plant,
                     flight_records=_flight(2), expect=None)
    assert "pulse_tests" not in bare
