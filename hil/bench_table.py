"""`hil bench`'s verdicts and table: the goals shown as met or not (never asserted), the sanity
checks of every figure, and the printed table.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

PARTS = ("realtime", "lockstep", "bus", "allocator", "load", "hostile")
# What ``hil bench`` measures without ``--parts``: the hostile campaign (hil.hostile, several
# minutes of runs under floods) only when asked for.
DEFAULT_PARTS = PARTS[:-1]
GOALS = (
    # (text, key path in the report, limit): shown as met or not met, never asserted
    ("release jitter p99 < 1 ms", ("realtime", "release_jitter_ms", "p99"), 1.0),
    ("no overrun", ("realtime", "overruns"), 0),
    ("flight compute p99 < 2 ms", ("realtime", "compute_ms", "p99"), 2.0),
    ("sample to THR_CMD at the plant p99 < 5 ms + bus one-way p99",
     ("realtime", "cmd_arrival_ms", "p99"), None),
    ("lockstep >= 20x real time", ("lockstep", "speed_x_realtime"), 20.0),
)


def _get(d: dict, path: tuple[str, ...]) -> Any:
    for k in path:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def goals(report: dict) -> list[dict[str, Any]]:
    """Issue 7's goals against the figures (information for the reader, never a failure)."""
    out = []
    one_way = _get(report, ("bus", "one_way_ms", "a_to_b", "p99"))
    for text, path, limit in GOALS:
        value = _get(report, path)
        if limit is None:  # sample to command: 5 ms plus the bus's one-way latency
            limit = None if one_way is None else round(5.0 + one_way, 4)
        if value is None or limit is None:
            met = None
        elif path[-1] == "overruns":
            met = value <= limit
        elif path[-1] == "speed_x_realtime":
            met = value >= limit
        else:
            met = value < limit
        out.append({"goal": text, "value": value, "limit": limit, "met": met})
    return out


