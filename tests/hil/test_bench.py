"""`hil bench`, pure parts: figures from records, goals, sanity checks, table, JSON, hogs.

Nothing here measures time: the figures come from synthetic per-tick records, and no test
compares a figure with a time limit (docs/style.md habit 8).
"""

from __future__ import annotations

import json
import math
import os
import time

import pytest

from hil import bench, bench_table, timing
from hil.errors import UsageError

H = 0.2
STAGES = ("gyro_in", "observer", "detector", "controller", "allocator", "output",
          "thr_cmd_out", "fdir_tm_out")


def flight_records(n: int = 20, last_expected: int | None = None) -> list[dict]:
    """Flight ticks 0..n-1 of a real-time run: tick k waits for sample 10 + k."""
    recs = []
    for k in range(n):
        recs.append({
            "tick": k, "t_s": k * H, "jitter_s": 1e-4 * (k % 4),
            "compute_s": 1e-3 * (1 + k % 3),
            "stage_s": {s: 1e-4 * (i + 1) for i, s in enumerate(STAGES)},
            "gyro_wait_s": 2e-3, "gyro_late": k == 12, "gyro_seq_expected": 10 + k,
            "overruns": 1 if k >= 15 else 0,
            "series": {"flight/on_ms": {"a": 30.0 if k % 2 else 0.0, "b": 0.0}},
        })
    return recs


def plant_records(n: int = 20, last_seq: int = 26) -> list[dict]:
    recs = []
    for k in range(n):
        t = (10 + k) * H
        recs.append({"tick": k, "t_s": t, "chain": [{
            "tick": k, "gyro_seq": 10 + k, "sample_s": t, "published_s": t + 5e-4,
            "received_s": t + 5e-3, "applied_s": t + 5e-3 + 1e-3 * (k == 7),
            **({"late": True} if k == 7 else {})}]})
    recs.append({"tick": n, "t_s": n * H, "final": True, "wall_s": 4.0, "cpu_s": 1.0,
                 "last_gyro_seq": last_seq})
    return recs


def test_stats_ms_counts_and_skips_none() -> None:
    s = timing.stats_ms([0.001, None, 0.003, 0.002])
    assert s["n"] == 3 and s["p50"] == 2.0 and s["max"] == 3.0
    assert timing.stats_ms([]) == {"p50": None, "p99": None, "max": None, "n": 0}


def test_realtime_figures_cut_warmup_and_ticks_after_the_plant() -> None:
    f = timing.realtime_figures(plant_records(), flight_records(), H, warmup_ticks=5)
    # samples up to 26 were published: ticks 17..19 (samples 27..29) came after the end
    assert f["ticks"] == 20 and f["ticks_after_plant_end"] == 3 and f["ticks_used"] == 12
    assert f["release_jitter_ms"]["max"] == pytest.approx(0.3)
    assert f["overruns"] == 1 and f["late_gyro"] == 1
    assert f["stage_ms"]["allocator"]["p50"] == pytest.approx(0.5)
    assert f["stage_ms"]["I/O"]["p50"] == pytest.approx(0.1 + 0.7 + 0.8)  # in + both outs
    assert f["compute_ms"]["max"] == pytest.approx(3.0)
    assert f["tick_share"]["max"] == pytest.approx(0.003 / H)
    # chains from tick 5 on: sample to applied 5 ms (6 ms at tick 7), published 0.5 ms after
    assert f["s2a_ms"]["n"] == 15 and f["s2a_ms"]["max"] == pytest.approx(6.0)
    assert f["cmd_arrival_ms"]["max"] == pytest.approx(5.0) and f["late_actuations"] == 1
    assert f["gyro_publish_ms"]["p50"] == pytest.approx(0.5)
    assert f["flight_turnaround_ms"]["p50"] == pytest.approx(4.5)
    assert f["firing_ticks"] == 6


