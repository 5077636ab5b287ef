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
