"""`hil report`: a one-minute report from run folders (Markdown table and PNG plots).

``hil report DIR... [--out REPORT_DIR]`` reads each run folder written by ``hil run``
(``summary.json``, ``plant.jsonl``, ``flight.jsonl``; see ``hil.recorder``) and writes
``REPORT_DIR/report.md``, ``REPORT_DIR/report.json`` (the table rows) and, per scenario, PNGs
named ``<scenario>_<plot>.png``. A DIR without ``summary.json`` whose sub-folders have one stands
for those sub-folders (``hil report runs``). Exit 0 when every run met its expectations, 1 when
one did not, 2 when a folder is missing or its summary unreadable. ``write_report`` does the same
from code (``hil run-all``).

How to read it
--------------
The table has one row per injected thruster fault (one row for a run without one: "no fault",
or its gyro/bus faults, which name no thruster):
fault time, the detection that answered it (time, thruster and type named), latency = detection
time minus fault time, the seed's latency (the scenario's
``expect.detections[].seed_latency_s``, "-" where the seed gives no figure; the verdict uses
``within_s``), whether the named thruster and type are right (a group "one of {i, j}" counts
when it holds the faulted thruster, docs/design.md 6.4), false alarms, the largest attitude error
and the verdict of the run's expectations (failures listed under the table). A fault answered
only by a wrong detection shows that detection with correct = NO; none at all shows
MISSED.

Per scenario, in every plot: a red vertical line marks a fault, green a correct detection, dark
orange (dash-dot) a false alarm; a grey band on a full-run panel marks the zoomed window. The
"faulted channel" is the body axis on which the faulted thruster's angular acceleration
``mu = J^-1 (r x F)`` is largest (``VehicleArrays.mu_B_rad_s2``).

* ``_rates``: the faulted channel's true rate (plant, relative to the orbit frame) and measured
  rate (gyro, one dot per tick; inertial, so on vehicles in orbit the two differ by the orbit
  rate; seed 002's integrating gyro gives the mean rate over the tick, not the rate at its end)
  against time; a zoom panel around the fault on long runs (seed 002's 700 s faults). Mirrors
  seed 000 figs. 9 and 13 (omega_x, fault red, detection green), seed 002 figs. 2-3. Without a
  fault: true rates and attitude errors of all three axes, with the controller's rate dead zone.
* ``_phase``: attitude error (abscissa, deg) against rate error (ordinate, deg/s) of the faulted
  channel, states after the fault in red (seed 000 figs. 7, 8 and 12; seed 004 fig. 2), with the
  controller's dead-zone band (half-width ``rate_deadband_deg_s``, 0.12 deg/s, about its
  switching line; drawn below the Euler-turn angle only) and the fault and detection states
  marked. The right panel zooms on the states from 5 s before the fault to 5 s after detection.
  Without a fault: one panel per channel.
* ``_residuals``: integral residuals around the fault, ``rho_off`` (stuck on; crosses ``+thr``)
  above, ``rho_on`` (fails to fire; crosses ``-thr``) below, with the thresholds dashed: the
  faulted thruster, the thruster the detection named, and the others that came closest to their
  thresholds; a star where the detection was raised. Mirrors seed 000 figs. 10, 11 and 14 and
  seed 003 figs. 5b and 6b. Where the vehicle's FDIR responds to a detection, it rebaselines the
  detector and the residuals drop to zero.
* ``_firing``: commanded on-time per thruster and tick (THR_CMD) in 10 ms quanta, 20 = the whole
  200 ms tick, around the fault (the whole run without a fault); on vehicles with more than 8
  thrusters only those commanded in the window, plus the faulted one. The faulted thruster's name
  is red and its row hatched red from the fault on: the chart is the command, not the thrust (a
  stuck-on thruster burns whatever it says). Mirrors seed 004 figs. 6, 9 and 12.
"""

from __future__ import annotations

import json
import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from hil.errors import HilError, UsageError
from hil.recorder import read_jsonl
from hil.summary import COMPATIBLE

DPI = 100
FIG_W_IN = 9.0
FIG_H_IN = 4.0
FAULT_COLOR = "tab:red"
DETECT_COLOR = "tab:green"
FALSE_ALARM_COLOR = "darkorange"
TRUTH_COLOR = "tab:blue"
MEAS_COLOR = "0.35"
# Thruster colours on residual plots: no red, green or orange (taken by fault/detection lines).
THRUSTER_COLORS = ("tab:blue", "tab:purple", "tab:brown", "tab:cyan", "tab:olive", "tab:pink",
                   "tab:gray", "navy")
AXES = ("x", "y", "z")
ZOOM_MARGIN_S = 20.0         # rates, residuals and firing chart: fault - 20 s .. detection + 20 s
PHASE_MARGIN_S = 5.0         # phase-plane zoom: fault - 5 s .. detection + 5 s
NO_DETECTION_AFTER_S = 40.0  # window end after a fault that was never detected
ZOOM_IF_FRACTION = 0.6       # add a zoom panel when the window is shorter than this share of run
MAX_RESIDUAL_THRUSTERS = 5
LEGEND_CHARS_PER_ROW = 140
FIRING_SHOW_ALL_UP_TO = 8     # more thrusters than this: show only those commanded


# =============================================================================== loading


@dataclass
class Run:
    """One run folder, read and checked: the summary, the per-tick arrays and the context."""

    path: Path
    summary: dict[str, Any]
    slug: str = ""
    notes: list[str] = field(default_factory=list)
    plant: dict[str, Any] = field(default_factory=dict)
    flight: dict[str, Any] = field(default_factory=dict)
    scenario: Any = None          # hil.config.Scenario or None
    vehicle: Any = None           # hil.config.VehicleCfg or None
    arrays: Any = None            # hil.config.VehicleArrays or None
    expected: list[dict[str, Any]] = field(default_factory=list)

    @property
    def name(self) -> str:
        return str(self.summary.get("scenario") or self.path.name)

    @property
    def thruster_faults(self) -> list[dict[str, Any]]:
        return [f for f in self.summary.get("faults") or [] if f.get("thruster")]

    @property
    def detections(self) -> list[dict[str, Any]]:
        return list(self.summary.get("detections") or [])