def test_sample_counter_wrap_does_not_cut_ticks() -> None:
    fl = flight_records(4)
    for r in fl:
        r["gyro_seq_expected"] = (65534 + r["tick"]) % 65536
    f = timing.realtime_figures(plant_records(4, last_seq=1), fl, H, warmup_ticks=0)
    assert f["ticks_after_plant_end"] == 0 and f["ticks_used"] == 4


def test_timing_summary_for_a_run_keeps_every_tick_and_skips_lockstep() -> None:
    t = timing.timing_summary(plant_records(), flight_records(), H)
    assert t["release_jitter_ms"]["n"] == 17 and t["s2a_ms"]["n"] == 20
    lock = [{**r, "jitter_s": None} for r in flight_records()]
    assert timing.timing_summary(plant_records(), lock, H) == {}


def test_lockstep_figures() -> None:
    recs = [{"tick": k, "t_s": k * H, "sync_to_cmd_s": 0.004, "deadline_misses": 0}
            for k in range(1, 101)] + [{"tick": 100, "t_s": 20.0, "final": True,
                                        "wall_s": 1.0, "cpu_s": 0.5}]
    f = timing.lockstep_figures(recs, {"speed_x_realtime": 8.0, "wall_s": 2.5})
    assert f["speed_x_realtime"] == 20.0 and f["end_to_end_x_realtime"] == 8.0
    assert f["sync_to_cmd_ms"]["p50"] == pytest.approx(4.0) and f["ticks"] == 100


def test_bus_load_from_the_catalog() -> None:
    f = bench.bus_load_figures(1_000_000)
    assert 0 < f["fraction"] < 1 and f["total_bps"] == pytest.approx(
        sum(r["bps"] for r in f["frames"]), rel=1e-3)
    assert bench.bus_load_figures(500_000)["fraction"] == pytest.approx(2 * f["fraction"],
                                                                        rel=1e-3)


def good_report() -> dict:
    rt = timing.realtime_figures(plant_records(), flight_records(), H, warmup_ticks=5)
    w = {"kernel": "native kernel", "cpus": 2}
    rt["where"] = {**w, "sched": {"flight": "SCHED_OTHER", "plant": "SCHED_BATCH"}}
    trip = {"p50": 0.5, "p99": 0.9, "max": 1.2, "n": 100}
    return {
        "host": {**w, "load_avg_1m": 0.1, "python": "3.11", "stress": False},
        "realtime": rt,
        "lockstep": {"speed_x_realtime": 25.0, "sim_s": 60.0, "where": w},
        "bus": {"clock": "CLOCK_MONOTONIC", "where": {**w, "clock": "CLOCK_MONOTONIC"},
                "round_trip_ms": trip,
                "one_way_ms": {"a_to_b": trip, "b_to_a": trip}, "stack_round_trip_ms": trip},
        "allocator": {"where": w, "ratio_linprog_over": {"simplex": 7.5, "highs": 5.0},
                      "per_solve_us": {"simplex": {"p50": 400.0, "p99": 900.0, "max": 2e3}},
                      "max_cost_rel_diff": 1e-9},
        "bus_load": bench.bus_load_figures(1_000_000),
    }


def test_a_complete_report_has_no_problem() -> None:
    assert bench_table.check_figures(good_report()) == []


@pytest.mark.parametrize(("mutate", "expected"), [
    (lambda r: r["realtime"].pop("s2a_ms"), "realtime.s2a_ms: expected p50/p99/max"),
    (lambda r: r["realtime"]["compute_ms"].update(p50=5.0),
     "realtime.compute_ms: expected p50 <= p99 <= max"),
    (lambda r: r["realtime"]["release_jitter_ms"].update(p99=math.nan),
     "realtime.release_jitter_ms.p99: expected a finite number"),
    (lambda r: r["realtime"]["tick_share"].update(p50=1.5), "realtime.tick_share.p50"),
    (lambda r: r["realtime"]["where"]["sched"].pop("plant"), "realtime.where.sched.plant"),
    (lambda r: r["lockstep"].pop("where"), "lockstep.where"),
    (lambda r: r["lockstep"].update(speed_x_realtime=-1.0), "lockstep.speed_x_realtime"),
    (lambda r: r["bus"].pop("clock"), "bus.clock"),
    (lambda r: r["allocator"]["ratio_linprog_over"].update(highs=None),
     "allocator.ratio_linprog_over.highs"),
    (lambda r: r.pop("bus_load"), "bus_load.fraction"),
])
def test_check_figures_names_the_missing_or_odd_figure(mutate, expected) -> None:
    r = good_report()
    mutate(r)
    problems = bench_table.check_figures(r)
    assert problems and any(p.startswith(expected) for p in problems), problems


