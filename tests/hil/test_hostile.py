"""The hostile campaign's pure parts (``hil.hostile``): loads, forged commands used, the
judgement of a run, the problems and the table. The runs themselves are in
``tests/integration/test_hostile_bus.py`` (vcan)."""

from __future__ import annotations

import pytest

from bus.catalog import FAULT_CMD_IDS, GYRO_IDS, THR_CMD_IDS
from hil import bench, bench_table, hostile
from hil.errors import UsageError


def test_loads_parse_and_bad_ones_are_one_line() -> None:
    assert hostile.parse_loads("none, foreign:5000,replay:100") == \
        [("none", 0.0), ("foreign", 5000.0), ("replay", 100.0)]
    for bad in ("warp:10", "foreign", "foreign:-1", "forged:nan", "foreign:1e9"):
        with pytest.raises(UsageError, match=r"^hil bench: --hostile-loads: expected a comma "
                                             r"list of none or CLASS:RATE .*got '"):
            hostile.parse_loads(bad)
    for load in hostile.DEFAULT_LOADS:
        assert hostile.parse_loads(load)


def test_bench_refuses_bad_loads_before_anything_boots(capsys) -> None:
    assert bench.main(["bench", "--parts", "hostile", "--hostile-loads", "foreign:x"]) == 2
    assert "error: hil bench: --hostile-loads: expected" in capsys.readouterr().err
    assert "hostile" in bench_table.PARTS and "hostile" not in bench_table.DEFAULT_PARTS


def _records(applied: list[list[int]]) -> tuple[list[dict], list[dict]]:
    flight = [{"tick": k, "thr_cmd_on_ms": 10 * k} for k in range(5)]
    plant = [{"tick": 0, "thr_cmd_applied": applied}, {"tick": 1}]
    return plant, flight


def test_forged_used_counts_commands_the_flight_never_sent_and_any_fault() -> None:
    plant, flight = _records([[1, 10], [2, 20], [3, 30]])
    assert hostile.forged_used({"faults": []}, plant, flight) == \
        {"fault_cmd": 0, "thr_cmd": 0, "thr_cmd_applied": 3}
    plant, flight = _records([[1, 10], [2, 1200], [9, 0]])  # other on-time; unknown tick
    used = hostile.forged_used({"faults": [{"type": "stuck_on"}]}, plant, flight)
    assert used == {"fault_cmd": 1, "thr_cmd": 2, "thr_cmd_applied": 3}


def test_frames_expected_at_each_receiver_follow_the_catalog() -> None:
    by_id = {str(THR_CMD_IDS[0]): 10, str(GYRO_IDS[0]): 7, str(FAULT_CMD_IDS[0]): 3,
             str(0x7AB): 100}
    assert hostile.expected_at(by_id) == {"plant": 13, "flight": 10}


def _row(load: str, **kw) -> dict:
    r = {"load": load, "flood": None if load == "none" else
         {"sent": 1000, "seconds": 20.0, "rate_reached_hz": 50.0},
         "flight_ticks": 100, "due": 100, "missed_releases": 0, "overruns": 0,
         "plant_safe_records": 0, "jitter_p99_ms": 2.0,
         "rejects": {"plant": {"bad_crc": 900}, "flight": {}},
         "kernel_drops": {"plant": 0, "flight": 0}, "forged_used": 0, "run_failures": [],
         "crashed": []}
    r.update(kw)
    return r


def test_judge_holds_and_largest_rate_per_class() -> None:
    rows = [_row("none"), _row("foreign:1000"), _row("foreign:5000", jitter_p99_ms=3.9),
            _row("catalog-bad-crc:250"), _row("catalog-bad-crc:500", plant_safe_records=3),
            _row("catalog-bad-crc:1000"), _row("forged:100", missed_releases=1),
            _row("forged:300", forged_used_by_kind={"thr_cmd_applied": 0}),
            _row("replay:100", jitter_p99_ms=4.1)]
    j = hostile.judge(rows)
    # forged:300: no safe state, but the plant applied none of the flight's commands
    assert [r["held"] for r in rows] == [True, True, True, True, False, True, False, False,
                                         True]
    assert [r["jitter_within"] for r in rows] == [True] * 8 + [False]
    lg = j["largest_held"]
    assert lg["foreign"] == {"asked_hz": 5000.0, "reached_hz": 50.0}
    # 1000/s held, but 500/s did not: the rate held is the largest with every lower one held
    assert lg["catalog-bad-crc"]["asked_hz"] == 250.0
    assert lg["forged"] is None and lg["replay"]["asked_hz"] == 100.0
    assert j["quiet_jitter_p99_ms"] == 2.0


def test_problems_are_a_forged_frame_used_or_a_crash_never_a_slow_run() -> None:
    slow = _row("foreign:5000", missed_releases=40, plant_safe_records=80,
                jitter_p99_ms=900.0, run_failures=["40 flight release(s) never ran"])
    assert hostile.check_rows({"hostile": {"runs": [_row("none"), slow]}}) == []
    bad = [_row("forged:100", forged_used=2, forged_used_by_kind={"thr_cmd": 2}),
           _row("replay:100", crashed=["plant process died (signal 11); see plant.log"]),
           _row("foreign:10", flood={"sent": 0})]
    problems = hostile.check_rows({"hostile": {"runs": bad}})
    assert [p.split(":")[0] for p in problems] == [
        "hostile.forged", "hostile.replay", "hostile.foreign"]
    assert "forged_used: expected 0, got 2" in problems[0]
    assert hostile.check_rows({}) == ["hostile.runs: expected one row per load, got nothing"]


def test_the_table_shows_every_figure_of_a_run() -> None:
    rows = [_row("none"), _row("catalog-bad-crc:1000", kernel_drops={"plant": 12,
                                                                        "flight": 3})]
    rep = {"host": {}, "hostile": {"vehicle": "orel", "duration_s": 20.0, "runs": rows,
                                   **hostile.judge(rows), "where": {"kernel": "native kernel"}}}
    text = bench_table.format_table(rep)
    for needle in ("hostile bus: orel, 20.0 s", "catalog-bad-crc:1000", "100/100", "12/3",
                   "p: bad_crc 900", "largest rate held", "1000/s asked (50.0/s reached)",
                   "native kernel"):
        assert needle in text, needle
    assert bench_table.check_figures(rep, ("hostile",)) == []


def test_hostile_options_without_the_hostile_part_are_refused(capsys):
    from hil import bench

    assert bench.main(["bench", "--parts", "allocator", "--hostile-loads", "foreign:100"]) == 2
    assert capsys.readouterr().err.strip().endswith(
        "hil bench: --hostile-loads: expected it only with --parts hostile, got 'foreign:100' "
        "with --parts allocator")
    assert bench.main(["bench", "--hostile-duration", "5"]) == 2
    assert "--hostile-duration: expected it only with --parts hostile, got 5.0" in \
        capsys.readouterr().err
