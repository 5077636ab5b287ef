"""Campaign statistics against scipy.stats and hand counts; the verdict of one run."""

from __future__ import annotations

from dataclasses import replace

import pytest
from scipy.stats import beta

from hil.campaign.expansion import RunSpec
from hil.campaign.statistics import campaign_statistics, classify, clopper_pearson


def _beta_ci(k: int, n: int) -> tuple[float, float]:
    # Clopper-Pearson from the beta quantiles (the definition), independent of binomtest.
    lo = 0.0 if k == 0 else beta.ppf(0.025, k, n - k + 1)
    hi = 1.0 if k == n else beta.ppf(0.975, k + 1, n - k)
    return lo, hi


@pytest.mark.parametrize("k, n", [(0, 10), (1, 10), (17, 100), (29, 100), (86, 100),
                                  (100, 100), (3, 500), (0, 1)])
def test_clopper_pearson_matches_beta_quantiles(k: int, n: int) -> None:
    lo, hi = clopper_pearson(k, n)
    blo, bhi = _beta_ci(k, n)
    assert lo == pytest.approx(blo, abs=1e-9)
    assert hi == pytest.approx(bhi, abs=1e-9)


def test_no_runs_no_interval() -> None:
    assert clopper_pearson(0, 0) is None


def _row(run: int, cls: str, verdict: str, latency: float | None = None, **kw) -> dict:
    r = {"run": run, "vehicle": "v", "fault_class": cls, "verdict": verdict,
         "fault": None if cls == "none" else {"kind": cls, "thruster": "A", "t_s": 1.0},
         "detections": [{"t_s": 5.0, "thruster": "A", "type": "stuck_on"}]
         if verdict in ("false_alarm", "detected", "misidentified") else [],
         "latency_s": latency, "detected_as": "exact" if verdict == "detected" else None,
         "false_alarms_before_fault": 0, "named": None, "error": None, "reason": None,
         "max_attitude_error_deg": 1.0}
    r.update(kw)
    return r


def test_rates_on_known_counts() -> None:
    rows = [_row(i, "none", "false_alarm") for i in range(17)]
    rows += [_row(100 + i, "none", "pass") for i in range(83)]
    rows += [_row(200, "none", "error", error="boom"), _row(201, "none", "incomplete",
                                                              reason="short")]
    lat = [1.0, 2.0, 3.0, 4.0, 10.0]
    rows += [_row(300 + i, "stuck_on", "detected", latency=x) for i, x in enumerate(lat)]
    rows += [_row(310, "stuck_on", "missed"), _row(311, "stuck_on", "misidentified",
                                                   named="B stuck_on")]
    rows += [_row(320 + i, "fail_to_fire", "unobservable") for i in range(4)]
    rows += [_row(330, "fail_to_fire", "detected", latency=2.0, detected_as="group")]
    s = campaign_statistics(rows)["by_vehicle"]["v"]
    fa = s["none"]["false_alarm"]
    assert (fa["k"], fa["n"]) == (17, 100)  # failures are in no rate
    assert fa["ci95"] == pytest.approx(list(_beta_ci(17, 100)), abs=1e-6)
    st = s["stuck_on"]
    assert (st["missed_detection"]["k"], st["missed_detection"]["n"]) == (2, 7)
    assert st["missed_detection"]["ci95"] == pytest.approx(list(_beta_ci(2, 7)), abs=1e-6)
    assert st["misidentified"] == 1
    assert st["latency_s"] == {"n": 5, "p50": 3.0, "p90": 7.6, "max": 10.0}
    ff = s["fail_to_fire"]
    assert ff["unobservable"] == 4 and ff["observable"] == 1
    assert (ff["missed_detection"]["k"], ff["detected_group"]) == (0, 1)
    assert s["all_faults"]["observable"] == 8
    assert len(campaign_statistics(rows)["failures"]) == 2


