"""Verdict of one run, and the campaign's statistics over the rows.

One run (``classify``), from the run's summary (``hil.summary.summarise``), read generically:
a detection is a type string and a thruster name or a list of names ("one of {i, j}"), judged
correct or not by the summary itself, so new detection types need nothing here.

* fault-free run: ``pass`` (no detection) or ``false_alarm``;
* run with a fault: ``detected`` (a correct detection; ``detected_as`` ``exact`` or ``group``
  when it named a group holding the thruster), ``unobservable`` (no correct detection, and a
  fault that needs its thruster commanded, such as fails-to-fire, whose thruster was never
  commanded after the fault: nothing could be seen; and a stuck-on whose thruster was
  commanded on for the whole tick at every tick after the fault: its valve was open anyway),
  ``misidentified`` (detections after the fault, none correct), ``missed`` (no detection after
  the fault), ``unjudged`` (the summary does not judge this fault: it has no thruster).
  Detections before the fault time are counted as ``false_alarms_before_fault``;
  ``wrong_first``: the first detection after the fault is not a correct one (a detected run
  whose right detection came after a wrong one: a gyro fault named a thruster first);
* ``error`` (the run raised; ``error`` holds it) and ``incomplete`` (the summary lacks ticks,
  the fault or a field; ``reason`` says which): failures, never a pass, left out of every rate
  and counted.

Rates (``campaign_statistics``), per vehicle and fault class (the fault kind; ``none`` for
fault-free runs), each with its exact Clopper-Pearson 95 % interval:

* false-alarm rate: fault-free runs with at least one detection / completed fault-free runs;
* missed-detection rate: observable fault runs without a correct detection / observable fault
  runs (unobservable runs are counted apart and said so);
* latency (fault time to the first correct detection): p50, p90, max over detected runs;
* degraded: the named thrust fraction against the injected one, |error| p50 / p90 / max,
  its mean signed error, and the share of observable runs detected with it within
  ``FRACTION_TOL`` (the goal's "fraction within +/-0.1");
* for faults seen only when their thruster fires (fails to fire, degraded), also the rate and
  latency the FDIR goal states (issue 12): among runs whose thruster was commanded on at least
  ``GOAL_COMMANDED_TICKS`` ticks after the fault, or detected before that many (the response
  drops the thruster: its commands stop at the detection; ``detected_sooner`` counts them),
  the detection rate, and the latency from the first command acting after the fault
  (``latency_from_command_s``), p50 / p90 / max;
* for a stuck-on fault, which shows only while its valve is meant to be closed, the mirror
  of that: among runs whose thruster was commanded closed for part or all of at least
  ``GOAL_COMMANDED_TICKS`` ticks after the fault, or detected before that many, the detection
  rate and the latency from the first closed time after the fault (``latency_from_closed_s``):
  a slew that holds the stuck thruster open for seconds shows nothing until it closes it.

The confusion matrix counts, for fault runs, the injected (thruster, kind) against what the
first detection after the fault named: a thruster, a group (its own column, "one of {...}"),
or none. Unobservable runs are not in it (counted apart).
"""

from __future__ import annotations

from collections import Counter, defaultdict
from typing import Any

import numpy as np

from hil.verdict import judge_summary

VERDICTS = ("pass", "false_alarm", "detected", "unobservable", "misidentified", "missed",
            "unjudged", "error", "incomplete")
FAILED = ("error", "incomplete")
# The fails-to-fire goal counts runs whose thruster was commanded on this many ticks or more
# after the fault (fewer firings may carry too little evidence).
GOAL_COMMANDED_TICKS = 3
# The degraded goal: detected as degraded with the thrust fraction within this of the truth.
FRACTION_TOL = 0.1
_EPS = 1e-9


def clopper_pearson(k: int, n: int, confidence: float = 0.95) -> tuple[float, float] | None:
    """Exact binomial interval for k successes in n trials (None when n is 0)."""
    if n <= 0:
        return None
    from scipy.stats import binomtest

    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=confidence, method="exact")
    return (float(ci.low), float(ci.high))


def _names(thruster: Any) -> list[str]:
    if thruster is None:
        return []
    return [thruster] if isinstance(thruster, str) else [str(t) for t in thruster]


def label(thruster: Any) -> str:
    """A detection's thruster as people read it: ``7`` or ``one of {7, 9}``."""
    names = _names(thruster)
    if not names:
        return "the gyro"  # a sensor fault names no thruster
    return names[0] if len(names) == 1 else "one of {" + ", ".join(names) + "}"