def read_summary(run_dir: Path) -> dict[str, Any]:
    """``run_dir/summary.json`` as a dict, or a one-line ``UsageError`` saying what is wrong."""
    run_dir = Path(run_dir)
    where = f"report: {run_dir}"
    if not run_dir.exists():
        raise UsageError(f"{where}: expected a run folder (hil run --out), got no such folder")
    if not run_dir.is_dir():
        raise UsageError(f"{where}: expected a run folder (hil run --out), got a file")
    path = run_dir / "summary.json"
    if not path.exists():
        raise UsageError(f"report: {path}: expected the run's summary, got no such file "
                         f"(not a run folder, or the run did not finish)")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise UsageError(f"report: {path}: expected JSON, got invalid JSON at line {exc.lineno} "
                         f"column {exc.colno} ({exc.msg})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"report: {path}: expected a readable file, got {exc}") from None
    if not isinstance(data, dict):
        raise UsageError(f"report: {path}: expected a JSON object, got {type(data).__name__}")
    if not data.get("scenario"):
        raise UsageError(f"report: {path}: expected a 'scenario' field, got nothing")
    return data


def expand_run_dirs(run_dirs: list[Path], skip: Path | None = None) -> list[Path]:
    """Run folders in order; a folder of run folders stands for them; ``skip`` (the report) out."""
    out: list[Path] = []
    skip_r = skip.resolve() if skip is not None else None
    for d in map(Path, run_dirs):
        if skip_r is not None and d.resolve() == skip_r:
            continue
        if d.is_dir() and not (d / "summary.json").exists():
            children = sorted(c for c in d.iterdir()
                              if c.is_dir() and (c / "summary.json").exists()
                              and (skip_r is None or c.resolve() != skip_r))
            if children:
                out.extend(children)
                continue
        out.append(d)
    return out


def _records(path: Path) -> list[dict[str, Any]]:
    return [r for r in read_jsonl(path) if isinstance(r, dict) and not r.get("final")
            and "t_s" in r]


def _xyz(records: list[dict], key: str) -> np.ndarray:
    """(n, 3) array of a series ``{x, y, z}``; NaN where a record lacks it."""
    out = np.full((len(records), 3), np.nan)
    for k, r in enumerate(records):
        v = (r.get("series") or {}).get(key)
        if isinstance(v, dict):
            out[k] = [float(v.get(a, np.nan)) for a in AXES]
    return out


def _named(records: list[dict], key: str) -> dict[str, np.ndarray]:
    """Per-label arrays of a named series (``{thruster: value}``); NaN where missing."""
    names: list[str] = []
    for r in records:
        v = (r.get("series") or {}).get(key)
        if isinstance(v, dict):
            names.extend(n for n in v if n not in names)
    out = {n: np.full(len(records), np.nan) for n in names}
    for k, r in enumerate(records):
        v = (r.get("series") or {}).get(key)
        if isinstance(v, dict):
            for n, x in v.items():
                if isinstance(x, int | float):
                    out[n][k] = float(x)
    return out


def _load_arrays(run: Run) -> None:
    plant = _records(run.path / "plant.jsonl")
    flight = _records(run.path / "flight.jsonl")
    if not plant:
        run.notes.append("plant.jsonl missing or empty: no truth plots")
    if not flight:
        run.notes.append("flight.jsonl missing or empty: no residual or firing plots")
    run.plant = {
        "t": np.array([float(r["t_s"]) for r in plant]),
        "omega": _xyz(plant, "truth/omega_deg_s"),
        "att": _xyz(plant, "truth/attitude_error_deg"),
    }
    run.flight = {
        "t": np.array([float(r["t_s"]) for r in flight]),
        "meas": _xyz(flight, "flight/omega_meas_deg_s"),
        "rho_on": _named(flight, "flight/rho_on"),
        "rho_off": _named(flight, "flight/rho_off"),
        "thr": _named(flight, "flight/thresholds"),
        "on_ms": _named(flight, "flight/on_ms"),
    }


def _scenario_candidates(run: Run) -> list[Path]:
    from hil.config import REPO_ROOT, SCENARIO_DIR

    out = []
    sp = run.summary.get("scenario_path")
    if isinstance(sp, str) and sp:
        p = Path(sp)
        out += [p] if p.is_absolute() else [p, run.path / p, REPO_ROOT / p]
    out.append(SCENARIO_DIR / f"{run.name}.yaml")
    return out


def _load_context(run: Run) -> None:
    """Scenario (for the seed's latency), vehicle and its arrays; trouble becomes a note."""
    from hil.config import VEHICLE_DIR, VehicleArrays, load_scenario, load_vehicle

    path = next((p for p in _scenario_candidates(run) if p.is_file()), None)
    if path is not None:
        try:
            run.scenario = load_scenario(path)
            run.vehicle = run.scenario.vehicle
        except HilError as exc:
            run.notes.append(f"scenario file not usable ({exc}): no seed latency from it")
    elif run.thruster_faults and not isinstance(run.summary.get("expect"), dict):
        run.notes.append("scenario file not found: no seed latency from it")
    vname = run.summary.get("vehicle")
    if run.vehicle is None and isinstance(vname, str) and (VEHICLE_DIR / f"{vname}.yaml").exists():
        try:
            run.vehicle = load_vehicle(vname)
        except HilError as exc:
            run.notes.append(f"vehicle {vname} not usable ({exc})")
    if run.vehicle is not None:
        run.arrays = VehicleArrays.from_vehicle(run.vehicle)
    run.expected = _expected_detections(run)


def _names(thruster: Any) -> list[str]:
    if thruster is None:
        return []
    return [thruster] if isinstance(thruster, str) else [str(t) for t in thruster]


def _expected_detections(run: Run) -> list[dict[str, Any]]:
    """``[{thruster: [names], type, seed_latency_s}]`` from the summary, else the scenario."""
    out: list[dict[str, Any]] = []
    block = run.summary.get("expect")
    items = block.get("detections") if isinstance(block, dict) else None
    if isinstance(items, list):
        for d in items:
            if isinstance(d, dict):
                lat = d.get("seed_latency_s")
                out.append({"thruster": _names(d.get("thruster")), "type": d.get("type"),
                            "seed_latency_s": lat})
    elif run.scenario is not None and run.scenario.cfg.expect is not None:
        for e in run.scenario.cfg.expect.detections:
            out.append({"thruster": _names(e.thruster), "type": e.type,
                        "seed_latency_s": e.seed_latency_s})
    # A separate seed figure in the summary wins: a number, a list (per expected detection)
    # or a mapping thruster -> seconds.
    seed = run.summary.get("seed_latency_s")
    if isinstance(seed, int | float) and out:
        out[0]["seed_latency_s"] = seed
    elif isinstance(seed, list):
        for e, s in zip(out, seed, strict=False):
            if isinstance(s, int | float):
                e["seed_latency_s"] = s
    elif isinstance(seed, dict):
        for e in out:
            for n in e["thruster"]:
                if isinstance(seed.get(n), int | float):
                    e["seed_latency_s"] = seed[n]
    return out


def load_run(run_dir: Path) -> Run:
    """Read one run folder (``UsageError`` if it is not one); plots need only what is there."""
    run = Run(path=Path(run_dir), summary=read_summary(Path(run_dir)))
    _load_arrays(run)
    _load_context(run)
    return run


# =============================================================================== table


def _seed_latency(run: Run, fault: dict[str, Any]) -> float | None:
    compatible = COMPATIBLE.get(fault.get("type"), {fault.get("type")})
    for e in run.expected:
        if fault["thruster"] in e["thruster"] and e.get("type") in compatible:
            return e.get("seed_latency_s")
    if len(run.expected) == 1 and len(run.thruster_faults) == 1:
        return run.expected[0].get("seed_latency_s")
    return None


def answer_to(run: Run, fault: dict[str, Any]) -> dict[str, Any] | None:
    """The detection that answers a fault: the first correct one naming it, else the first after."""
    t_f = float(fault["t_s"])
    compatible = COMPATIBLE.get(fault.get("type"), {fault.get("type")})
    after = [d for d in run.detections if float(d.get("t_s", -1.0)) >= t_f - 1e-9]
    for d in after:
        if d.get("correct") and fault["thruster"] in _names(d.get("thruster")) \
                and d.get("type") in compatible:
            return d
    return after[0] if after else None


def _thr_text(thruster: Any) -> str:
    names = _names(thruster)
    if len(names) == 1:
        return names[0]
    return "one of {" + ", ".join(names) + "}" if names else "-"


def _fault_text(f: dict[str, Any]) -> str:
    frac = f.get("fraction")
    pct = ""
    if f.get("type") in ("stuck_on", "degraded") and isinstance(frac, int | float):
        pct = f" {frac * 100:.0f} %"
    return f"{f.get('type')} {f.get('thruster') or ''}{pct}".strip()


def table_rows(run: Run) -> list[dict[str, Any]]:
    """The report's rows for one run (``report.json``), one per thruster fault or 'no fault'."""
    s = run.summary
    common = {
        "scenario": run.name,
        "vehicle": s.get("vehicle"),
        "false_alarms": len(s.get("false_alarms") or []),
        "max_attitude_error_deg": s.get("max_attitude_error_deg"),
        "max_rate_error_deg_s": s.get("max_rate_error_deg_s"),
        "expectations_met": s.get("expectations_met"),
        "expectation_failures": list(s.get("expectation_failures") or []),
        "run_dir": str(run.path),
    }
    faults = run.thruster_faults
    if not faults:  # fault-free, or only gyro / bus faults (no thruster to name)
        other = [f for f in s.get("faults") or [] if f.get("t_s") is not None]
        return [{**common, "thruster_fault": False,
                 "fault": ", ".join(_fault_text(f) for f in other) or None,
                 "fault_t_s": float(other[0]["t_s"]) if other else None,
                 "detected_thruster": None, "detected_type": None, "detection_t_s": None,
                 "latency_s": None, "seed_latency_s": None, "correct": None}]
    rows = []
    for f in faults:
        d = answer_to(run, f)
        t_f = float(f["t_s"])
        rows.append({
            **common,
            "thruster_fault": True,
            "fault": _fault_text(f),
            "fault_thruster": f["thruster"],
            "fault_type": f.get("type"),
            "fault_t_s": t_f,
            "detected_thruster": d.get("thruster") if d else None,
            "detected_type": d.get("type") if d else None,
            "detection_source": d.get("source") if d else None,
            "detection_t_s": float(d["t_s"]) if d else None,
            "latency_s": round(float(d["t_s"]) - t_f, 6) if d else None,
            "seed_latency_s": _seed_latency(run, f),
            "correct": bool(d.get("correct")) if d else False,
            "missed": not (d is not None and d.get("correct")),  # no correct detection
        })
    return rows


# =============================================================================== plots: helpers


def _s(x: float | None) -> str:
    """Seconds for the report: one decimal when the value sits on it (0.2 s ticks), else two."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return f"{x:.1f}" if abs(x * 10 - round(x * 10)) < 1e-6 else f"{x:.2f}"


def _num(x: Any, fmt: str = ".2f") -> str:
    return format(x, fmt) if isinstance(x, int | float) else "-"


def _channel(run: Run, thruster: str, t_fault: float) -> int:
    """Body axis of the thruster's largest angular acceleration; else the largest rate change."""
    ar = run.arrays
    if ar is not None and thruster in ar.names:
        return int(np.argmax(np.abs(ar.mu_B_rad_s2[ar.names.index(thruster)])))
    t, w = run.plant.get("t"), run.plant.get("omega")
    if t is None or len(t) == 0:
        return 0
    k0 = int(np.searchsorted(t, t_fault))
    seg = w[k0:k0 + max(1, int(np.searchsorted(t, t_fault + 10.0)) - k0)]
    if len(seg) == 0 or np.all(np.isnan(seg)):
        return 0
    return int(np.nanargmax(np.nanmax(np.abs(seg - seg[0]), axis=0)))


def _span(run: Run) -> tuple[float, float]:
    ts = [a for a in (run.plant.get("t"), run.flight.get("t")) if a is not None and len(a)]
    if not ts:
        return 0.0, 1.0
    return float(min(a[0] for a in ts)), float(max(a[-1] for a in ts))


def fault_window(run: Run) -> tuple[float, float] | None:
    """Zoom window around the thruster faults: first fault - m .. its answer + m, with the
    margin m = 5 latencies, between 2 s and 20 s (a one-tick detection gets a window where
    its ticks can be told apart)."""
    faults = run.thruster_faults
    if not faults:
        return None
    t0, t1 = _span(run)
    t_f = min(float(f["t_s"]) for f in faults)
    ends = []
    for f in faults:
        d = answer_to(run, f)
        ends.append(float(d["t_s"]) if d else float(f["t_s"]) + NO_DETECTION_AFTER_S)
    margin = min(ZOOM_MARGIN_S, max(2.0, 5.0 * (max(ends) - t_f)))
    lo = max(t0, t_f - margin)
    hi = min(t1, max(ends) + margin)
    return (lo, hi) if hi > lo else (t0, t1)


def _needs_zoom(run: Run, win: tuple[float, float] | None) -> bool:
    if win is None:
        return False
    t0, t1 = _span(run)
    return (win[1] - win[0]) < ZOOM_IF_FRACTION * (t1 - t0)


def _markers(ax, run: Run, labels: bool = True) -> list:
    """Vertical fault (red), detection (green) and false-alarm (orange) lines; legend handles."""
    handles = []
    for f in run.summary.get("faults") or []:
        if f.get("t_s") is None:
            continue
        h = ax.axvline(float(f["t_s"]), color=FAULT_COLOR, lw=1.3, zorder=1.5,
                       label=f"fault: {_fault_text(f)} at {_s(float(f['t_s']))} s")
        handles.append(h)
    for d in run.detections:
        if d.get("t_s") is None:
            continue
        ok = bool(d.get("correct"))
        what = "detection" if ok else "false alarm"
        h = ax.axvline(float(d["t_s"]), color=DETECT_COLOR if ok else FALSE_ALARM_COLOR,
                       lw=1.3, ls="-" if ok else "-.", zorder=1.5,
                       label=f"{what}: {d.get('type')} {_thr_text(d.get('thruster'))} "
                             f"at {_s(float(d['t_s']))} s")
        handles.append(h)
    return handles if labels else []


def _new_figure(rows: int = 1, cols: int = 1, height: float = FIG_H_IN, **kw):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(FIG_W_IN, height), dpi=DPI, layout="constrained")
    axs = fig.subplots(rows, cols, squeeze=False, **kw)
    return fig, axs