def test_fault_free_pointing_is_summarised_over_completed_runs() -> None:
    import numpy as np

    att = [0.3, 0.5, 0.9, 0.4, 0.6]
    rows = [_row(i, "none", "pass", max_attitude_error_deg=a) for i, a in enumerate(att)]
    rows.append(_row(9, "none", "error", error="boom", max_attitude_error_deg=None))
    got = campaign_statistics(rows)["by_vehicle"]["v"]["none"]["max_attitude_error_deg"]
    assert got == {"n": 5, "p50": float(np.percentile(att, 50)),
                   "p90": round(float(np.percentile(att, 90)), 3), "max": 0.9}


SPEC = RunSpec(run=0, name="c-00000", scenario={"duration_s": 10.0}, vehicle={
    "name": "v", "timing": {"tick_s": 0.2}, "thrusters": [{"name": "A"}, {"name": "B"}]},
    vehicle_changed=False, vehicle_ref="v", params={},
    fault={"kind": "fail_to_fire", "thruster": "A", "t_s": 4.0})


def _summary(**kw) -> dict:
    s = {"detections": [], "false_alarms": [], "missed_faults": [
        {"t_s": 4.0, "thruster": "A", "type": "fail_to_fire"}],
        "faults": [{"t_s": 4.0, "thruster": "A", "type": "fail_to_fire"}], "ticks": 50,
        "flight_ticks": 50, "max_attitude_error_deg": 1.0, "max_rate_error_deg_s": 0.1,
        "fuel_kg": 0.01, "scenario": "s", "vehicle": "v", "mode": "in-process",
        "expectations_met": True, "expectation_failures": [], "run_failures": [],
        "verdict": "passed"}
    s.update(kw)
    return s


def test_a_false_gyro_fault_in_a_fault_free_run_is_a_false_alarm_not_a_failure() -> None:
    gyro = {"t_s": 9.0, "thruster": None, "type": "gyro_fault", "gyro": "noise",
            "correct": False}
    free = replace(SPEC, fault=None)
    r = classify(free, _summary(detections=[gyro], faults=[], missed_faults=[],
                                false_alarms=[gyro]))
    assert r["verdict"] == "false_alarm" and r["reason"] is None


@pytest.mark.parametrize(("detections", "verdict"), [
    ([], "missed"),
    ([{"t_s": 9.0, "thruster": "A", "type": "stuck_on", "correct": False}], "misidentified"),
    ([{"t_s": 9.0, "thruster": None, "type": "gyro_fault", "gyro": "spike", "correct": True,
       "latency_s": 1.0}], "detected"),
])
def test_a_gyro_fault_is_judged_like_a_thruster_fault(detections, verdict) -> None:
    """A gyro fault nobody named is missed, one named as a thruster misidentified (through
    the summary's own matching, hil.summary.match_detections)."""
    from hil.summary import match_detections
    fault = {"t_s": 8.0, "thruster": None, "type": "gyro_spike"}
    matched, false_alarms, missed = match_detections([fault], detections)
    spec = replace(SPEC, fault={"kind": "gyro_spike", "thruster": None, "t_s": 8.0, "axis": 0})
    r = classify(spec, _summary(detections=matched, false_alarms=false_alarms,
                                missed_faults=missed, faults=[fault]))
    assert r["verdict"] == verdict


