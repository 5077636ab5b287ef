"""Telemetry on LCM, whatever the control bus (docs/lcm.md).

Each process publishes its per-tick record as it writes it (``hil.node_shell.write_record``):
the plant a ``hil_telemetry.truth_t`` on ``HIL_TRUTH``, the flight a
``hil_telemetry.flight_view_t`` on ``HIL_FLIGHT_VIEW`` (types in ``hil/lcm/*.lcm``, Python by
``lcm-gen`` in ``hil/hil_telemetry/``). The values are those of ``plant.jsonl`` /
``flight.jsonl``, so ``lcm-logger`` records a run and ``lcm-spy`` shows it live.

A publish that fails (a full socket buffer) is counted in ``failed`` and never stops a tick.
"""

from __future__ import annotations

import time

from hil.hil_telemetry import flight_view_t, truth_t

TRUTH_CHANNEL = "HIL_TRUTH"
FLIGHT_CHANNEL = "HIL_FLIGHT_VIEW"


def _flat_series(rec: dict) -> tuple[list[str], list[float]]:
    names, values = [], []
    for path, labels in (rec.get("series") or {}).items():
        for label, v in labels.items():
            if v is None:
                continue
            names.append(f"{path}/{label}")
            values.append(float(v))
    return names, values


def truth_message(rec: dict) -> truth_t:
    m = truth_t()
    m.utime = time.time_ns() // 1000
    m.tick, m.t_s = int(rec["tick"]), float(rec["t_s"])
    m.att_err_deg = float(rec.get("att_err_deg", float("nan")))
    m.rate_err_deg_s = float(rec.get("rate_err_deg_s", float("nan")))
    m.fuel_kg = float(rec.get("fuel_kg", float("nan")))
    m.dv_B_m_s = [float(x) for x in rec.get("dv_B_m_s", [float("nan")] * 3)]
    m.safe = bool(rec.get("safe", False))
    m.names, m.values = _flat_series(rec)
    m.n_values = len(m.names)
    m.events = [str(e) for e in rec.get("events", [])]
    m.n_events = len(m.events)
    return m


def flight_view_message(rec: dict) -> flight_view_t:
    m = flight_view_t()
    m.utime = time.time_ns() // 1000
    m.tick, m.t_s = int(rec["tick"]), float(rec["t_s"])
    c = rec.get("compute_s")
    m.compute_s = -1.0 if c is None else float(c)
    m.overruns = int(rec.get("overruns", 0))
    m.safe = bool(rec.get("safe", False))
    d = rec.get("detection")
    if d:
        th = d.get("thruster")
        m.detection_type = str(d["type"])
        m.detection_thruster = "|".join(th) if isinstance(th, list) else (th or "")
        m.detection_source = str(d.get("source", ""))
        m.detection_rho = float(d.get("rho", 0.0))
    else:
        m.detection_type = m.detection_thruster = m.detection_source = ""
        m.detection_rho = 0.0
    m.names, m.values = _flat_series(rec)
    m.n_values = len(m.names)
    m.events = [str(e) for e in rec.get("events", [])]
    m.n_events = len(m.events)
    return m


class Telemetry:
    """One process's telemetry publisher (``node``: ``plant`` or ``flight``)."""

    def __init__(self, node: str, url: str, lc=None) -> None:
        from bus.lcm_transport import open_lcm

        self.node = node
        self.url = url
        self.lc = lc if lc is not None else open_lcm(url)
        self.published = 0
        self.failed = 0
        self.bytes = 0

    def publish(self, rec: dict) -> None:
        if self.node == "plant":
            channel, msg = TRUTH_CHANNEL, truth_message(rec)
        else:
            channel, msg = FLIGHT_CHANNEL, flight_view_message(rec)
        data = msg.encode()
        try:
            self.lc.publish(channel, data)
        except (OSError, RuntimeError):
            self.failed += 1
            return
        self.published += 1
        self.bytes += len(data)