def _legend_below(fig, handles: list, ncol: int = 4) -> None:
    """One legend under the axes (never over the data), as many columns as fit the width."""
    seen: dict[str, Any] = {}
    for h in handles:
        seen.setdefault(h.get_label(), h)
    if not seen:
        return
    labels = list(seen)
    # About 145 characters of 8 pt text fit across 9 in; a column costs ~8 more for its handle.
    # Columns as matplotlib fills them: the first len % c columns get one label more.
    cols = 1
    for c in range(min(ncol, len(labels)), 0, -1):
        rows, big = divmod(len(labels), c)
        width, k = 0, 0
        for j in range(c):
            n = rows + (1 if j < big else 0)
            width += max(len(x) for x in labels[k:k + n]) + 8
            k += n
        if width <= LEGEND_CHARS_PER_ROW:
            cols = c
            break
    fig.legend(list(seen.values()), labels, loc="outside lower center", ncol=cols, fontsize=8,
               frameon=False)


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=DPI)
    return path


def _in(t: np.ndarray, win: tuple[float, float]) -> np.ndarray:
    return (t >= win[0] - 1e-9) & (t <= win[1] + 1e-9)


def _subtitle(run: Run) -> str:
    return f"{run.name} ({run.summary.get('vehicle', '?')})"


