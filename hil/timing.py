"""Timing figures of a run from its per-tick records (pure: records in, figures out).

Used by ``hil run`` for the ``timing`` block of ``summary.json`` (``timing_summary``), by the
summary's lockstep speed and by ``hil bench`` (``realtime_figures``, ``lockstep_figures``). The
bench imports this module; nothing here imports the bench.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from hil.records import FlightRecord, PlantRecord
from hil.summary import percentiles_ms

WARMUP_TICKS = 5  # 1 s at 5 Hz: imports, first solves, page faults
STAGE_GROUPS = {  # the names -> the stages the flight records
    "I/O": ("gyro_in", "thr_cmd_out", "fdir_tm_out"),
}


def stats_ms(values_s: Iterable[float | None]) -> dict[str, float | int | None]:
    """p50 / p99 / max in milliseconds of seconds values (None skipped), and their count."""
    v = [float(x) for x in values_s if x is not None]
    return {**percentiles_ms(v), "n": len(v)}


def _wrap_ge(a: int, b: int) -> bool:
    """``a`` at or after ``b`` on the 16-bit sample counter."""
    return ((a - b) & 0xFFFF) < 0x8000


def realtime_figures(plant_records: list[PlantRecord], flight_records: list[FlightRecord],
                     tick_s: float, warmup_ticks: int = WARMUP_TICKS) -> dict[str, Any]:
    """Timing figures of a real-time run from the per-tick records of both processes.

    Flight ticks before ``warmup_ticks`` and after the plant's last gyro sample are left out
    (and counted); latency chains of those ticks too.
    """
    fl = [r for r in flight_records if r.get("jitter_s") is not None]
    final = next((r for r in plant_records if r.get("final")), {})
    last_seq = final.get("last_gyro_seq")
    first = fl[0]["tick"] if fl else 0
    kept, after_end = [], 0
    for r in fl:
        want = r.get("gyro_seq_expected")
        if last_seq is not None and want is not None and not _wrap_ge(last_seq, want):
            after_end += 1
            continue
        if r["tick"] >= first + warmup_ticks:
            kept.append(r)
    stage_names: list[str] = []
    for r in kept:
        for k in r.get("stage_s", {}):
            if k not in stage_names:
                stage_names.append(k)
    stages = {k: stats_ms(r["stage_s"].get(k) for r in kept) for k in stage_names}
    for group, members in STAGE_GROUPS.items():
        if any(m in stage_names for m in members):
            stages[group] = stats_ms(sum(r["stage_s"].get(m, 0.0) for m in members)
                                     for r in kept)
    compute = [r["compute_s"] for r in kept if r.get("compute_s") is not None]
    share = {k: (round(float(np.percentile(compute, q)) / tick_s, 6) if compute else None)
             for k, q in (("p50", 50), ("p99", 99), ("max", 100))}
    first_kept = kept[0]["tick"] if kept else first + warmup_ticks
    chains = [c for r in plant_records for c in r.get("chain", [])
              if c.get("tick", 0) >= first_kept]
    pub = [c["published_s"] - c["sample_s"] for c in chains if c.get("published_s") is not None]
    turn = [c["received_s"] - c["published_s"] for c in chains
            if c.get("published_s") is not None]
    on = [r for r in kept if any(v > 0 for v in r.get("series", {}).get("flight/on_ms", {})
                                 .values())]
    last_flight = fl[-1] if fl else {}
    before = next((r for r in reversed(fl) if kept and r["tick"] < kept[0]["tick"]), {})
    return {
        "ticks": len(fl), "ticks_used": len(kept), "warmup_ticks": min(warmup_ticks, len(fl)),
        "ticks_after_plant_end": after_end, "tick_ms": round(tick_s * 1e3, 3),
        "release_jitter_ms": stats_ms(r["jitter_s"] for r in kept),
        # Overruns in the measured ticks (counter before the first, at the last), and all.
        "overruns": (int(kept[-1].get("overruns", 0)) - int(before.get("overruns", 0))
                     if kept else 0),
        "overruns_all_ticks": int(last_flight.get("overruns", 0)),
        "late_gyro": sum(1 for r in kept if r.get("gyro_late")),
        "gyro_wait_ms": stats_ms(r.get("gyro_wait_s") for r in kept),
        "compute_ms": stats_ms(compute),
        "stage_ms": stages,
        "tick_share": share,
        "s2a_ms": stats_ms(c["applied_s"] - c["sample_s"] for c in chains),
        # Sample to THR_CMD at the plant: the chain's own latency (the plant then holds the
        # command until its actuation time, so s2a is the actuation phase when in time).
        "cmd_arrival_ms": stats_ms(c["received_s"] - c["sample_s"] for c in chains),
        # Commands that came after their actuation time (applied on arrival, no evidence).
        "late_actuations": sum(1 for c in chains if c.get("late")),
        "gyro_publish_ms": stats_ms(pub),
        "flight_turnaround_ms": stats_ms(turn),
        "firing_ticks": len(on),
        "_kept_ticks": [r["tick"] for r in kept],  # for the plots, not the JSON
    }


def timing_summary(plant_records: list[PlantRecord], flight_records: list[FlightRecord],
                   tick_s: float) -> dict[str, Any]:
    """The per-run timing block for ``summary.json`` (``hil run``): no warm-up cut, so every
    tick of the run counts. Empty dict for a lockstep run (no real-time figures)."""
    if not any(r.get("jitter_s") is not None for r in flight_records):
        return {}
    f = realtime_figures(plant_records, flight_records, tick_s, warmup_ticks=0)
    keep = ("release_jitter_ms", "gyro_wait_ms", "late_gyro", "stage_ms", "tick_share",
            "s2a_ms", "cmd_arrival_ms", "late_actuations", "gyro_publish_ms",
            "flight_turnaround_ms")
    return {k: f[k] for k in keep}


def lockstep_figures(plant_records: list[PlantRecord],
                     summary: dict | None = None) -> dict[str, Any]:
    """Speed of a lockstep run: the loop (plant's own wall time) and end to end."""
    ticks = [r for r in plant_records if not r.get("final")]
    final = next((r for r in plant_records if r.get("final")), {})
    sim_s = ticks[-1]["t_s"] if ticks else 0.0
    wall = final.get("wall_s")
    out = {
        "ticks": len(ticks), "sim_s": sim_s, "loop_wall_s": wall,
        "speed_x_realtime": round(sim_s / wall, 2) if wall else None,
        "sync_to_cmd_ms": stats_ms(r.get("sync_to_cmd_s") for r in ticks),
        "plant_cpu_s": final.get("cpu_s"),
        "deadline_misses": int(ticks[-1].get("deadline_misses", 0)) if ticks else 0,
    }
    if summary:
        # Summaries before the loop-only speed figure had only the end-to-end one.
        out["end_to_end_x_realtime"] = summary.get("end_to_end_x_realtime",
                                                   summary.get("speed_x_realtime"))
        out["end_to_end_wall_s"] = summary.get("wall_s")
    return out

