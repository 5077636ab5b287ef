"""Verdict of a run: detections matched to injected faults, false alarms, misses, maxima, timing.

Pure: works on the per-tick records the plant and flight processes write (``plant.jsonl``,
``flight.jsonl``, declared in ``hil.records``) and on the scenario. The fields of ``summary.json``:

``scenario, vehicle, mode, faults[{t_s, thruster, type, fraction}], detections[{t_s, thruster,
type, latency_s, correct}], false_alarms, missed_faults, max_attitude_error_deg,
max_rate_error_deg_s, fuel_kg, ticks, flight_ticks, overruns, missed_releases,
compute_ms{p50, p99, max}, bus{...}, run_failures, expectations_met, expectation_failures,
verdict`` (``passed``, ``not_met`` or ``run_failed``: see ``hil.verdict``).

A detection is *correct* when a thruster fault active at the detection time (injected at or
before it, not cleared before it) names the detected thruster (or is in the detected group)
with a compatible type: a ``degraded`` thruster reported as ``fail_to_fire`` counts (the
detector sees too little thrust in both cases). Latency is detection time minus the fault's
injection time. A fault's clear time is its scheduled ``clear_t_s`` or, when the fault panel
cleared it (``hil fault clear``), the time in the plant's ``faults_cleared`` record.

Also, where the records carry them: ``safety`` (the safe-state settings the nodes used, from
their first record's ``config``) and ``sched`` (the scheduler policy each node got, with what
``--rt`` was refused).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from hil.config import ExpectationsCfg
from hil.records import FlightRecord, PlantRecord
from hil.verdict import run_integrity, verdict_of

COMPATIBLE = {
    "stuck_on": {"stuck_on"},
    "fail_to_fire": {"fail_to_fire"},
    "degraded": {"degraded", "fail_to_fire"},
}


def _names(thruster: str | list[str]) -> list[str]:
    return [thruster] if isinstance(thruster, str) else list(thruster)


def match_detections(
    faults: list[dict[str, Any]], detections: list[dict[str, Any]]
) -> tuple[list[dict], list[dict], list[dict]]:
    """Return (detections with ``latency_s``/``correct``, false alarms, missed faults)."""
    out, false_alarms = [], []
    detected_faults: set[int] = set()
    for d in detections:
        best = None
        for k, f in enumerate(faults):
            if d["type"] == "gyro_fault":
                # A sensor fault detection names no thruster: it matches an active gyro fault.
                if str(f.get("type", "")).startswith("gyro_") and f["t_s"] <= d["t_s"] + 1e-9:
                    best = k
                    break
                continue
            if f.get("thruster") is None or f["t_s"] > d["t_s"] + 1e-9:
                continue
            # Cleared before the detection: not the fault detected. A detection at the clear
            # time still counts (computed from measurements taken while it was active).
            if f.get("clear_t_s") is not None and f["clear_t_s"] < d["t_s"] - 1e-9:
                continue
            if f["thruster"] in _names(d["thruster"]) and d["type"] in COMPATIBLE.get(
                f["type"], {f["type"]}
            ):
                best = k
                break
        row = dict(d)
        if best is None:
            row.update(latency_s=None, correct=False)
            false_alarms.append(row)
        else:
            row.update(latency_s=round(d["t_s"] - faults[best]["t_s"], 6), correct=True)
            detected_faults.add(best)
        out.append(row)
    # A fault is missed without its detection: a thruster fault, or a gyro fault (a sensor
    # fault named as a thruster is a false alarm and a missed gyro fault). Bus faults are not
    # FDIR's to find.
    missed = [
        f for k, f in enumerate(faults)
        if (f.get("thruster") is not None or str(f.get("type", "")).startswith("gyro_"))
        and k not in detected_faults
    ]
    return out, false_alarms, missed


def apply_clear(faults: list[dict[str, Any]], cleared: dict[str, Any]) -> None:
    """Give the fault a panel clear ended (same thruster, type and start) its clear time."""
    for f in faults:
        if (f.get("thruster"), f.get("type"), f.get("t_s")) == (
                cleared.get("thruster"), cleared.get("type"), cleared.get("t_on_s")) and \
                (f.get("clear_t_s") is None or f["clear_t_s"] > cleared["t_s"]):
            f["clear_t_s"] = cleared["t_s"]


def _first(records: list[dict[str, Any]], key: str) -> Any:
    """The value of ``key`` in the first record that has it ({} when none)."""
    return next((r[key] for r in records if r.get(key)), {})


def longest_excursion_s(samples: list[tuple[float, float]], band: float) -> float:
    """Longest stretch (s) of consecutive samples ``(t, value)`` with ``value > band``."""
    longest, start, prev_t = 0.0, None, None
    for t, v in samples:
        if v > band:
            if start is None:
                start = prev_t if prev_t is not None else t
            longest = max(longest, t - start)
        else:
            start = None
        prev_t = t
    return round(longest, 3)


def percentiles_ms(values_s: Iterable[float]) -> dict[str, float | None]:
    v = np.asarray(list(values_s), dtype=float)
    if v.size == 0:
        return {"p50": None, "p99": None, "max": None}
    return {
        "p50": round(float(np.percentile(v, 50)) * 1e3, 4),
        "p99": round(float(np.percentile(v, 99)) * 1e3, 4),
        "max": round(float(v.max()) * 1e3, 4),
    }


def check_expectations(summary: dict[str, Any], expect: ExpectationsCfg | None) -> list[str]:
    """Every unmet expectation as one line; empty when all hold."""
    if expect is None:
        return []
    fails = []
    for e in expect.detections:
        want = set(_names(e.thruster))
        ok = [
            d for d in summary["detections"]
            if d["correct"] and want & set(_names(d["thruster"])) and d["type"] == e.type
            and d["latency_s"] is not None and d["latency_s"] <= e.within_s + 1e-9
        ]
        if not ok:
            got = [(d["thruster"], d["type"], d["latency_s"]) for d in summary["detections"]]
            fails.append(
                f"detection of {e.thruster} {e.type} within {e.within_s} s: "
                f"expected, got {got or 'no detection'}"
            )
    if expect.no_false_alarm and summary["false_alarms"]:
        fa = [(d["thruster"], d["type"], d["t_s"]) for d in summary["false_alarms"]]
        fails.append(f"no false alarm: expected none, got {fa}")
    if expect.false_alarm_expected and not summary["false_alarms"]:
        fails.append("false alarm: expected one (demonstration run), got none")
    if expect.delta_v_B_m_s is not None:
        got = summary.get("delta_v_B_m_s")
        if got is None or any(abs(g - w) > expect.delta_v_tol_m_s
                              for g, w in zip(got, expect.delta_v_B_m_s, strict=True)):
            fails.append(f"delta-v: expected {list(expect.delta_v_B_m_s)} m/s within "
                         f"{expect.delta_v_tol_m_s}, got {got}")
    if expect.rate_band_deg_s is not None:
        got = summary.get("longest_rate_excursion_s")
        if got is None or got > expect.max_excursion_s:
            fails.append(f"rate within {expect.rate_band_deg_s} deg/s apart from excursions of "
                         f"at most {expect.max_excursion_s} s: expected, got {got} s")
    if expect.recover_after_s is not None:
        rec = summary.get("recovery")
        if rec is None:
            fails.append("recovery: expected a correct detection to recover from, got none")
        else:
            for key, limit in (("max_attitude_error_deg", expect.recovered_attitude_deg),
                               ("max_rate_error_deg_s", expect.recovered_rate_deg_s)):
                if limit is not None and (rec[key] is None or rec[key] > limit):
                    fails.append(f"recovery {key} from {rec['from_t_s']} s: expected <= "
                                 f"{limit}, got {rec[key]}")
    for key, limit in (
        ("max_attitude_error_deg", expect.max_attitude_error_deg),
        ("max_rate_error_deg_s", expect.max_rate_error_deg_s),
    ):
        if limit is not None and (summary[key] is None or summary[key] > limit):
            fails.append(f"{key}: expected <= {limit}, got {summary[key]}")
    return fails


SEEN = ("bad_crc", "wrong_length", "unknown_id", "counter_jump", "repeated_counter",
        "incomplete_set", "stale", "lost_frames")


def bus_fault_counts(plant_bus: dict[str, int], flight_bus: dict[str, int]) -> dict[str, Any]:
    """Per sending node, what its send path injected (``injected_*`` of its port counts) and
    what the other node's receiver saw (its reject classes)."""
    out: dict[str, Any] = {}
    for node, tx, rx in (("plant", plant_bus, flight_bus), ("flight", flight_bus, plant_bus)):
        out[node] = {"injected": {k[len("injected_"):]: v for k, v in tx.items()
                                  if k.startswith("injected_")},
                     "seen_by_peer": {k: rx[k] for k in SEEN if k in rx}}
    return out


