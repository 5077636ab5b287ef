"""Issue 17: a verdict that never lies. A run whose process died, stopped early, never ticked
or lost ticks is a failed run whatever its expectations say; a summary read back that is
incomplete or contradicts itself is a failure with its reason."""

from __future__ import annotations

import math

import pytest

from hil.config import ExpectationsCfg
from hil.sim import simulate
from hil.summary import summarise
from hil.verdict import (
    EXIT_CODES,
    EXIT_RUN_FAILED,
    REALTIME_EDGE_TICKS,
    judge_summary,
    run_integrity,
)


def _recs(ticks):
    return [{"tick": n, "t_s": round(0.2 * n, 6), "att_err_deg": 0.1, "rate_err_deg_s": 0.01,
             "faults_injected": [], "detection": None} for n in ticks]


def _summary(plant_ticks, flight_ticks, expected=200, mode="lockstep", **kw):
    return summarise(scenario="s", vehicle="generic", mode=mode,
                     plant_records=_recs(plant_ticks), flight_records=_recs(flight_ticks),
                     expect=ExpectationsCfg(no_false_alarm=True), expected_ticks=expected,
                     **kw)


def test_a_sound_run_passes() -> None:
    s = _summary(range(200), range(200), exit_codes={"plant": 0, "flight": 0})
    assert (s["verdict"], s["run_failures"], s["missed_releases"]) == ("passed", [], 0)
    assert s["expectations_met"] is True
    assert judge_summary(s) == ("passed", [])


def test_a_flight_that_never_ticked_fails_the_run_although_no_false_alarm_holds() -> None:
    s = _summary(range(200), [], exit_codes={"plant": 0, "flight": 1})
    assert s["verdict"] == "run_failed" and s["expectations_met"] is False
    assert s["expectation_failures"] == []  # no expectation failed: the run did
    assert "the flight never ticked" in s["run_failures"]
    assert "flight process died (exit code 1); see flight.log" in s["run_failures"]
    assert EXIT_CODES[s["verdict"]] == EXIT_RUN_FAILED == 3


def test_a_plant_killed_mid_run_fails_the_run() -> None:
    # SIGKILL at 13.8 s of a 40 s run: 70 of 200 ticks, the supervisor then stops the flight.
    s = _summary(range(70), range(70), exit_codes={"plant": -9, "flight": 0})
    assert s["verdict"] == "run_failed"
    assert s["run_failures"] == ["plant process died (signal 9); see plant.log",
                                 "stopped early: the plant ran 70 of 200 ticks"]


def test_a_flight_that_stopped_early_fails_the_run() -> None:
    s = _summary(range(200), range(120))
    assert s["run_failures"] == ["the flight stopped at tick 119 while the plant ran to "
                                 "tick 199"]


def test_releases_that_never_ran_are_counted_apart_from_overruns() -> None:
    flight = [n for n in range(200) if not 50 <= n < 60]  # a 2 s stall: 10 releases skipped
    s = _summary(range(200), flight, mode="realtime")
    assert s["missed_releases"] == 10 and s["verdict"] == "run_failed"
    assert "10 flight release(s) never ran (overrun skips or a stall)" in s["run_failures"]


def test_realtime_edges_allow_the_grid_alignment_and_the_stop() -> None:
    s = _summary(range(300), range(5, 300 - REALTIME_EDGE_TICKS), expected=300, mode="realtime")
    assert s["verdict"] == "passed", s["run_failures"]
    # The real-time plant stops on its clock: its last record may be one tick short (seen in
    # a 360 s real-time soak: 1799 of 1800); two short is a stop.
    assert _summary(range(299), range(299), expected=300, mode="realtime")["verdict"] == \
        "passed"
    assert _summary(range(298), range(298), expected=300, mode="realtime")["run_failures"] == [
        "stopped early: the plant ran 298 of 300 ticks"]
    assert _summary(range(199), range(199), mode="lockstep")["verdict"] == "run_failed"


def test_a_kill_on_request_and_an_interruption_are_failures_with_their_reason() -> None:
    s = _summary(range(200), range(51), exit_codes={"plant": 0, "flight": -9},
                 killed={"flight": (10.0, 10.2)})
    assert "flight process killed on request (--kill-flight-at 10) at 10.2 s" in \
        s["run_failures"]
    assert not any("died" in r for r in s["run_failures"])
    s = _summary(range(50), range(50), interrupted=True)
    assert s["run_failures"][0] == "interrupted before the end (Ctrl-C or a signal)"


@pytest.mark.parametrize(("summary", "reason"), [
    ({"scenario": "x"}, "summary: vehicle: expected a field, got nothing"),
    ([], "summary: expected a JSON object, got list"),
    ("passed", "summary: expected a JSON object, got str"),
])
def test_an_incomplete_summary_is_a_failed_run(summary, reason) -> None:
    verdict, reasons = judge_summary(summary)
    assert verdict == "run_failed" and reason in reasons


def test_a_summary_that_contradicts_itself_is_a_failed_run() -> None:
    s = _summary(range(200), range(10))
    assert s["verdict"] == "run_failed"
    forged = dict(s, verdict="passed")
    assert judge_summary(forged) == ("run_failed", [
        "summary: verdict: expected 'run_failed' from its failures, got 'passed'"])
    assert judge_summary(dict(s, ticks="200"))[1] == ["summary: ticks: expected int, got str"]
    assert judge_summary(dict(s, verdict="great"))[0] == "run_failed"


def test_run_integrity_is_pure_and_ignores_records_without_a_tick() -> None:
    r = run_integrity(mode="lockstep", plant_records=[{"final": True}], flight_records=[],
                      expected_ticks=10)
    assert r == {"run_ok": False, "missed_releases": 0,
                 "run_failures": ["the plant never ticked", "the flight never ticked"]}


def test_the_in_process_run_of_a_reference_scenario_is_sound() -> None:
    s = simulate("configs/scenarios/S000-stuck.yaml").summary
    assert s["verdict"] == "passed" and s["run_failures"] == [] and s["missed_releases"] == 0
    assert s["ticks"] == s["flight_ticks"] == 150
    assert math.isfinite(s["max_attitude_error_deg"])