def _incomplete(spec: Any, s: dict[str, Any]) -> str | None:
    verdict, reasons = judge_summary(s)  # the run's own integrity (hil.verdict)
    if verdict == "run_failed":
        return "; ".join(reasons) or "run failed"
    for key in ("detections", "false_alarms", "missed_faults", "faults", "ticks",
                "max_attitude_error_deg", "fuel_kg"):
        if key not in s or s[key] is None:
            return f"summary field {key} missing"
    if s["ticks"] != spec.n_ticks:
        return f"{s['ticks']} plant ticks of {spec.n_ticks}"
    if s.get("flight_ticks", spec.n_ticks) != spec.n_ticks:
        return f"{s['flight_ticks']} flight ticks of {spec.n_ticks}"
    f = spec.fault
    if f is not None and f["t_s"] < spec.scenario["duration_s"]:
        seen = [g for g in s["faults"] if abs((g.get("t_s") or -1) - f["t_s"]) < 1e-6
                and g.get("type") == f["kind"] and g.get("thruster") == f.get("thruster")]
        if not seen:
            return f"the fault {f['kind']} {f.get('thruster')} at {f['t_s']} s is not in the " \
                   f"summary's faults"
    for d in s["detections"]:
        # A sensor fault names no thruster (FDIR_STATUS gyro_fault); every other type does.
        needs_thruster = d.get("type") != "gyro_fault"
        if not isinstance(d.get("type"), str) or not isinstance(d.get("t_s"), (int, float)) \
                or (needs_thruster and not _names(d.get("thruster"))):
            return f"a detection without type, thruster or time: {d}"
    return None


def classify(spec: Any, summary: dict[str, Any] | None, *, commanded_after: bool | None = None,
             error: str | None = None, commanded_ticks: int | None = None,
             first_command_s: float | None = None,
             open_throughout: bool | None = None, closed_ticks: int | None = None,
             first_closed_s: float | None = None) -> dict[str, Any]:
    """The row of one run (module doc); ``spec`` is its ``RunSpec``. ``commanded_ticks`` and
    ``first_command_s``: ticks with the faulty thruster commanded after the fault and the time
    the first of them acted (faults seen only when their thruster fires); ``open_throughout``:
    a stuck-on thruster commanded on for the whole of every tick after the fault;
    ``closed_ticks`` and ``first_closed_s``: for a stuck-on fault, ticks with its valve meant
    closed for part or all of the tick after the fault and the time the first closed time
    began."""
    f = spec.fault
    row: dict[str, Any] = {
        "run": spec.run, "name": spec.name, "vehicle": spec.vehicle["name"],
        "fault_class": f["kind"] if f else "none",
        "fault": f, "params": spec.params, "verdict": None, "reason": None, "error": error,
        "detections": [], "false_alarms": 0, "false_alarms_before_fault": 0,
        "latency_s": None, "detected_as": None, "named": None, "wrong_first": None,
        "commanded_after_fault": commanded_after, "commanded_ticks_after_fault": commanded_ticks,
        "first_command_after_fault_s": first_command_s, "latency_from_command_s": None,
        "closed_ticks_after_fault": closed_ticks, "first_closed_after_fault_s": first_closed_s,
        "latency_from_closed_s": None,
        "fraction_error": None,
        "max_attitude_error_deg": None,
        "max_rate_error_deg_s": None, "fuel_kg": None, "sim_s": None, "pulse_tests": None,
    }
    if error is not None or summary is None:
        row["verdict"] = "error"
        row["error"] = error or "no summary"
        return row
    reason = _incomplete(spec, summary)
    if reason is not None:
        row.update(verdict="incomplete", reason=reason)
        return row
    dets = [{k: d.get(k) for k in ("t_s", "thruster", "type", "source", "latency_s", "correct",
                                   "fraction")}
            for d in summary["detections"]]
    row.update(detections=dets, false_alarms=len(summary["false_alarms"]),
               max_attitude_error_deg=summary["max_attitude_error_deg"],
               max_rate_error_deg_s=summary["max_rate_error_deg_s"],
               fuel_kg=summary["fuel_kg"], sim_s=summary.get("sim_s"),
               pulse_tests=summary.get("pulse_tests"))
    if f is None:
        row["verdict"] = "false_alarm" if dets else "pass"
        return row
    t_f = f["t_s"]
    before = [d for d in dets if d["t_s"] < t_f - _EPS]
    after = [d for d in dets if d["t_s"] >= t_f - _EPS]
    row["false_alarms_before_fault"] = len(before)
    if after:
        row["named"] = f"{label(after[0]['thruster'])} {after[0]['type']}"
    correct = [d for d in after if d.get("correct")]
    row["wrong_first"] = bool(after) and not after[0].get("correct")
    judged = any(g.get("thruster") == f.get("thruster") and g.get("type") == f["kind"]
                 for g in summary["missed_faults"]) or bool(correct)
    if correct:
        d = correct[0]
        row.update(verdict="detected", latency_s=d["latency_s"],
                   detected_as="exact" if len(_names(d["thruster"])) == 1 else "group")
        if f["kind"] == "degraded" and d.get("fraction") is not None \
                and f.get("fraction") is not None:
            row["fraction_error"] = round(float(d["fraction"]) - float(f["fraction"]), 6)
        if first_command_s is not None:
            row["latency_from_command_s"] = round(d["t_s"] - first_command_s, 6)
        if first_closed_s is not None:
            row["latency_from_closed_s"] = round(d["t_s"] - first_closed_s, 6)
    elif not judged:
        row["verdict"] = "unjudged"
        row["reason"] = "the summary does not judge this fault (no thruster)"
    elif commanded_after is False:
        row["verdict"] = "unobservable"
        row["reason"] = "the thruster was never commanded after the fault"
    elif open_throughout and f["kind"] == "stuck_on":
        row["verdict"] = "unobservable"
        row["reason"] = "the thruster was commanded on for the whole of every tick after the " \
                        "fault (its valve was open anyway)"
    elif after:
        row["verdict"] = "misidentified"
    else:
        row["verdict"] = "missed"
    return row