def check_figures(report: dict, parts: Iterable[str] = DEFAULT_PARTS) -> list[str]:
    """Every figure present, finite, non-negative and ordered; one line per problem.

    What the CI smoke run asserts: the bench measured everything and nothing is absurd. No
    figure is compared with a time limit (a slow machine is not a failure).
    """
    problems: list[str] = []

    def num(path: str, x: Any, *, lo: float = 0.0, hi: float | None = None) -> None:
        if not isinstance(x, int | float) or isinstance(x, bool) or not math.isfinite(x):
            problems.append(f"{path}: expected a finite number, got {x!r}")
        elif x < lo or (hi is not None and x > hi):
            problems.append(f"{path}: expected {lo} <= value{f' <= {hi}' if hi else ''}, "
                            f"got {x}")

    def triple(path: str, d: Any) -> None:
        if not isinstance(d, dict):
            problems.append(f"{path}: expected p50/p99/max, got {d!r}")
            return
        for k in ("p50", "p99", "max"):
            num(f"{path}.{k}", d.get(k))
        if all(isinstance(d.get(k), int | float) for k in ("p50", "p99", "max")) and not (
                d["p50"] <= d["p99"] + 1e-9 <= d["max"] + 2e-9):
            problems.append(f"{path}: expected p50 <= p99 <= max, got "
                            f"{d['p50']}, {d['p99']}, {d['max']}")

    def where(path: str, sec: Any) -> None:
        w = sec.get("where") if isinstance(sec, dict) else None
        if not isinstance(w, dict) or not w.get("kernel"):
            problems.append(f"{path}.where: expected the kernel it ran on, got {w!r}")

    parts = tuple(parts)
    if "realtime" in parts:
        rt = report.get("realtime") or {}
        where("realtime", rt)
        for k in ("release_jitter_ms", "compute_ms", "s2a_ms", "cmd_arrival_ms", "gyro_wait_ms",
                  "gyro_publish_ms", "flight_turnaround_ms"):
            triple(f"realtime.{k}", rt.get(k))
        stages = rt.get("stage_ms") or {}
        for k in ("observer", "detector", "controller", "allocator", "I/O"):
            triple(f"realtime.stage_ms.{k}", stages.get(k))
        share = rt.get("tick_share") or {}
        # The median tick inside its tick; p99 and max may pass 1 (an overrun is counted).
        for k in ("p50", "p99", "max"):
            num(f"realtime.tick_share.{k}", share.get(k), hi=1.0 if k == "p50" else None)
        num("realtime.overruns", rt.get("overruns"))
        num("realtime.ticks_used", rt.get("ticks_used"), lo=1)
        sched = (rt.get("where") or {}).get("sched") or {}
        for node in ("flight", "plant"):
            if not sched.get(node):
                problems.append(f"realtime.where.sched.{node}: expected a policy, got nothing")
    if "lockstep" in parts:
        ls = report.get("lockstep") or {}
        where("lockstep", ls)
        num("lockstep.speed_x_realtime", ls.get("speed_x_realtime"), lo=1e-9)
        num("lockstep.sim_s", ls.get("sim_s"), lo=1e-9)
    if "bus" in parts:
        bus = report.get("bus") or {}
        where("bus", bus)
        if not bus.get("clock"):
            problems.append("bus.clock: expected the clock's name, got nothing")
        triple("bus.round_trip_ms", bus.get("round_trip_ms"))
        for k in ("a_to_b", "b_to_a"):
            triple(f"bus.one_way_ms.{k}", (bus.get("one_way_ms") or {}).get(k))
        triple("bus.stack_round_trip_ms", bus.get("stack_round_trip_ms"))
    if "allocator" in parts:
        al = report.get("allocator") or {}
        where("allocator", al)
        for k, d in (al.get("per_solve_us") or {"missing": None}).items():
            triple(f"allocator.per_solve_us.{k}", d)
        for k, v in (al.get("ratio_linprog_over") or {"missing": None}).items():
            num(f"allocator.ratio_linprog_over.{k}", v, lo=1e-9)
        num("allocator.max_cost_rel_diff", al.get("max_cost_rel_diff"))
    if "load" in parts:
        ld = report.get("bus_load") or {}
        num("bus_load.fraction", ld.get("fraction"), hi=1.0)
        num("bus_load.bitrate_bps", ld.get("bitrate_bps"), lo=1)
    if "hostile" in parts:
        from hil.hostile import check_rows

        problems += check_rows(report)
    return problems


# ============================================================================ the table


def _f(x: Any, nd: int = 3) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.{nd}f}"
    return str(x)


def _where_text(w: dict | None) -> str:
    if not w:
        return ""
    bits = [w.get("kernel", "?")]
    if w.get("bus"):
        bits.append(f"bus {w['bus']}")
    sched = w.get("sched")
    if isinstance(sched, dict):
        bits.append(", ".join(f"{k} {v}" for k, v in sched.items()))
    elif sched:
        bits.append(str(sched))
    if w.get("clock"):
        bits.append(w["clock"])
    return "; ".join(bits)


