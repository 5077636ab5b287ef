"""Whether a run can be believed at all, before its expectations are judged.

A dead flight trivially satisfies "no false alarm", and a plant killed at 13.8 s of 40 s leaves
a summary whose expectations look met. So a run is judged in two steps:

1. **integrity** (``run_integrity``): did both processes tick, to the end, without losing a
   tick, and exit cleanly? Any "no" is a *failed run* with its reasons, whatever the
   expectations say;
2. **expectations** (``hil.summary.check_expectations``), meaningful only on a sound run.

``verdict`` is then ``passed``, ``not_met`` (a sound run whose expectations fail) or
``run_failed``. The exit codes of ``hil run`` (and of ``hil report``, ``hil run-all`` and
campaigns, which read the same field) follow it: 0, 1 and 3; 2 stays the usage or
configuration error. ``judge_summary`` applies the same rules to a ``summary.json`` read back
from disk, so a truncated, hand-edited or foreign file is a failure with a reason, never a pass.

Pure: no I/O; records are the per-tick dicts the processes write (``hil.recorder``).
"""

from __future__ import annotations

from typing import Any

EXIT_PASSED = 0
EXIT_NOT_MET = 1
EXIT_USAGE = 2
EXIT_RUN_FAILED = 3
EXIT_OUTPUT_LOST = 4  # a node's exit code when it could not write its records (disk full...)

VERDICTS = ("passed", "not_met", "run_failed")
EXIT_CODES = {"passed": EXIT_PASSED, "not_met": EXIT_NOT_MET, "run_failed": EXIT_RUN_FAILED}

# In real time the flight's tick grid is placed on the first gyro arrivals and the supervisor
# stops the flight once the plant has ended, so the flight's first and last ticks may differ
# from the plant's by this much without a tick being lost.
REALTIME_EDGE_TICKS = 15
# The real-time plant stops on its clock at the duration, which may fall just before its last
# tick's record: one tick short is the end of the run, not a stop.
REALTIME_PLANT_END_TICKS = 1
# Exit codes of a node that ended because the supervisor asked it to (SIGTERM handled: 0;
# not handled in time: -15).
CLEAN_EXIT_CODES = (0, -15)

# What a summary must hold to be judged at all (``judge_summary``).
SUMMARY_REQUIRED = {
    "scenario": str, "vehicle": str, "mode": str, "ticks": int, "flight_ticks": int,
    "detections": list, "false_alarms": list, "missed_faults": list,
    "expectations_met": bool, "expectation_failures": list, "run_failures": list,
    "verdict": str,
}


def _ticks(records: list[dict[str, Any]]) -> list[int]:
    return [int(r["tick"]) for r in records if isinstance(r.get("tick"), int)]


def run_integrity(
    *,
    mode: str,
    plant_records: list[dict[str, Any]],
    flight_records: list[dict[str, Any]],
    expected_ticks: int | None,
    exit_codes: dict[str, int | None] | None = None,
    killed: dict[str, tuple[float, float]] | None = None,
    interrupted: bool = False,
    io_error: str | None = None,
) -> dict[str, Any]:
    """``{"run_ok", "run_failures": [reason, ...], "missed_releases"}`` of one run.

    ``expected_ticks`` is the scenario's tick count (``None``: a run without an end, such as
    ``hil up``, judged only on what it ran); ``exit_codes`` the nodes' return codes (``None``
    while still running); ``killed`` the nodes the supervisor killed on request: (the time
    asked, the simulated time it did so).
    """
    reasons: list[str] = []
    plant, flight = _ticks(plant_records), _ticks(flight_records)
    if io_error:
        reasons.append(f"output could not be written: {io_error}")
    if interrupted:
        reasons.append("interrupted before the end (Ctrl-C or a signal)")
    for node, (asked, t) in (killed or {}).items():
        reasons.append(f"{node} process killed on request (--kill-flight-at {asked:g}) at "
                       f"{t:g} s")
    for node, rc in sorted((exit_codes or {}).items()):
        if rc == EXIT_OUTPUT_LOST:
            reasons.append(f"{node} process stopped: it could not write its records (disk "
                           f"full, read-only or failing); see {node}.log")
        elif rc is not None and rc not in CLEAN_EXIT_CODES and node not in (killed or {}):
            how = f"signal {-rc}" if rc < 0 else f"exit code {rc}"
            reasons.append(f"{node} process died ({how}); see {node}.log")
    if not plant:
        reasons.append("the plant never ticked")
    if not flight:
        reasons.append("the flight never ticked")
    edge = REALTIME_EDGE_TICKS if mode == "realtime" else 0
    plant_edge = REALTIME_PLANT_END_TICKS if mode == "realtime" else 0
    if plant and expected_ticks is not None and max(plant) + 1 + plant_edge < expected_ticks:
        reasons.append(f"stopped early: the plant ran {max(plant) + 1} of {expected_ticks} "
                       "ticks")
    missed = 0
    if flight:
        # Releases the flight's own grid skipped (overruns) or never reached.
        missed = (max(flight) - min(flight) + 1) - len(set(flight))
        if plant and max(flight) + edge < max(plant):
            reasons.append(f"the flight stopped at tick {max(flight)} while the plant ran to "
                           f"tick {max(plant)}")
        if plant and min(flight) > min(plant) + edge:
            reasons.append(f"the flight started at tick {min(flight)}, the plant at "
                           f"{min(plant)}")
    if missed:
        reasons.append(f"{missed} flight release(s) never ran (overrun skips or a stall)")
    return {"run_ok": not reasons, "run_failures": reasons, "missed_releases": missed}


def verdict_of(run_ok: bool, expectations_met: bool) -> str:
    if not run_ok:
        return "run_failed"
    return "passed" if expectations_met else "not_met"


def judge_summary(summary: Any) -> tuple[str, list[str]]:
    """``(verdict, reasons)`` of a ``summary.json`` read back: a summary that lacks a field,
    holds one of the wrong type, or contradicts itself is ``run_failed`` with the reason."""
    if not isinstance(summary, dict):
        return "run_failed", [f"summary: expected a JSON object, got {type(summary).__name__}"]
    reasons = []
    for key, typ in SUMMARY_REQUIRED.items():
        if key not in summary:
            reasons.append(f"summary: {key}: expected a field, got nothing")
        elif not isinstance(summary[key], typ) or (typ is int and isinstance(summary[key], bool)):
            reasons.append(f"summary: {key}: expected {typ.__name__}, got "
                           f"{type(summary[key]).__name__}")
    if reasons:
        return "run_failed", reasons
    if summary["verdict"] not in VERDICTS:
        return "run_failed", [f"summary: verdict: expected one of {list(VERDICTS)}, got "
                              f"{summary['verdict']!r}"]
    run_failures = [str(r) for r in summary["run_failures"]]
    want = verdict_of(not run_failures, summary["expectations_met"]
                      and not summary["expectation_failures"])
    if want != summary["verdict"]:
        return "run_failed", [f"summary: verdict: expected {want!r} from its failures, got "
                              f"{summary['verdict']!r}"]
    return want, run_failures + [str(f) for f in summary["expectation_failures"]]