# =============================================================================== plots


def plot_rates(run: Run, path: Path) -> Path | None:
    """True and measured rate of the faulted channel (seed 000 figs. 9, 13); no fault: all."""
    tp, w = run.plant.get("t"), run.plant.get("omega")
    tf, wm = run.flight.get("t"), run.flight.get("meas")
    if (tp is None or not len(tp)) and (tf is None or not len(tf)):
        return None
    faults = run.thruster_faults
    orbit = run.vehicle is not None and run.vehicle.orbit.rate_rad_s > 0
    true_lbl = "true (plant, rel. orbit frame)" if orbit else "true (plant)"
    integrating = run.vehicle is not None and run.vehicle.gyro.kind == "integrating"
    meas_lbl = "measured (" + ("integrating gyro: mean rate over the tick" if integrating
                               else "gyro") + (", inertial)" if orbit else ")")
    if not faults:
        return _plot_rates_nofault(run, path, true_lbl)
    f0 = faults[0]
    ch = _channel(run, f0["thruster"], float(f0["t_s"]))
    win = fault_window(run)
    zoom = _needs_zoom(run, win)
    fig, axs = (_new_figure(1, 2, width_ratios=[1, 1.6]) if zoom else _new_figure(1, 1))
    panels = [(axs[0][0], None)] + ([(axs[0][1], win)] if zoom else [])
    handles: list = []
    for ax, wnd in panels:
        if len(tp):
            m = _in(tp, wnd) if wnd else slice(None)
            handles.append(ax.plot(tp[m], w[m, ch], color=TRUTH_COLOR, lw=1.6,
                                   label=true_lbl)[0])
        if len(tf) and (wnd or not zoom):  # thousands of dots would bury the whole-run line
            m = _in(tf, wnd) if wnd else slice(None)
            n_dots = np.count_nonzero(m) if wnd else len(tf)
            ms = 2.5 if n_dots < 400 else 1.0  # dots, not a line: it would hide under the truth
            handles.append(ax.plot(tf[m], wm[m, ch], ".", color=MEAS_COLOR, ms=ms,
                                   label=f"{meas_lbl}, one dot per tick")[0])
        handles += _markers(ax, run)
        ax.set_xlabel("time [s]")
        ax.set_ylabel(f"rate ω_{AXES[ch]} [deg/s]")
        ax.grid(alpha=0.3)
        if wnd:
            ax.set_xlim(*wnd)
            ax.set_title(f"zoom {_s(wnd[0])}-{_s(wnd[1])} s", fontsize=9)
        elif zoom:
            ax.axvspan(*win, color="0.85", zorder=0)
            ax.set_title("whole run (grey: zoomed window)", fontsize=9)
    fig.suptitle(f"{_subtitle(run)}: rate of channel {AXES[ch]} "
                 f"(largest torque axis of {f0['thruster']})", fontsize=11)
    _legend_below(fig, handles)
    return _save(fig, path)


def _dead_zone_deg_s(run: Run) -> float | None:
    if run.vehicle is None:
        return None
    c = run.vehicle.flight.controller
    return float(c.rate_deadband_deg_s) if c.law == "phase_plane" else None


def _plot_rates_nofault(run: Run, path: Path, true_lbl: str) -> Path:
    tp, w, att = run.plant.get("t"), run.plant.get("omega"), run.plant.get("att")
    fig, axs = _new_figure(1, 2)
    handles: list = []
    colors = ("tab:blue", "tab:purple", "tab:brown")
    ax_w, ax_a = axs[0]
    for i, a in enumerate(AXES):
        if len(tp):
            handles.append(ax_w.plot(tp, w[:, i], color=colors[i], lw=1.2, label=f"axis {a}")[0])
            ax_a.plot(tp, att[:, i], color=colors[i], lw=1.2)
    dz = _dead_zone_deg_s(run)
    if dz is not None:
        for sgn in (1, -1):
            h = ax_w.axhline(sgn * dz, color="k", ls=":", lw=1.0,
                             label=f"controller rate dead zone ±{dz:g} deg/s")
        handles.append(h)
    for ax in (ax_w, ax_a):
        handles += _markers(ax, run)
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
    ax_w.set_ylabel("rate ω [deg/s]")
    ax_a.set_ylabel("attitude error ν [deg]")
    ax_w.set_title(f"rate ω, {true_lbl}", fontsize=9)
    ax_a.set_title("attitude error ν, true (plant)", fontsize=9)
    fig.suptitle(f"{_subtitle(run)}: no thruster fault, rates and attitude errors", fontsize=11)
    _legend_below(fig, handles)
    return _save(fig, path)