def format_table(report: dict) -> str:
    """The printed table: one line per figure, p50 / p99 / max, and where it was taken."""
    head = report.get("host", {})
    lines = [
        f"hil bench: {head.get('kernel', '?')}, {head.get('cpus', '?')} CPU(s), host load "
        f"{head.get('load_avg_1m', '?')} before, stress "
        f"{'on (' + str(head.get('stress_procs')) + ' hogs)' if head.get('stress') else 'off'}, "
        f"python {head.get('python', '?')}",
        f"{'figure':<44}{'p50':>10}{'p99':>10}{'max':>10}",
    ]

    def row(name: str, d: dict | None, unit: str = "ms") -> None:
        d = d or {}
        lines.append(f"  {name + ' [' + unit + ']':<42}{_f(d.get('p50')):>10}"
                     f"{_f(d.get('p99')):>10}{_f(d.get('max')):>10}")

    def text(name: str, value: str) -> None:
        lines.append(f"  {name:<42}{value}")

    rt = report.get("realtime")
    if rt:
        lines.append(f"real time: {rt.get('vehicle')}, {rt.get('duration_s')} s, "
                     f"{rt.get('ticks_used')} ticks used ({rt.get('warmup_ticks')} warm-up, "
                     f"{rt.get('ticks_after_plant_end')} after the plant's end left out)")
        lines.append(f"  where: {_where_text(rt.get('where'))}")
        row("tick release jitter", rt.get("release_jitter_ms"))
        text("overruns", f"{rt.get('overruns')} in {rt.get('ticks_used')} ticks "
                         f"({rt.get('overruns_all_ticks')} in all {rt.get('ticks')})")
        for k, d in (rt.get("stage_ms") or {}).items():
            row(f"compute {k}", d)
        row("compute whole tick", rt.get("compute_ms"))
        sh = rt.get("tick_share") or {}
        lines.append(f"  {'share of the ' + _f(rt.get('tick_ms'), 0) + ' ms tick':<42}"
                     + "".join(f"{_f(None if sh.get(k) is None else 100 * sh[k], 2) + ' %':>10}"
                               for k in ("p50", "p99", "max")))
        row("sensor-to-actuator (sample->applied)", rt.get("s2a_ms"))
        row("sample->THR_CMD at the plant", rt.get("cmd_arrival_ms"))
        row("  of which sample->published", rt.get("gyro_publish_ms"))
        row("  of which published->THR_CMD rx", rt.get("flight_turnaround_ms"))
        text("late actuations (THR_CMD after its phase)", str(rt.get("late_actuations")))
        row("flight's wait for its gyro sample", rt.get("gyro_wait_ms"))
        text("late gyro samples (wait bound hit)", str(rt.get("late_gyro")))
        text("ticks firing / FDIR false alarms",
             f"{rt.get('firing_ticks')} / {rt.get('false_alarms')}")
    ls = report.get("lockstep")
    if ls:
        lines.append(f"lockstep: {ls.get('sim_s')} s simulated")
        lines.append(f"  where: {_where_text(ls.get('where'))}")
        text("lockstep speed (loop) [x real time]", _f(ls.get("speed_x_realtime"), 2))
        text("lockstep speed (start-up incl.) [x]",
             _f(ls.get("end_to_end_x_realtime"), 2))
        row("SYNC sent to THR_CMD complete", ls.get("sync_to_cmd_ms"))
    bus = report.get("bus")
    if bus:
        lines.append(f"bus: {bus.get('frames')} frames ping-pong, {bus.get('lost')} lost")
        lines.append(f"  where: {_where_text(bus.get('where'))}")
        ow = bus.get("one_way_ms") or {}
        row("one way A->B (send->recv)", ow.get("a_to_b"))
        row("one way B->A", ow.get("b_to_a"))
        row("round trip A->B->A", bus.get("round_trip_ms"))
        row("SYNC->THR_CMD set (Port, 30 thr.)", bus.get("stack_round_trip_ms"))
    al = report.get("allocator")
    if al:
        lines.append(f"allocator: {al.get('vehicle')}, {al.get('problems')} LPs, flight uses "
                     f"{al.get('solver_configured')}")
        lines.append(f"  where: {_where_text(al.get('where'))}")
        for k, d in (al.get("per_solve_us") or {}).items():
            row(f"LP solve {k}", d, "us")
        for k, r in (al.get("ratio_linprog_over") or {}).items():
            text(f"linprog / {k} (total time)", f"{_f(r, 1)}x")
        text("largest optimum difference vs linprog", _f(al.get("max_cost_rel_diff"), 6))
    ld = report.get("bus_load")
    if ld:
        text("bus load from the catalog",
             f"{ld['total_bps']:.0f} bit/s = {100 * ld['fraction']:.2f} % of "
             f"{ld['bitrate_bps'] / 1e6:g} Mbit/s")
    host = report.get("hostile")
    if host:
        from hil.hostile import format_rows

        lines += format_rows({**host, "where_text": _where_text(host.get("where"))})
    gl = report.get("goals")
    if gl:
        lines.append("goals of issue 7 (information, not a verdict):")
        for g in gl:
            state = {True: "met", False: "NOT met", None: "-"}[g["met"]]
            lines.append(f"  {g['goal']:<52}{_f(g['value']):>10}  {state}")
    return "\n".join(lines)
