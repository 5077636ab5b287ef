"""The per-tick records, declared once: what the process shells write (``plant.jsonl``,
``flight.jsonl``) and the in-process run (``hil.sim``) keeps, and what the summary, the report,
the bench and the recorder read. Units are in the field names (``_s`` seconds, ``_deg`` degrees,
``_deg_s`` deg/s, ``_kg``, ``_m_s`` m/s, ``_ms`` milliseconds); body axes B.

The fields both writers share are built here (``truth_fields``, ``detection_record``,
``newly_active_faults``), so the in-process records equal the processes' by construction. A
record also carries ``series`` (``{entity path: {label: value}}``, the rerun time series,
listed in ``hil.recorder``) and ``events`` (text lines); the processes add the fields of their
own clock and bus (``bus``, ``compute_s``, ``jitter_s``...).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any, NotRequired, TypedDict

import numpy as np

from common.units import DEG


class FaultEvent(TypedDict):
    """A fault that became active (``faults_injected``): its start ``t_s``, the thruster (None
    for gyro and bus faults), the kind, the thrust fraction it leaves and its scheduled end."""

    t_s: float
    thruster: str | None
    type: str
    fraction: float
    clear_t_s: float | None
    node: NotRequired[str]  # bus faults: the node whose send path has it
    message: NotRequired[str | None]  # bus faults: the message it is limited to (None: all)


class DetectionRecord(TypedDict):
    """A detection the flight raised at tick ``tick`` (``t_s`` = tick x tick length): the
    thruster, or the group it cannot tell apart; the kind; which test (``source``); its
    integral residual ``rho``."""

    t_s: float
    tick: int
    thruster: str | list[str] | None  # None: a gyro fault (no thruster named)
    type: str
    source: str
    rho: float
    fraction: NotRequired[float]  # degraded: the estimated thrust fraction
    gyro: NotRequired[str]  # gyro_fault: which error (spike, bias step, frozen, noise)


class TruthFields(TypedDict):
    """The plant's truth at the end of a tick: attitude error to the target and rate error
    (relative to the orbit frame), fuel used by every thruster, thrust delta-v in body axes."""

    att_err_deg: float
    rate_err_deg_s: float
    fuel_kg: float
    dv_B_m_s: list[float]


class PlantRecord(TruthFields):
    """One ``plant.jsonl`` line (``t_s`` the plant's time at the end of tick ``tick``)."""

    tick: int
    t_s: float
    faults_injected: list[FaultEvent]
    faults_cleared: NotRequired[list[dict[str, Any]]]
    series: NotRequired[dict[str, dict[str, float]]]
    events: NotRequired[list[str]]
    safe: NotRequired[bool]
    # real time: THR_CMD by the plant's freshness verdict (hil.safe_states.CommandGate),
    # fresh / stale / out_of_order / unknown_sample, counted since the start
    command_gate: NotRequired[dict[str, int]]
    bus: NotRequired[dict[str, int]]
    # THR_CMD applied as received during this tick, [tick, total on-time ms] each (not the
    # held or safe ones): compared with the flight's ``thr_cmd_on_ms``, a command the flight
    # never sent shows (``hil.hostile.forged_used``)
    thr_cmd_applied: NotRequired[list[list[int]]]
    # The last line only: the loop's wall and CPU time, when it started (CLOCK_MONOTONIC).
    final: NotRequired[bool]
    wall_s: NotRequired[float]
    cpu_s: NotRequired[float | None]
    loop_t0_monotonic_s: NotRequired[float | None]


class FlightRecord(TypedDict):
    """One ``flight.jsonl`` line (``t_s`` = the flight tick's time)."""

    tick: int
    t_s: float
    detection: DetectionRecord | None
    series: NotRequired[dict[str, dict[str, float]]]
    events: NotRequired[list[str]]
    compute_s: NotRequired[float]
    stage_s: NotRequired[dict[str, float]]
    jitter_s: NotRequired[float | None]
    overruns: NotRequired[int]
    safe: NotRequired[bool]
    thr_cmd_on_ms: NotRequired[int]
    bus: NotRequired[dict[str, int]]
    # Process runs: the FDIR's state and configuration (``fdir_view``) and what it changed
    # this tick (``fdir_actions``: manifolds closed, thrusters dropped, given back).
    fdir: NotRequired[dict[str, Any]]
    fdir_actions: NotRequired[list[dict[str, Any]]]
    # ticks so far the detector took no evidence from (no fresh gyro sample, or the plant
    # did not apply the last command); bus faults of the flight's send path that started
    no_evidence_ticks: NotRequired[int]
    # ticks so far whose gyro sample was clipped to the GYRO range (hil.binding.saturated)
    gyro_saturated_ticks: NotRequired[int]
    # with test pulses configured: the tests so far (FlightSoftware.pulse_tests)
    pulse_tests: NotRequired[dict[str, int]]
    faults_injected: NotRequired[list[FaultEvent]]


def fdir_view(out, names: Sequence[str], manifold_names: Sequence[str],
              manifold_of: Sequence[str]) -> dict[str, Any]:
    """The FDIR block of a flight record: state, closed manifolds, unavailable thrusters and,
    of those, the ones dropped (their manifold open; none in safe mode, where all are off).
    ``manifold_of``: each thruster's manifold name."""
    closed = [m for m, o in zip(manifold_names, out.manifold_open, strict=True) if not o]
    off = [n for n, a in zip(names, out.available, strict=True) if not a]
    safe = str(out.fdir_state) == "safe"
    return {"state": str(out.fdir_state), "closed_manifolds": closed, "unavailable": off,
            "dropped": [] if safe else [n for n, m in zip(names, manifold_of, strict=True)
                                        if n in off and m not in closed]}


def fdir_actions(before: dict[str, Any] | None, now: dict[str, Any],
                 t_s: float) -> list[dict[str, Any]]:
    """What the FDIR changed between two ``fdir_view`` blocks: ``manifold_closed`` /
    ``manifold_opened`` (a manifold) and ``thruster_dropped`` / ``thruster_restored`` (a
    thruster whose manifold stays open). Safe mode (every thruster off) is its own state,
    not a drop of each thruster."""
    if before is None:
        return []
    acts = []
    for m in now["closed_manifolds"]:
        if m not in before["closed_manifolds"]:
            acts.append({"t_s": t_s, "action": "manifold_closed", "manifold": m})
    for m in before["closed_manifolds"]:
        if m not in now["closed_manifolds"]:
            acts.append({"t_s": t_s, "action": "manifold_opened", "manifold": m})
    if "safe" not in (before["state"], now["state"]):
        dropped = now.get("dropped", [])
        was = before.get("dropped", [])
        acts += [{"t_s": t_s, "action": "thruster_dropped", "thruster": n}
                 for n in dropped if n not in was]
        acts += [{"t_s": t_s, "action": "thruster_restored", "thruster": n}
                 for n in was if n not in dropped]
    return acts


def fdir_action_text(a: dict[str, Any]) -> str:
    what = f"manifold {a['manifold']}" if "manifold" in a else f"thruster {a['thruster']}"
    verb = a["action"].split("_", 1)[1]
    return f"fdir: {what} {verb} at {a['t_s']:.1f} s"


def truth_fields(truth, err_q: np.ndarray) -> TruthFields:
    """``TruthFields`` of a ``plant.core.Truth`` and its error quaternion to the target."""
    from flight.attitude import rotation_angle

    return {
        "att_err_deg": float(rotation_angle(err_q) * DEG),
        "rate_err_deg_s": float(np.linalg.norm(truth.omega_BO_B_rad_s) * DEG),
        "fuel_kg": float(np.sum(truth.fuel_kg)),
        "dv_B_m_s": [float(x) for x in truth.dv_B_m_s],
    }


def detection_record(det, tick: int, tick_s: float, thruster_names: Sequence[str],
                     t_s: float | None = None) -> DetectionRecord:
    """The record of a ``flight.detector.Detection`` raised at ``tick``; ``t_s`` its time on
    the plant's clock (default ``tick * tick_s``: lockstep and in-process runs, where the two
    agree)."""
    names = [thruster_names[i] for i in det.group]
    rec: DetectionRecord = {
        "t_s": round(tick * tick_s if t_s is None else t_s, 6), "tick": tick,
        "thruster": (names[0] if len(names) == 1 else names) if names else None,
        "type": det.kind, "source": det.source, "rho": float(det.rho)}
    if getattr(det, "fraction", None) is not None:  # degraded: the estimated thrust fraction
        rec["fraction"] = round(float(det.fraction), 4)
    if det.kind == "gyro_fault":  # a sensor fault: which gyro error, no thruster
        rec["gyro"] = det.names[0]
    return rec


def newly_active_faults(entries: Iterable[Any], reported: set[int],
                        t_s: float) -> list[FaultEvent]:
    """The plant's fault entries active by ``t_s`` and not yet in ``reported`` (which is
    updated): the ``faults_injected`` field."""
    out: list[FaultEvent] = []
    for e in entries:
        if e.id not in reported and e.t_on_s <= t_s + 1e-9:
            reported.add(e.id)
            out.append({"t_s": round(e.t_on_s, 6), "thruster": e.spec.thruster,
                        "type": e.spec.kind, "fraction": e.spec.effective_fraction,
                        "clear_t_s": None if math.isinf(e.t_off_s) else e.t_off_s})
    return out