def _band(run: Run, ch: int, nu_max_deg: float):
    """Controller dead zone on the channel's phase plane: (nu_deg, lo_deg_s, hi_deg_s, label)."""
    if run.vehicle is None or run.arrays is None:
        return None
    try:
        from flight.controller import Controller

        ctl = Controller(run.vehicle, run.arrays)
    except Exception:  # noqa: BLE001 - the band is a reading aid; the plot stands without it
        return None
    c = ctl.cfg
    if c.law == "s_law":
        nu = np.linspace(-nu_max_deg, nu_max_deg, 201)
        half = math.degrees(ctl.s_dz) / c.s_gain_s
        return (nu, -nu / c.s_gain_s - half, -nu / c.s_gain_s + half,
                f"dead zone |ν + {c.s_gain_s:g} s·ω| ≤ {c.s_deadband_deg:g} deg")
    lim = min(nu_max_deg, c.large_angle_deg)
    nu = np.linspace(-lim, lim, 401)
    eps = float(ctl.eps_B_rad_s2[ch])
    e_ref = []
    for x in np.radians(nu):
        if abs(x) > ctl.curve_rad:
            e_ref.append(-math.copysign(min(math.sqrt(2.0 * eps * abs(x)), ctl.w_max), x))
        else:
            e_ref.append(ctl.centre_line(float(x), eps))
    e = np.degrees(np.array(e_ref))
    dz = c.rate_deadband_deg_s
    return nu, e - dz, e + dz, f"controller dead zone (±{dz:g} deg/s about the switching line)"


def _phase_panel(ax, run: Run, ch: int, win: tuple[float, float] | None, t_fault: float | None,
                 dets: list[dict]) -> list:
    t, att, w = run.plant["t"], run.plant["att"][:, ch], run.plant["omega"][:, ch]
    m = _in(t, win) if win else np.ones(len(t), bool)
    t, x, y = t[m], att[m], w[m]
    handles = []
    if len(t) == 0:
        return handles
    xmax = float(np.nanmax(np.abs(x))) if np.any(np.isfinite(x)) else 1.0
    ymax = float(np.nanmax(np.abs(y))) if np.any(np.isfinite(y)) else 0.2
    band = _band(run, ch, max(xmax * 1.2, 1.0))
    if band is not None:
        nu, lo, hi, lbl = band
        handles.append(ax.fill_between(nu, lo, hi, color="0.8", alpha=0.6, lw=0, label=lbl))
    if t_fault is None:
        handles.append(ax.plot(x, y, color=TRUTH_COLOR, lw=1.2, label="true state")[0])
    else:
        k = int(np.searchsorted(t, t_fault))
        handles.append(ax.plot(x[:k + 1], y[:k + 1], color=TRUTH_COLOR, lw=1.2,
                               label="true state before the fault")[0])
        handles.append(ax.plot(x[k:], y[k:], color=FAULT_COLOR, lw=1.2,
                               label="true state after the fault (seed 000 fig. 8)")[0])
        if t[0] <= t_fault <= t[-1]:
            handles.append(ax.plot(np.interp(t_fault, t, x), np.interp(t_fault, t, y), "o",
                                   ms=8, mfc="none", mec=FAULT_COLOR, mew=2,
                                   label="state at the fault")[0])
    for d in dets:
        td = float(d["t_s"])
        if t[0] <= td <= t[-1]:
            ok = bool(d.get("correct"))
            handles.append(ax.plot(np.interp(td, t, x), np.interp(td, t, y), "*", ms=13,
                                   color=DETECT_COLOR if ok else FALSE_ALARM_COLOR, mec="k",
                                   mew=0.5, label="state at detection" if ok
                                   else "state at false alarm")[0])
    handles.append(ax.plot(x[0], y[0], "s", color="k", ms=5, label="first state shown")[0])
    ax.axhline(0, color="k", lw=0.5)
    ax.axvline(0, color="k", lw=0.5)
    pad_x, pad_y = 0.08 * max(xmax, 0.1), 0.12 * max(ymax, 0.05)
    ax.set_xlim(np.nanmin(x) - pad_x, np.nanmax(x) + pad_x)
    ax.set_ylim(np.nanmin(y) - pad_y, np.nanmax(y) + pad_y)
    ax.set_xlabel(f"attitude error ν_{AXES[ch]} [deg]")
    ax.set_ylabel(f"rate error ω_{AXES[ch]} [deg/s]")
    ax.grid(alpha=0.3)
    return handles


def plot_phase(run: Run, path: Path) -> Path | None:
    """Phase plane of the faulted channel (seed 000 figs. 7-8, 12; seed 004 fig. 2)."""
    if not len(run.plant.get("t", [])):
        return None
    faults = run.thruster_faults
    if not faults:
        fig, axs = _new_figure(1, 3)
        handles: list = []
        for ch in range(3):
            handles += _phase_panel(axs[0][ch], run, ch, None, None, run.detections)
            axs[0][ch].set_title(f"channel {AXES[ch]}", fontsize=9)
        fig.suptitle(f"{_subtitle(run)}: phase planes, no thruster fault", fontsize=11)
        _legend_below(fig, handles)
        return _save(fig, path)
    f0 = faults[0]
    t_f = float(f0["t_s"])
    ch = _channel(run, f0["thruster"], t_f)
    d = answer_to(run, f0)
    t0, t1 = _span(run)
    zwin = (max(t0, t_f - PHASE_MARGIN_S),
            min(t1, (float(d["t_s"]) if d else t_f + NO_DETECTION_AFTER_S) + PHASE_MARGIN_S))
    fig, axs = _new_figure(1, 2)
    handles = _phase_panel(axs[0][0], run, ch, None, t_f, run.detections)
    axs[0][0].set_title("whole run", fontsize=9)
    handles += _phase_panel(axs[0][1], run, ch, zwin, t_f, run.detections)
    axs[0][1].set_title(f"zoom {_s(zwin[0])}-{_s(zwin[1])} s", fontsize=9)
    fig.suptitle(f"{_subtitle(run)}: phase plane of channel {AXES[ch]} "
                 f"({_fault_text(f0)} at {_s(t_f)} s)", fontsize=11)
    _legend_below(fig, handles)
    return _save(fig, path)