def test_a_gyro_fault_named_a_thruster_first_is_detected_with_a_wrong_one_first() -> None:
    """iss_rs-gyro run 19: a noise increase at 24.1 s, SM+pitch_II named stuck on at 31.6 s,
    the gyro at 38.0 s. The run is detected (a right detection came), and the row and the
    statistics say a wrong one was named first; the misidentified count does not hold it."""
    from hil.summary import match_detections
    fault = {"t_s": 24.1, "thruster": None, "type": "gyro_noise"}
    dets = [{"t_s": 31.6, "thruster": "A", "type": "stuck_on", "correct": False},
            {"t_s": 38.0, "thruster": None, "type": "gyro_fault", "gyro": "noise",
             "correct": True, "latency_s": 13.9}]
    matched, false_alarms, missed = match_detections([fault], dets)
    spec = replace(SPEC, fault={"kind": "gyro_noise", "thruster": None, "t_s": 24.1, "axis": 1})
    row = classify(spec, _summary(detections=matched, false_alarms=false_alarms,
                                  missed_faults=missed, faults=[fault]))
    assert row["verdict"] == "detected" and row["wrong_first"] is True
    right = classify(spec, _summary(detections=matched[1:], false_alarms=false_alarms,
                                    missed_faults=missed, faults=[fault]))
    assert right["verdict"] == "detected" and right["wrong_first"] is False
    st = campaign_statistics([row, right, {**right, "run": 2}])["by_vehicle"]["v"]["gyro_noise"]
    assert st["wrong_first"] == 1 and st["misidentified"] == 0
    assert st["detection"]["k"] == 3


def test_verdicts() -> None:
    assert classify(SPEC, _summary(), commanded_after=True)["verdict"] == "missed"
    r = classify(SPEC, _summary(), commanded_after=False)
    assert r["verdict"] == "unobservable" and "never commanded" in r["reason"]
    det = {"t_s": 6.0, "thruster": ["A", "B"], "type": "fail_to_fire", "latency_s": 2.0,
           "correct": True}
    r = classify(SPEC, _summary(detections=[det], missed_faults=[]), commanded_after=True)
    assert (r["verdict"], r["detected_as"], r["latency_s"]) == ("detected", "group", 2.0)
    assert r["named"] == "one of {A, B} fail_to_fire"
    # A new detection type the summary judges wrong: a misidentification, read generically.
    wrong = {"t_s": 5.0, "thruster": "B", "type": "gyro_fault", "correct": False}
    r = classify(SPEC, _summary(detections=[wrong], false_alarms=[wrong]), commanded_after=True)
    assert r["verdict"] == "misidentified" and r["named"] == "B gyro_fault"
    early = {"t_s": 1.0, "thruster": "B", "type": "stuck_on", "correct": False}
    r = classify(SPEC, _summary(detections=[early], false_alarms=[early]), commanded_after=True)
    assert (r["verdict"], r["false_alarms_before_fault"]) == ("missed", 1)
    free = replace(SPEC, fault=None)
    assert classify(free, _summary(faults=[], missed_faults=[]))["verdict"] == "pass"
    assert classify(free, _summary(detections=[early], faults=[], missed_faults=[],
                                   false_alarms=[early]))["verdict"] == "false_alarm"


@pytest.mark.parametrize("change, reason", [
    ({"ticks": 49}, "49 plant ticks of 50"),
    ({"flight_ticks": 10}, "10 flight ticks of 50"),
    ({"faults": []}, "the fault fail_to_fire A at 4.0 s is not in the summary's faults"),
    ({"fuel_kg": None}, "summary field fuel_kg missing"),
    ({"detections": [{"t_s": 5.0, "type": "stuck_on"}]}, "a detection without type, thruster"),
    ({"run_failures": ["the flight never ticked"], "verdict": "run_failed",
      "expectations_met": False}, "the flight never ticked"),
    ({"verdict": "passed", "run_failures": ["flight process died (signal 9)"]},
     "summary: verdict: expected 'run_failed' from its failures, got 'passed'"),
])
def test_incomplete_summary_is_a_failure_never_a_pass(change: dict, reason: str) -> None:
    r = classify(SPEC, _summary(**change), commanded_after=True)
    assert r["verdict"] == "incomplete"
    assert r["reason"].startswith(reason)