def _pct(values: list[float]) -> dict[str, Any]:
    if not values:
        return {"n": 0, "p50": None, "p90": None, "max": None}
    v = np.asarray(values, dtype=float)
    return {"n": int(v.size), "p50": round(float(np.percentile(v, 50)), 3),
            "p90": round(float(np.percentile(v, 90)), 3), "max": round(float(v.max()), 3)}


def _rate(k: int, n: int) -> dict[str, Any]:
    ci = clopper_pearson(k, n)
    return {"k": k, "n": n, "rate": round(k / n, 6) if n else None,
            "ci95": None if ci is None else [round(ci[0], 6), round(ci[1], 6)]}


def _evidence_goal(obs: list[dict[str, Any]], ticks: str, latency: str
                   ) -> dict[str, Any] | None:
    """The goal's population over the observable rows ``obs``: those with ``GOAL_COMMANDED_TICKS``
    or more ticks of evidence (row field ``ticks``), and those detected before that many (the
    response ends the evidence); their detection rate and the latency field ``latency``.
    None when no row counts its evidence (an older campaign, or a fault of another kind)."""
    if not any(r.get(ticks) is not None for r in obs):
        return None
    early = [r for r in obs if r["verdict"] == "detected"
             and (r.get(ticks) or 0) < GOAL_COMMANDED_TICKS]
    goal = [r for r in obs if (r.get(ticks) or 0) >= GOAL_COMMANDED_TICKS] + early
    gdet = [r for r in goal if r["verdict"] == "detected"]
    return {"min_ticks": GOAL_COMMANDED_TICKS, "detected_sooner": len(early),
            "detection": _rate(len(gdet), len(goal)),
            latency: _pct([r[latency] for r in gdet if r.get(latency) is not None])}


