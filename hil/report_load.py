"""Loading of run folders for ``hil report``: the summary, the per-tick records as arrays, and
the scenario and vehicle a run flew (for its expectations and the faulted channel).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hil.errors import HilError, UsageError
from hil.recorder import read_jsonl
from hil.summary import COMPATIBLE

AXES = ("x", "y", "z")


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


def _load_arrays(run: Run, records: Any = None) -> None:
    """The per-tick arrays from the run's JSON lines, or from ``records`` (a
    ``hil.lcm_replay.Records``: the run's LCM log replayed)."""
    if records is None:
        plant = _records(run.path / "plant.jsonl")
        flight = _records(run.path / "flight.jsonl")
    else:
        plant, flight = records.plant, records.flight
        run.notes.append(f"per-tick data: {records.how}")
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


def names_of(thruster: Any) -> list[str]:
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
                out.append({"thruster": names_of(d.get("thruster")), "type": d.get("type"),
                            "seed_latency_s": lat})
    elif run.scenario is not None and run.scenario.cfg.expect is not None:
        for e in run.scenario.cfg.expect.detections:
            out.append({"thruster": names_of(e.thruster), "type": e.type,
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


def load_run(run_dir: Path, records: Any = None) -> Run:
    """Read one run folder (``UsageError`` if it is not one); plots need only what is there.
    ``records``: the per-tick records to use instead of the folder's JSON lines."""
    run = Run(path=Path(run_dir), summary=read_summary(Path(run_dir)))
    _load_arrays(run, records)
    _load_context(run)
    return run


# =============================================================================== faults and answers


def seed_latency(run: Run, fault: dict[str, Any]) -> float | None:
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
        if d.get("correct") and fault["thruster"] in names_of(d.get("thruster")) \
                and d.get("type") in compatible:
            return d
    return after[0] if after else None


def thruster_text(thruster: Any) -> str:
    names = names_of(thruster)
    if len(names) == 1:
        return names[0]
    return "one of {" + ", ".join(names) + "}" if names else "-"


def fault_text(f: dict[str, Any]) -> str:
    frac = f.get("fraction")
    pct = ""
    if f.get("type") in ("stuck_on", "degraded") and isinstance(frac, int | float):
        pct = f" {frac * 100:.0f} %"
    return f"{f.get('type')} {f.get('thruster') or ''}{pct}".strip()