def test_the_fails_to_fire_goal_counts_runs_commanded_three_ticks_and_times_from_the_command(
        ) -> None:
    """The goal's population and latency: runs commanded on 3+ ticks after the fault or
    detected sooner, the latency from the first command acting (the row's own figure, checked
    by hand here)."""
    det = {"t_s": 6.0, "thruster": "A", "type": "fail_to_fire", "latency_s": 2.0,
           "correct": True}
    r = classify(SPEC, _summary(detections=[det], missed_faults=[]), commanded_after=True,
                 commanded_ticks=5, first_command_s=5.2)
    assert r["latency_from_command_s"] == pytest.approx(0.8)
    assert r["commanded_ticks_after_fault"] == 5
    rows = [dict(r, run=0)]
    late = dict(r, run=1, latency_from_command_s=2.5)
    few = dict(r, run=2, commanded_ticks_after_fault=2, latency_from_command_s=9.0)
    miss = classify(SPEC, _summary(), commanded_after=True, commanded_ticks=4,
                    first_command_s=4.6)
    few_missed = classify(SPEC, _summary(), commanded_after=True, commanded_ticks=2,
                          first_command_s=4.6)
    rows += [late, few, dict(miss, run=3), dict(few_missed, run=4)]
    g = campaign_statistics(rows)["by_vehicle"]["v"]["fail_to_fire"]["commanded_goal"]
    assert g["min_ticks"] == 3
    # run 2, detected after 2 commands (the response ends them), is in it; run 4, missed
    # with 2 commands, is not
    assert (g["detection"]["k"], g["detection"]["n"]) == (3, 4)
    assert g["detected_sooner"] == 1
    assert g["latency_from_command_s"]["max"] == 9.0
    # Rows of an older campaign (no command counts) carry no goal figures.
    old = [{k: v for k, v in x.items() if k != "commanded_ticks_after_fault"} for x in rows]
    assert "commanded_goal" not in campaign_statistics(old)["by_vehicle"]["v"]["fail_to_fire"]


def test_commands_after_the_fault_are_counted_from_the_ticks_on_times() -> None:
    """The engine's count: a command acts from ``n h + latency`` for its on-time; it counts
    when it still acts after the fault (hand count over six ticks)."""
    import numpy as np

    from hil.campaign.engine import _Collector, _commands_after

    spec = replace(SPEC, scenario={"duration_s": 1.0, "plant": {"command_latency_ms": 10.0}},
                   fault={"kind": "fail_to_fire", "thruster": "B", "t_s": 0.45})
    col = _Collector(record=False)
    # B (index 1) on 100 ms at tick 1 (acts 0.21-0.31: before the fault), 60 ms at tick 2
    # (0.41-0.47: across it), nothing at tick 3, 20 ms at ticks 4 and 5.
    for on_b in (0, 100, 60, 0, 20, 20):
        col.on_ms.append(np.array([200, on_b], dtype=np.int16))
    ticks, first = _commands_after(spec, col)
    assert ticks == 3
    assert first == pytest.approx(0.45)  # the tick-2 pulse still burns at the fault time
    assert _commands_after(replace(spec, fault={"kind": "stuck_on", "thruster": "B",
                                                "t_s": 0.45}), col) is None


def test_a_stuck_on_thruster_open_at_every_tick_after_the_fault_is_unobservable() -> None:
    """A stuck valve that the controller holds open for the whole of every tick after the fault
    changes nothing the plant can show (hand-made ticks; the engine's rule, then the verdict)."""
    import numpy as np

    from hil.campaign.engine import _Collector, _open_throughout

    fault = {"kind": "stuck_on", "thruster": "B", "t_s": 0.45}
    spec = replace(SPEC, scenario={"duration_s": 1.2, "plant": {"command_latency_ms": 10.0}},
                   fault=fault)
    col = _Collector(record=False)
    # B (index 1): 100 ms at tick 0 and 1 (acting before the fault: not counted), then the
    # whole tick at ticks 2-5 (tick 2 acts 0.41-0.61, across the fault).
    for on_b in (100, 100, 200, 200, 200, 200):
        col.on_ms.append(np.array([0, on_b], dtype=np.int16))
    assert _open_throughout(spec, col) is True
    col.on_ms[4] = np.array([0, 190], dtype=np.int16)  # one tick with 10 ms off: observable
    assert _open_throughout(spec, col) is False
    assert _open_throughout(replace(spec, fault={**fault, "kind": "fail_to_fire"}), col) is None
    summ = _summary(faults=[{"t_s": 0.45, "thruster": "B", "type": "stuck_on"}],
                    missed_faults=[{"t_s": 0.45, "thruster": "B", "type": "stuck_on"}],
                    ticks=6, flight_ticks=6)
    r = classify(spec, summ, open_throughout=True)
    assert r["verdict"] == "unobservable" and "whole of every tick" in r["reason"]
    assert classify(spec, summ, open_throughout=False)["verdict"] == "missed"
    det = {"t_s": 0.8, "thruster": "B", "type": "stuck_on", "latency_s": 0.35, "correct": True}
    assert classify(spec, _summary(detections=[det], missed_faults=[], faults=summ["faults"],
                                   ticks=6, flight_ticks=6),
                    open_throughout=True)["verdict"] == "detected"