def campaign_statistics(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Rates, intervals, latencies and confusion counts per vehicle and fault class."""
    by_vehicle: dict[str, dict[str, list[dict]]] = defaultdict(lambda: defaultdict(list))
    for r in rows:
        by_vehicle[r["vehicle"]][r["fault_class"]].append(r)
    out: dict[str, Any] = {}
    for veh, classes in sorted(by_vehicle.items()):
        vstats: dict[str, Any] = {}
        for cls, rs in sorted(classes.items()):
            verdicts = Counter(r["verdict"] for r in rs)
            done = [r for r in rs if r["verdict"] not in FAILED]
            st: dict[str, Any] = {"runs": len(rs), "completed": len(done),
                                  "verdicts": dict(sorted(verdicts.items()))}
            if cls == "none":
                st["false_alarm"] = _rate(verdicts["false_alarm"], len(done))
                st["first_false_alarm_s"] = _pct(
                    [r["detections"][0]["t_s"] for r in done if r["detections"]])
                # Pointing: each fault-free run's largest attitude error against its target.
                st["max_attitude_error_deg"] = _pct(
                    [r["max_attitude_error_deg"] for r in done
                     if r.get("max_attitude_error_deg") is not None])
            else:
                judged = [r for r in done if r["verdict"] != "unjudged"]
                obs = [r for r in judged if r["verdict"] != "unobservable"]
                det = [r for r in obs if r["verdict"] == "detected"]
                st["unobservable"] = verdicts["unobservable"]
                st["observable"] = len(obs)
                st["missed_detection"] = _rate(len(obs) - len(det), len(obs))
                st["detection"] = _rate(len(det), len(obs))
                st["detected_exact"] = sum(r["detected_as"] == "exact" for r in det)
                st["detected_group"] = sum(r["detected_as"] == "group" for r in det)
                st["misidentified"] = verdicts["misidentified"]
                # Detected, but a wrong detection came first (the confusion matrix's column).
                st["wrong_first"] = sum(bool(r.get("wrong_first")) for r in det)
                st["latency_s"] = _pct([r["latency_s"] for r in det])
                st["false_alarm_before_fault"] = _rate(
                    sum(r["false_alarms_before_fault"] > 0 for r in done), len(done))
                if cls == "degraded":
                    # The goal: named degraded with the thrust fraction within FRACTION_TOL.
                    errs = [r["fraction_error"] for r in det
                            if r.get("fraction_error") is not None]
                    st["fraction_error"] = {
                        **_pct([abs(e) for e in errs]),
                        "within_tolerance": _rate(
                            sum(abs(e) <= FRACTION_TOL for e in errs), len(obs)),
                        "tolerance": FRACTION_TOL,
                        "mean_signed": None if not errs else round(float(np.mean(errs)), 4)}
                # A run detected before the thruster's third command is in it too: the
                # response drops the thruster, so its commands stop at the detection (a test
                # pulse names a thruster that failed after one burn and one pulse).
                for key, ticks, lat in (("commanded_goal", "commanded_ticks_after_fault",
                                         "latency_from_command_s"),
                                        ("closed_goal", "closed_ticks_after_fault",
                                         "latency_from_closed_s")):
                    goal = _evidence_goal(obs, ticks, lat)
                    if goal is not None:
                        st[key] = goal
            tested = [r["pulse_tests"] for r in done if r.get("pulse_tests")]
            if tested:
                # What the test pulses cost (the controller waits on their ticks) and found.
                st["pulse_tests"] = {
                    "runs_with_tests": sum(t["started"] > 0 for t in tested),
                    **{k: sum(t[k] for t in tested)
                       for k in ("started", "healthy", "named", "void")},
                    "wait_ticks_per_run": _pct([t["ticks"] for t in tested])}
            vstats[cls] = st
        fault_rows = [r for rs in classes.values() for r in rs
                      if r["fault_class"] != "none" and r["verdict"] not in FAILED]
        if fault_rows:
            obs = [r for r in fault_rows if r["verdict"] not in ("unobservable", "unjudged")]
            det = [r for r in obs if r["verdict"] == "detected"]
            vstats["all_faults"] = {
                "runs": len(fault_rows), "observable": len(obs),
                "missed_detection": _rate(len(obs) - len(det), len(obs)),
                "latency_s": _pct([r["latency_s"] for r in det])}
        out[veh] = vstats
    return {"by_vehicle": out, "confusion": confusion(rows),
            "failures": [{"run": r["run"], "verdict": r["verdict"],
                          "why": r["error"] or r["reason"]}
                         for r in rows if r["verdict"] in FAILED]}


def confusion(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per vehicle: counts of (injected thruster and kind, what the first detection after the
    fault named), groups as their own labels; and the same by kind only."""
    out: dict[str, Any] = {}
    for veh in sorted({r["vehicle"] for r in rows}):
        full: Counter = Counter()
        kinds: Counter = Counter()
        for r in rows:
            f = r["fault"]
            if r["vehicle"] != veh or f is None or r["verdict"] in (*FAILED, "unobservable"):
                continue
            injected = f"{f.get('thruster')} {f['kind']}"
            named = r["named"] or "none"
            full[(injected, named)] += 1
            if r["named"] is None:
                kind_named = "none"
            else:
                ty = r["named"].rsplit(" ", 1)[-1]
                who = r["named"].rsplit(" ", 1)[0]
                if who == str(f.get("thruster")):
                    kind_named = f"{ty} (right thruster)"
                elif who.startswith("one of {") and str(f.get("thruster")) in \
                        who[8:-1].split(", "):
                    kind_named = f"{ty} (group holding it)"
                else:
                    kind_named = f"{ty} (other thruster)"
            kinds[(f["kind"], kind_named)] += 1
        out[veh] = {
            "by_thruster": [{"injected": a, "named": b, "runs": n}
                            for (a, b), n in sorted(full.items())],
            "by_kind": [{"injected": a, "named": b, "runs": n}
                        for (a, b), n in sorted(kinds.items())],
        }
    return out


def worst_runs(rows: list[dict[str, Any]], n: int = 10) -> list[dict[str, Any]]:
    """The runs a reviewer looks at first: failures, false alarms (earliest first), missed and
    misidentified faults, the longest latencies, then the largest attitude errors."""
    def key(r: dict[str, Any]) -> tuple:
        v = r["verdict"]
        if v in FAILED:
            return (0, r["run"])
        if v == "false_alarm":
            return (1, r["detections"][0]["t_s"], r["run"])
        if v in ("missed", "misidentified"):
            return (2, r["run"])
        if r["false_alarms_before_fault"]:
            return (3, r["run"])
        if v == "detected":
            return (4, -(r["latency_s"] or 0.0), r["run"])
        return (5, -(r["max_attitude_error_deg"] or 0.0), r["run"])
    return sorted(rows, key=key)[:n]