def summarise(
    *,
    scenario: str,
    vehicle: str,
    mode: str,
    plant_records: list[PlantRecord],
    flight_records: list[FlightRecord],
    expect: ExpectationsCfg | None,
    extra: dict[str, Any] | None = None,
    expected_ticks: int | None = None,
    exit_codes: dict[str, int | None] | None = None,
    killed: dict[str, tuple[float, float]] | None = None,
    interrupted: bool = False,
    io_error: str | None = None,
) -> dict[str, Any]:
    """Build ``summary.json`` from the per-tick records of both processes.

    The run's integrity (``hil.verdict.run_integrity``: both processes ticked to the end,
    none died, no release lost) is judged first; a failed run is ``verdict: run_failed``
    with its ``run_failures`` and never counts its expectations as met."""
    faults: list[dict[str, Any]] = []
    for r in plant_records:
        faults.extend(dict(f) for f in r.get("faults_injected", []))
        for c in r.get("faults_cleared", []):
            apply_clear(faults, c)
    for r in flight_records:  # the flight's own bus faults (its send path)
        faults.extend(dict(f) for f in r.get("faults_injected", []))
    faults.sort(key=lambda f: f["t_s"])
    detections: list[dict[str, Any]] = []
    for r in flight_records:
        if r.get("detection"):
            detections.append(r["detection"])
    matched, false_alarms, missed = match_detections(faults, detections)

    settle = expect.settle_after_s if expect else 0.0
    att = [r["att_err_deg"] for r in plant_records if "att_err_deg" in r and r["t_s"] >= settle]
    rate = [r["rate_err_deg_s"] for r in plant_records
            if "rate_err_deg_s" in r and r["t_s"] >= settle]
    compute = [r["compute_s"] for r in flight_records if "compute_s" in r]
    jitter = [r["jitter_s"] for r in flight_records if r.get("jitter_s") is not None]
    last_plant = plant_records[-1] if plant_records else {}
    last_flight = flight_records[-1] if flight_records else {}
    summary: dict[str, Any] = {
        "scenario": scenario,
        "vehicle": vehicle,
        "mode": mode,
        "faults": [
            {k: f.get(k) for k in ("t_s", "thruster", "type", "fraction", "clear_t_s")
             + (("node", "message") if "node" in f else ())}
            for f in faults
        ],
        "detections": matched,
        "false_alarms": false_alarms,
        "missed_faults": missed,
        "max_attitude_error_deg": round(max(att), 6) if att else None,
        "max_rate_error_deg_s": round(max(rate), 6) if rate else None,
        "fuel_kg": last_plant.get("fuel_kg"),
        "ticks": len(plant_records),
        "flight_ticks": len(flight_records),
        "overruns": int(last_flight.get("overruns", 0)),
        "compute_ms": percentiles_ms(compute),
        "release_jitter_ms": percentiles_ms(jitter) if jitter else None,
        "bus": {"plant": last_plant.get("bus", {}), "flight": last_flight.get("bus", {})},
        # bus faults: injected by each node's send path, seen by the other node's receiver
        "bus_faults": bus_fault_counts(last_plant.get("bus", {}), last_flight.get("bus", {})),
        # real time: THR_CMD the plant applied (fresh) or dropped, by class
        "command_gate": next((r["command_gate"] for r in reversed(plant_records)
                              if r.get("command_gate")), None),
        "safe_events": [e for r in plant_records + flight_records for e in r.get("events", [])
                        if "safe" in e or "lost" in e],
        # what the FDIR did about its detections (process runs: hil.records.fdir_actions)
        "fdir_actions": [a for r in flight_records for a in r.get("fdir_actions", [])],
    }
    if "pulse_tests" in last_flight:
        summary["pulse_tests"] = dict(last_flight["pulse_tests"])
    safety = {**_first(plant_records, "config").get("safety", {}),
              **_first(flight_records, "config").get("safety", {})}
    if safety:
        summary["safety"] = safety
    sched = {k: _first(recs, "sched") or None
             for k, recs in (("plant", plant_records), ("flight", flight_records))}
    if any(sched.values()):
        summary["sched"] = sched
    last_dv = next((r["dv_B_m_s"] for r in reversed(plant_records) if "dv_B_m_s" in r), None)
    summary["delta_v_B_m_s"] = None if last_dv is None else [round(float(x), 4) for x in last_dv]
    if expect is not None and expect.rate_band_deg_s is not None:
        summary["longest_rate_excursion_s"] = longest_excursion_s(
            [(r["t_s"], r["rate_err_deg_s"]) for r in plant_records
             if "rate_err_deg_s" in r and r["t_s"] >= settle], expect.rate_band_deg_s)
    if expect is not None and expect.recover_after_s is not None:
        first = next((d for d in matched if d["correct"]), None)
        if first is not None:
            t_from = first["t_s"] + expect.recover_after_s
            after = [r for r in plant_records if "att_err_deg" in r and r["t_s"] >= t_from]
            summary["recovery"] = {
                "from_t_s": round(t_from, 3),
                "max_attitude_error_deg": round(max(r["att_err_deg"] for r in after), 6)
                if after else None,
                "max_rate_error_deg_s": round(max(r["rate_err_deg_s"] for r in after), 6)
                if after else None,
            }
    if extra:
        summary.update(extra)
    integrity = run_integrity(
        mode=mode, plant_records=plant_records, flight_records=flight_records,
        expected_ticks=expected_ticks, exit_codes=exit_codes, killed=killed,
        interrupted=interrupted, io_error=io_error)
    summary["missed_releases"] = integrity["missed_releases"]
    summary["run_failures"] = integrity["run_failures"]
    fails = check_expectations(summary, expect)
    summary["expectations_met"] = not fails and integrity["run_ok"]
    summary["expectation_failures"] = fails
    summary["verdict"] = verdict_of(integrity["run_ok"], not fails)
    return summary