def test_closed_ticks_after_a_stuck_on_are_counted_from_the_ticks_on_times() -> None:
    """The mirror of the command count: a tick n's command acts from ``n h + latency`` for its
    on-time, and the valve is meant closed from then to the tick's end; a tick counts when
    that closed time ends after the fault (hand count over seven ticks)."""
    import numpy as np

    from hil.campaign.engine import _closed_after, _Collector

    fault = {"kind": "stuck_on", "thruster": "B", "t_s": 0.45}
    spec = replace(SPEC, scenario={"duration_s": 1.4, "plant": {"command_latency_ms": 10.0}},
                   fault=fault)
    col = _Collector(record=False)
    # B (index 1): nothing at tick 1 (closed 0.21-0.41: before the fault), the whole tick at
    # tick 2 (acts 0.41-0.61: open across the fault), 150 ms at tick 3 (closed 0.76-0.81),
    # the whole tick at 4, nothing at 5, 190 ms at 6 (closed 1.40-1.41).
    for on_b in (200, 0, 200, 150, 200, 0, 190):
        col.on_ms.append(np.array([0, on_b], dtype=np.int16))
    ticks, first = _closed_after(spec, col)
    assert ticks == 3
    assert first == pytest.approx(0.76)
    # the fault inside a closed time: the evidence starts at the fault
    ticks, first = _closed_after(replace(spec, fault={**fault, "t_s": 0.3}), col)
    assert (ticks, first) == (4, pytest.approx(0.3))
    assert _closed_after(replace(spec, fault={**fault, "kind": "fail_to_fire"}), col) is None
    col.on_ms = [np.array([0, 200], dtype=np.int16)] * 7
    assert _closed_after(spec, col) == (0, None)


def test_the_stuck_on_goal_counts_runs_closed_three_ticks_and_times_from_the_closing() -> None:
    """The stuck-on goal population: runs whose valve was meant closed on 3+ ticks after the
    fault or detected sooner; the latency from the first closed time (checked by hand)."""
    fault = {"kind": "stuck_on", "thruster": "A", "t_s": 4.0}
    spec = replace(SPEC, fault=fault)
    faults = [{"t_s": 4.0, "thruster": "A", "type": "stuck_on"}]
    det = {"t_s": 6.0, "thruster": "A", "type": "stuck_on", "latency_s": 2.0, "correct": True}
    r = classify(spec, _summary(detections=[det], missed_faults=[], faults=faults),
                 closed_ticks=6, first_closed_s=5.4)
    assert r["verdict"] == "detected"
    assert r["latency_from_closed_s"] == pytest.approx(0.6)
    assert r["closed_ticks_after_fault"] == 6 and r["first_closed_after_fault_s"] == 5.4
    summ = _summary(faults=faults, missed_faults=[{"t_s": 4.0, "thruster": "A",
                                                    "type": "stuck_on"}])
    missed = classify(spec, summ, open_throughout=False, closed_ticks=5, first_closed_s=4.2)
    few = classify(spec, summ, open_throughout=False, closed_ticks=2, first_closed_s=9.0)
    sooner = dict(r, run=3, closed_ticks_after_fault=1, latency_from_closed_s=0.2)
    rows = [dict(r, run=0), dict(missed, run=1), dict(few, run=2), sooner]
    st = campaign_statistics(rows)["by_vehicle"]["v"]["stuck_on"]
    g = st["closed_goal"]
    # runs 0 and 1 (6 and 5 closed ticks), run 3 (detected after 1); not run 2 (missed, 2)
    assert (g["detection"]["k"], g["detection"]["n"]) == (2, 3)
    assert g["detected_sooner"] == 1
    assert g["latency_from_closed_s"]["max"] == pytest.approx(0.6)
    assert "commanded_goal" not in st
    assert (st["detection"]["k"], st["detection"]["n"]) == (2, 4)  # the whole population