def _residual_thrusters(run: Run, win: tuple[float, float] | None) -> list[str]:
    """Faulted, detected, then the others closest to their thresholds (max |rho| / thr)."""
    tf = run.flight["t"]
    m = _in(tf, win) if win else np.ones(len(tf), bool)
    rho_on, rho_off = run.flight["rho_on"], run.flight["rho_off"]
    names = list(dict.fromkeys([*rho_off, *rho_on]))
    first: list[str] = []
    for f in run.thruster_faults:
        first.append(f["thruster"])
    for d in run.detections:
        if win is None or win[0] <= float(d["t_s"]) <= win[1]:
            first.extend(_names(d.get("thruster"))[:2])
    first = [n for n in dict.fromkeys(first) if n in names]
    thr = run.flight["thr"]
    t_off = float(np.nanmax(np.abs(thr["off"]))) if "off" in thr and len(thr["off"]) else 1.0
    t_on = float(np.nanmax(np.abs(thr["on"]))) if "on" in thr and len(thr["on"]) else 1.0

    def score(n: str) -> float:
        a = np.abs(rho_off.get(n, np.zeros(len(tf)))[m]) / (t_off or 1.0)
        b = np.abs(rho_on.get(n, np.zeros(len(tf)))[m]) / (t_on or 1.0)
        v = np.concatenate([a, b])
        return float(np.nanmax(v)) if v.size and np.any(np.isfinite(v)) else 0.0

    others = sorted((n for n in names if n not in first), key=score, reverse=True)
    others = [n for n in others if score(n) > 0.0]
    return (first + others)[:max(MAX_RESIDUAL_THRUSTERS, len(first))]


def plot_residuals(run: Run, path: Path) -> Path | None:
    """rho_off above, rho_on below, thresholds dashed (seed 000 figs. 10-11; seed 003 fig. 5b)."""
    tf = run.flight.get("t")
    if tf is None or not len(tf) or not (run.flight["rho_off"] or run.flight["rho_on"]):
        return None
    win = fault_window(run)
    shown = _residual_thrusters(run, win)
    m = _in(tf, win) if win else np.ones(len(tf), bool)
    t = tf[m]
    fig, axs = _new_figure(2, 1, height=5.0, sharex=True)
    ax_off, ax_on = axs[0][0], axs[1][0]
    faulted = {f["thruster"] for f in run.thruster_faults}
    handles: list = []
    for k, n in enumerate(shown):
        c = THRUSTER_COLORS[k % len(THRUSTER_COLORS)]
        lw = 2.0 if n in faulted else 1.2
        z = 5 if n in faulted else 2  # the faulted thruster on top of the others
        mk = "o" if n in faulted else None
        lbl = f"thruster {n} (faulted)" if n in faulted else f"thruster {n}"
        if n in run.flight["rho_off"]:
            handles.append(ax_off.plot(t, run.flight["rho_off"][n][m], color=c, lw=lw,
                                       label=lbl, zorder=z, marker=mk, ms=3)[0])
        if n in run.flight["rho_on"]:
            handles.append(ax_on.plot(t, run.flight["rho_on"][n][m], color=c, lw=lw,
                                      label=lbl, zorder=z, marker=mk, ms=3)[0])
    thr = run.flight["thr"]
    last = {k: v[m][np.isfinite(v[m])] for k, v in thr.items()}
    thr_lbl = "thresholds" + (
        f" (ρ_off > {last['off'][-1]:+g}, ρ_on < {last['on'][-1]:+g})"
        if all(k in last and last[k].size for k in ("off", "on")) else "")
    for ax, key in ((ax_off, "off"), (ax_on, "on")):
        if key in thr:
            handles.append(ax.step(t, thr[key][m], where="post", color="k", ls="--", lw=1.2,
                                   label=thr_lbl)[0])
        handles += _markers(ax, run)
        ax.grid(alpha=0.3)
        ax.axhline(0, color="k", lw=0.5)
    for d in run.detections:
        n = _names(d.get("thruster"))
        series = run.flight["rho_off" if d.get("type") == "stuck_on" else "rho_on"]
        ax = ax_off if d.get("type") == "stuck_on" else ax_on
        if n and n[0] in series and len(t) and t[0] <= float(d["t_s"]) <= t[-1]:
            ax.plot(float(d["t_s"]), np.interp(float(d["t_s"]), t, series[n[0]][m]), "*",
                    ms=12, color=DETECT_COLOR if d.get("correct") else FALSE_ALARM_COLOR,
                    mec="k", mew=0.5)
    ax_off.set_ylabel("ρ_off (stuck on) [-]")
    ax_on.set_ylabel("ρ_on (fails to fire) [-]")
    ax_on.set_xlabel("time [s]")
    if win:
        ax_on.set_xlim(*win)
    where = f", {_s(win[0])}-{_s(win[1])} s" if win and _needs_zoom(run, win) else ""
    fig.suptitle(f"{_subtitle(run)}: integral residuals{where}", fontsize=11)
    _legend_below(fig, handles, ncol=4)
    return _save(fig, path)