def test_check_only_the_parts_measured() -> None:
    r = good_report()
    del r["lockstep"], r["bus"]
    assert bench_table.check_figures(r, ("realtime", "allocator", "load")) == []


def test_goals_are_information_with_the_bus_latency_in_the_latency_goal() -> None:
    g = {x["goal"]: x for x in bench_table.goals(good_report())}
    s2a = g["sample to THR_CMD at the plant p99 < 5 ms + bus one-way p99"]
    assert s2a["limit"] == pytest.approx(5.9) and s2a["met"] is (s2a["value"] < 5.9)
    assert g["no overrun"]["met"] is False and g["lockstep >= 20x real time"]["met"] is True
    assert bench_table.goals({})[0]["met"] is None  # nothing measured: no verdict either way


def test_table_names_every_figure_and_where() -> None:
    r = good_report()
    r["goals"] = bench_table.goals(r)
    text = bench_table.format_table(r)
    for needle in ("tick release jitter", "compute allocator", "compute I/O", "share of the",
                   "sensor-to-actuator", "lockstep speed (loop)", "round trip A->B->A",
                   "linprog / simplex", "bus load from the catalog", "native kernel",
                   "plant SCHED_BATCH", "CLOCK_MONOTONIC", "NOT met"):
        assert needle in text, needle


def test_json_report_drops_plot_series_and_is_strict_json() -> None:
    r = good_report()
    r["realtime"]["_series"] = {"jitter_ms": [0.1]}
    pub = bench._public(r)
    assert "_series" not in pub["realtime"]
    json.dumps(pub, allow_nan=False)


def test_parts_option() -> None:
    assert bench._parse_parts("bus, load") == ("bus", "load")
    with pytest.raises(UsageError, match="--parts: expected a comma list"):
        bench._parse_parts("bus,warp")


def test_usage_errors_exit_2(capsys) -> None:
    assert bench.main(["bench", "--duration", "0"]) == 2
    assert "--duration: expected a finite number >= 2, got 0" in capsys.readouterr().err
    assert bench.main(["bench", "--duration", "inf"]) == 2
    assert "--duration: expected a finite number >= 2, got inf" in capsys.readouterr().err
    assert bench.main(["bench", "--vehicle", "nope"]) == 2
    assert "--vehicle: expected one of" in capsys.readouterr().err


def test_cpu_hogs_leave_no_process_behind() -> None:
    with bench.CpuHogs(2) as hogs:
        pids = hogs.pids
        time.sleep(0.2)
        assert all(p.poll() is None for p in hogs.procs)
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)  # killed and reaped: not even a zombie left


def test_allocator_comparison_is_measured_on_the_same_problems() -> None:
    f = bench.compare_allocator("generic", ticks=20)
    assert set(f["ratio_linprog_over"]) == {"simplex", "highs"}
    assert f["max_cost_rel_diff"] < 1e-6  # the same optimum as linprog
    assert all(v > 0 for v in f["ratio_linprog_over"].values())


def test_an_overrun_tick_is_a_figure_not_a_problem() -> None:
    r = good_report()
    r["realtime"]["tick_share"].update(max=1.3)  # one tick longer than the tick: counted
    r["realtime"]["compute_ms"].update(max=260.0)
    assert bench_table.check_figures(r) == []