def test_a_degraded_detection_carries_its_fraction_error_and_the_goal_counts_the_tolerance(
        ) -> None:
    spec = replace(SPEC, fault={"kind": "degraded", "thruster": "A", "t_s": 4.0,
                                "fraction": 0.5})
    fault = {"t_s": 4.0, "thruster": "A", "type": "degraded"}

    def row(run: int, named: float | None) -> dict:
        dets = [] if named is None else [{"t_s": 6.0, "thruster": "A", "type": "degraded",
                                          "latency_s": 2.0, "correct": True,
                                          "fraction": named}]
        r = classify(spec, _summary(detections=dets, faults=[fault],
                                    missed_faults=[] if dets else [fault]),
                     commanded_after=True)
        return dict(r, run=run)

    r = row(0, 0.42)
    assert r["fraction_error"] == pytest.approx(-0.08)
    rows = [r, row(1, 0.75), row(2, 0.55), row(3, None)]
    fe = campaign_statistics(rows)["by_vehicle"]["v"]["degraded"]["fraction_error"]
    # Within 0.1: runs 0 and 2 of the 4 observable (run 1 is 0.25 off, run 3 missed).
    assert (fe["within_tolerance"]["k"], fe["within_tolerance"]["n"]) == (2, 4)
    assert fe["max"] == pytest.approx(0.25) and fe["n"] == 3
    assert fe["mean_signed"] == pytest.approx((-0.08 + 0.25 + 0.05) / 3, abs=1e-4)


def test_the_test_pulses_of_the_runs_are_summed_per_fault_class() -> None:
    """Each completed run's ``pulse_tests`` (its summary's) summed; the ticks the controller
    waited, per run, as percentiles; runs without the counters (no pulses configured) and
    failed runs are in no sum."""
    def pt(started, healthy, named, void, ticks):
        return {"started": started, "healthy": healthy, "named": named, "void": void,
                "ticks": ticks}
    rows = [_row(0, "degraded", "detected", latency=1.0, pulse_tests=pt(2, 1, 1, 0, 12)),
            _row(1, "degraded", "missed", pulse_tests=pt(0, 0, 0, 0, 0)),
            _row(2, "degraded", "missed", pulse_tests=pt(3, 1, 0, 2, 20)),
            _row(3, "degraded", "error", error="boom", pulse_tests=pt(9, 9, 0, 0, 90)),
            _row(4, "none", "pass")]
    s = campaign_statistics(rows)["by_vehicle"]["v"]
    got = s["degraded"]["pulse_tests"]
    assert {k: got[k] for k in ("runs_with_tests", "started", "healthy", "named", "void")} \
        == {"runs_with_tests": 2, "started": 5, "healthy": 2, "named": 1, "void": 2}
    assert (got["wait_ticks_per_run"]["n"], got["wait_ticks_per_run"]["p50"],
            got["wait_ticks_per_run"]["max"]) == (3, 12.0, 20.0)
    assert "pulse_tests" not in s["none"]