def plot_firing(run: Run, path: Path) -> Path | None:
    """Commanded on-time per thruster per tick in 10 ms quanta (seed 004 figs. 6, 9, 12)."""
    tf = run.flight.get("t")
    on = run.flight.get("on_ms") or {}
    if tf is None or not len(tf) or not on:
        return None
    import matplotlib
    from matplotlib.colors import BoundaryNorm, ListedColormap
    from matplotlib.patches import Patch, Rectangle

    quantum_ms = run.vehicle.timing.pwm_quantum_ms if run.vehicle is not None else 10.0
    tick_s = run.vehicle.timing.tick_s if run.vehicle is not None else (
        float(np.median(np.diff(tf))) if len(tf) > 1 else 0.2)
    n_q = max(1, int(round(tick_s * 1000.0 / quantum_ms)))
    win = fault_window(run)
    m = _in(tf, win) if win else np.ones(len(tf), bool)
    t = tf[m]
    if not len(t):
        return None
    faulted = [f["thruster"] for f in run.thruster_faults]
    if len(on) <= FIRING_SHOW_ALL_UP_TO:
        names = list(on)
    else:  # 30 thrusters: only those commanded in the window (and the faulted ones)
        names = [n for n in on if np.nansum(on[n][m]) > 0 or n in faulted]
    order = run.arrays.names if run.arrays is not None else tuple(on)
    names.sort(key=lambda n: order.index(n) if n in order else len(order))
    if not names:
        names = list(on)[:1]
    q = np.array([np.nan_to_num(on[n][m]) / quantum_ms for n in names])
    edges_t = np.append(t, t[-1] + tick_s)
    edges_y = np.arange(len(names) + 1) - 0.5
    # 0 is white; 1..n_q quanta from light to dark, starting dark enough to see a 30 ms pulse.
    ramp = matplotlib.colormaps["viridis_r"](np.linspace(0.15, 1.0, n_q))
    cmap = ListedColormap(np.vstack([[1.0, 1.0, 1.0, 1.0], ramp]))
    norm = BoundaryNorm(np.arange(n_q + 2) - 0.5, cmap.N)
    height = min(8.0, max(FIG_H_IN, 1.8 + 0.22 * len(names)))
    fig, axs = _new_figure(1, 1, height=height)
    ax = axs[0][0]
    mesh = ax.pcolormesh(edges_t, edges_y, q, cmap=cmap, norm=norm, shading="flat")
    ax.set_yticks(range(len(names)), names, fontsize=8 if len(names) > 12 else 9)
    for lbl in ax.get_yticklabels():
        if lbl.get_text() in faulted:
            lbl.set_color(FAULT_COLOR)
            lbl.set_fontweight("bold")
    ax.set_ylim(len(names) - 0.5, -0.5)  # first thruster on top
    handles = _markers(ax, run)
    for f in run.thruster_faults:
        if f["thruster"] not in names:
            continue
        row = names.index(f["thruster"])
        t_end = f.get("clear_t_s") or edges_t[-1]
        ax.add_patch(Rectangle((float(f["t_s"]), row - 0.45), float(t_end) - float(f["t_s"]),
                               0.9, fill=False, hatch="///", edgecolor=FAULT_COLOR, lw=0.0))
    if faulted:
        handles.append(Patch(fill=False, hatch="///", edgecolor=FAULT_COLOR, lw=0.0,
                             label="faulted: real thrust differs from the command"))
    ax.set_xlim(edges_t[0], edges_t[-1])
    ax.set_xlabel("time [s]")
    ax.set_ylabel("thruster")
    cb = fig.colorbar(mesh, ax=ax, ticks=range(0, n_q + 1, max(1, n_q // 4)), pad=0.01)
    cb.set_label(f"on-time [{quantum_ms:g} ms quanta], {n_q} = whole tick", fontsize=8)
    hidden = len(on) - len(names)
    sub = f"{_s(edges_t[0])}-{_s(edges_t[-1])} s"
    if hidden > 0:
        sub += f"; {hidden} thrusters not commanded in this window are not shown"
    ax.set_title(sub, fontsize=9)
    fig.suptitle(f"{_subtitle(run)}: commanded on-time per tick (THR_CMD)", fontsize=11)
    _legend_below(fig, handles)
    return _save(fig, path)


PLOTS: tuple[tuple[str, Callable[[Run, Path], Path | None], str], ...] = (
    ("rates", plot_rates, "rate against time"),
    ("phase", plot_phase, "phase plane"),
    ("residuals", plot_residuals, "integral residuals and thresholds"),
    ("firing", plot_firing, "thruster firing chart"),
)


# =============================================================================== report


@dataclass(frozen=True)
class ReportResult:
    """What ``write_report`` wrote. ``exit_code``: 0 all expectations met, 1 some not."""

    out_dir: Path
    markdown: Path
    json: Path
    rows: list[dict[str, Any]]
    plots: dict[str, list[Path]]
    failed: list[str]

    @property
    def all_met(self) -> bool:
        return not self.failed

    @property
    def exit_code(self) -> int:
        return 0 if self.all_met else 1


def _slug(name: str, run_dir: Path, used: set[str]) -> str:
    base = re.sub(r"[^A-Za-z0-9._+-]+", "_", name) or "run"
    slug = base
    if slug in used:
        slug = f"{base}-{re.sub(r'[^A-Za-z0-9._+-]+', '_', run_dir.name)}"
    k = 2
    while slug in used:
        slug, k = f"{base}-{k}", k + 1
    used.add(slug)
    return slug


def _verdict(met: Any) -> str:
    return "met" if met is True else ("**NOT met**" if met is False else "not judged")


def _correct(row: dict[str, Any]) -> str:
    if not row.get("thruster_fault"):
        return "-"
    if row["detection_t_s"] is None:
        return "**MISSED**"
    if row["correct"]:
        return "yes"
    return "**NO** (fault missed)"


def _markdown(runs: list[Run], rows: list[dict[str, Any]], plots: dict[str, list[Path]],
              failed: list[str]) -> str:
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    verdict = ("all expectations met" if not failed
               else f"**{len(failed)} of {len(runs)} run(s) did NOT meet their expectations**: "
                    + ", ".join(failed))
    out = [
        "# Thruster HIL report", "",
        f"{len(runs)} run(s), written {when}. Verdict: {verdict}.", "",
        "| scenario | vehicle | fault | fault at [s] | detected as | detected at [s] "
        "| latency [s] | seed latency [s] | correct | false alarms | max att. error [deg] "
        "| verdict |",
        "|---|---|---|--:|---|--:|--:|--:|---|--:|--:|---|",
    ]
    for r in rows:
        if not r.get("thruster_fault"):
            det = "-"
        elif r["detection_t_s"] is None:
            det = "none"
        else:
            det = f"{r['detected_type']} {_thr_text(r['detected_thruster'])}"
        out.append(
            f"| {r['scenario']} | {r['vehicle'] or '-'} | {r['fault'] or 'no fault'} "
            f"| {_s(r['fault_t_s'])} | {det} | {_s(r['detection_t_s'])} | {_s(r['latency_s'])} "
            f"| {_s(r['seed_latency_s'])} | {_correct(r)} | {r['false_alarms']} "
            f"| {_num(r['max_attitude_error_deg'])} | {_verdict(r['expectations_met'])} |")
    out += [
        "",
        "Latency = detection time - fault time. Seed latency = the seed's own figure "
        "(`expect.detections[].seed_latency_s`; - where the seed gives none; the run is judged "
        "against `within_s`). "
        "Correct = the named thruster (or group \"one of {...}\") and type match the injected "
        "fault. Max attitude error is over the judged part of the run (after "
        "`expect.settle_after_s`).", "",
        "Plots: red line = fault, green = correct detection, orange dash-dot = false alarm; "
        "the faulted channel is the body axis of the faulted thruster's largest torque.", "",
    ]
    fails = [(run, f) for run in runs for f in run.summary.get("expectation_failures") or []]
    if fails:
        out += ["## Expectations not met", ""]
        out += [f"- {run.name}: {f}" for run, f in fails]
        out.append("")
    for run in runs:
        out += _run_section(run, plots.get(run.slug, []))
    return "\n".join(out) + "\n"


def _run_section(run: Run, pngs: list[Path]) -> list[str]:
    s = run.summary
    desc = run.scenario.cfg.description if run.scenario is not None else ""
    out = [f"## {run.name}", ""]
    if desc:
        out += [desc, ""]
    cm = s.get("compute_ms") or {}
    out.append(
        f"- run: `{run.path}`, vehicle {s.get('vehicle', '-')}, {s.get('mode', '-')}, "
        f"{_s(s.get('sim_s'))} s simulated in {_s(s.get('wall_s'))} s wall "
        f"({s.get('where', '-')}), {s.get('ticks', '-')} ticks")
    for f in s.get("faults") or []:
        out.append(f"- fault: {_fault_text(f)} at {_s(f.get('t_s'))} s")
    if not s.get("faults"):
        out.append("- fault: none injected")
    for d in run.detections:
        lat = f", latency {_s(d.get('latency_s'))} s" if d.get("latency_s") is not None else ""
        rho = f", ρ = {d['rho']:.2f}" if isinstance(d.get("rho"), int | float) else ""
        out.append(f"- {'detection' if d.get('correct') else '**false alarm**'}: "
                   f"{d.get('type')} {_thr_text(d.get('thruster'))} at {_s(d.get('t_s'))} s "
                   f"({d.get('source', '-')}{rho}){lat}")
    for f in s.get("missed_faults") or []:
        out.append(f"- **missed**: {_fault_text(f)} at {_s(f.get('t_s'))} s")
    if not run.detections:
        out.append("- detections: none")
    for f in run.thruster_faults:
        seed = _seed_latency(run, f)
        d = answer_to(run, f)
        if seed is not None and d is not None and d.get("correct"):
            lat = float(d["t_s"]) - float(f["t_s"])
            cmp = "faster than" if lat < seed - 1e-9 else (
                "as fast as" if lat <= seed + 1e-9 else "**slower** than")
            out.append(f"- {f['thruster']}: latency {_s(lat)} s, {cmp} the seed's {_s(seed)} s")
    out.append(
        f"- max attitude error {_num(s.get('max_attitude_error_deg'))} deg, max rate error "
        f"{_num(s.get('max_rate_error_deg_s'), '.3f')} deg/s, fuel "
        f"{_num(s.get('fuel_kg'), '.3f')} kg; flight compute p50/p99/max "
        f"{_num(cm.get('p50'), '.1f')}/{_num(cm.get('p99'), '.1f')}/{_num(cm.get('max'), '.1f')}"
        f" ms, overruns {s.get('overruns', '-')}; safe events {len(s.get('safe_events') or [])}")
    out.append(f"- verdict: expectations {_verdict(s.get('expectations_met'))}")
    for f in s.get("expectation_failures") or []:
        out.append(f"  - {f}")
    for note in run.notes:
        out.append(f"- note: {note}")
    out.append("")
    captions = {kind: text for kind, _, text in PLOTS}
    for p in pngs:
        kind = p.stem.rsplit("_", 1)[-1]
        out += [f"![{run.name}: {captions.get(kind, kind)}]({p.name})", ""]
    return out


def write_report(run_dirs: list[Path], out_dir: Path, *, plots: bool = True,
                 progress: Callable[[str], None] | None = None) -> ReportResult:
    """Read every run folder (all checked first), write plots, ``report.md`` and ``report.json``.

    Raises ``UsageError`` (one line) for a missing folder or an unreadable summary before
    anything is written. Missing per-tick files only cost plots (a note says so).
    ``plots=False`` writes the table alone (fast). ``progress`` gets one line per run.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"report: --out {out_dir}: expected a folder, got a file")
    dirs = expand_run_dirs([Path(d) for d in run_dirs], skip=out_dir)
    if not dirs:
        raise UsageError("report: DIR: expected at least one run folder, got none")
    for d in dirs:
        read_summary(d)  # fail fast, before the slow part
    out_dir.mkdir(parents=True, exist_ok=True)
    runs: list[Run] = []
    used: set[str] = set()
    rows: list[dict[str, Any]] = []
    pngs_of: dict[str, list[Path]] = {}
    for d in dirs:
        t0 = time.monotonic()
        run = load_run(d)
        run.slug = _slug(run.name, run.path, used)
        runs.append(run)
        rows.extend(table_rows(run))
        pngs = []
        for kind, fn, _ in PLOTS if plots else ():
            try:
                p = fn(run, out_dir / f"{run.slug}_{kind}.png")
            except Exception as exc:  # noqa: BLE001 - one bad plot must not lose the report
                run.notes.append(f"{kind} plot failed: {type(exc).__name__}: {exc}")
                p = None
            if p is not None:
                pngs.append(p)
        pngs_of[run.slug] = pngs
        if progress:
            progress(f"  {run.name}: {len(pngs)} plots ({time.monotonic() - t0:.1f} s)")
    failed = [r.name for r in runs if r.summary.get("expectations_met") is False]
    md = out_dir / "report.md"
    md.write_text(_markdown(runs, rows, pngs_of, failed), encoding="utf-8")
    js = out_dir / "report.json"
    js.write_text(json.dumps({
        "all_met": not failed,
        "failed": failed,
        "rows": rows,
        "plots": {k: [p.name for p in v] for k, v in pngs_of.items()},
    }, indent=2) + "\n", encoding="utf-8")
    return ReportResult(out_dir=out_dir, markdown=md, json=js, rows=rows, plots=pngs_of,
                        failed=failed)


def _cmd(args) -> int:
    out = Path(args.out) if args.out else Path("runs") / "report"
    result = write_report([Path(d) for d in args.runs], out, plots=not args.no_plots,
                          progress=print)
    n = len(result.plots)
    if result.all_met:
        print(f"report: {result.markdown} ({n} run(s), all expectations met)")
    else:
        print(f"report: {result.markdown} ({n} run(s); expectations NOT met: "
              f"{', '.join(result.failed)})")
    return result.exit_code


def register(sub) -> None:
    p = sub.add_parser("report", help="Markdown + PNG report from run folders (exit 0/1/2)",
                       description="Write report.md, report.json and PNG plots (rates, phase "
                                   "plane, residuals, firing chart) from hil run folders.")
    p.add_argument("runs", nargs="+", metavar="DIR",
                   help="run folder (hil run --out), or a folder of run folders")
    p.add_argument("--out", metavar="REPORT_DIR",
                   help="report folder (default runs/report)")
    p.add_argument("--no-plots", action="store_true", help="table only (fast)")
    p.set_defaults(func=_cmd)
