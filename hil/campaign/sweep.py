"""Threshold sweep: detection latency against false-alarm rate over the detector's thresholds
and forgetting factors, replayed from recorded residuals (one simulation per run).

The runs of one or more campaigns (one vehicle) are simulated once with the FDIR response
switched off (``flight.fdir.on_*: none``): a detection then changes nothing the loop does (the
detector latches, nothing is reconfigured), so the flight's per-tick projections ``xi`` (N,)
(``TickOutput.xi``: residual after the dead zone and normalisation, projected on each
thruster's acceleration direction), the commands ``on_ms`` (N,) and the available set are the
same for every threshold and forgetting factor. Each grid point replays the integral residuals
of seed 000 on them::

    rho_on,i[n]  = w_on  rho_on,i[n-1]  + xi_i[n]   (i commanded over the tick, no opposite
                                                     thruster commanded with it)
    rho_off,i[n] = w_off rho_off,i[n-1] + xi_i[n]   (i not commanded)
    first n with -rho_on,i > threshold_on (fails to fire) or rho_off,i > threshold_off (stuck
    on); the largest ratio to its threshold names the thruster, fails-to-fire first on a tie,
    then the lower index; the thruster's direction group is reported with it,

and judges the first detection with ``hil.summary.summarise`` (the same judgement as a run's).
A test checks that the replay at the vehicle's own settings finds the detector's own first
detection in every recorded run, so the replay and ``flight/detector.py`` cannot drift apart
unnoticed. What the replay does not cover: the dead zone (it acts before ``xi``) and the Kalman
leak test (seed 002; its detections are not replayed), the isolation of opposite thrusters
(``flight.software``: a crossing it renames or probes is replayed as the detector's own), and
only the first detection of a run.

Outputs: ``DIR/<campaign>/`` (rows and ``residuals/run-K.npz``, resumable like a campaign),
``DIR/sweep.json`` and ``DIR/sweep.png`` (the operating curve).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from hil.campaign.engine import read_rows, run_campaign
from hil.campaign.file import Campaign, CampaignError
from hil.campaign.statistics import FAILED, clopper_pearson

FDIR_OFF = {"fdir": {"on_stuck_on": "none", "on_fail_to_fire": "none", "on_degraded": "none"}}


def sweep_campaign(c: Campaign) -> Campaign:
    """The same campaign with the FDIR response off (module doc)."""
    flight = dict(c.model.flight)
    fdir = {**(flight.get("fdir") or {}), **FDIR_OFF["fdir"]}
    flight["fdir"] = fdir
    model = c.model.model_copy(update={"flight": flight})
    return dataclasses.replace(c, model=model)


def directions(vehicle: dict[str, Any]) -> np.ndarray:
    """Unit angular-acceleration directions e_i (N, 3) = J^-1 (r_i x d_i) F_i, normalised."""
    J = np.array(vehicle["inertia_B_kg_m2"], dtype=float)
    com = np.array(vehicle["com_m"], dtype=float)
    r = np.array([t["position_m"] for t in vehicle["thrusters"]], dtype=float) - com
    d = np.array([t["direction"] for t in vehicle["thrusters"]], dtype=float)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    F = np.array([t["thrust_n"] for t in vehicle["thrusters"]], dtype=float)
    mu = (np.linalg.inv(J) @ (np.cross(r, d) * F[:, None]).T).T
    n = np.linalg.norm(mu, axis=1, keepdims=True)
    return np.divide(mu, n, out=np.zeros_like(mu), where=n > 0)


@dataclasses.dataclass(frozen=True)
class Grid:
    """Grid points: arrays (G,) of threshold_on, threshold_off, forgetting_on, forgetting_off."""

    thr_on: np.ndarray
    thr_off: np.ndarray
    w_on: np.ndarray
    w_off: np.ndarray

    @classmethod
    def product(cls, thresholds: list[float], forgetting: list[float]) -> Grid:
        t, w = np.meshgrid(np.asarray(thresholds, float), np.asarray(forgetting, float),
                           indexing="ij")
        t, w = t.ravel(), w.ravel()
        return cls(t, t.copy(), w, w.copy())

    def __len__(self) -> int:
        return len(self.thr_on)


def replay(xi: np.ndarray, on_ms: np.ndarray, available: np.ndarray, e_B: np.ndarray,
           same_direction_deg: float, grid: Grid) -> list[tuple[int, int, str] | None]:
    """First detection (tick, thruster index, kind) for each grid point, or None.

    ``xi`` (T, N) the recorded projections, ``on_ms`` (T, N) the commands of each tick (the
    residual of tick n covers the commands of tick n-1), ``available`` (T, N).
    """
    T, N = xi.shape
    G = len(grid)
    cos_tol = math.cos(math.radians(same_direction_deg))
    opposite = (e_B @ e_B.T) <= -(cos_tol - 1e-12)
    rho_on = np.zeros((G, N))
    rho_off = np.zeros((G, N))
    w_on, w_off = grid.w_on[:, None], grid.w_off[:, None]
    thr_on, thr_off = grid.thr_on[:, None], grid.thr_off[:, None]
    first: list[tuple[int, int, str] | None] = [None] * G
    open_ = np.ones(G, dtype=bool)
    for n in range(T):
        act = on_ms[n - 1] > 0 if n > 0 else np.zeros(N, dtype=bool)
        av = available[n - 1] if n > 0 else np.ones(N, dtype=bool)
        both = act & (opposite & act[None, :]).any(axis=1)
        on = act & av & ~both
        off = ~act & av
        rho_on = np.where(on, w_on * rho_on + xi[n], rho_on)
        rho_off = np.where(off, w_off * rho_off + xi[n], rho_off)
        rho_on[:, ~av] = 0.0
        rho_off[:, ~av] = 0.0
        r_fail = np.where(av, -rho_on / thr_on, 0.0)
        r_stuck = np.where(av, rho_off / thr_off, 0.0)
        hit = open_ & ((r_fail > 1.0).any(axis=1) | (r_stuck > 1.0).any(axis=1))
        for g in np.flatnonzero(hit):
            cands = [(r_fail[g, i], 1, -i, i, "fail_to_fire") for i in
                     np.flatnonzero(r_fail[g] > 1.0)]
            cands += [(r_stuck[g, i], 0, -i, i, "stuck_on") for i in
                      np.flatnonzero(r_stuck[g] > 1.0)]
            _, _, _, i, kind = max(cands)
            first[g] = (n, int(i), kind)
            open_[g] = False
        if not open_.any():
            break
    return first


def groups(e_B: np.ndarray, same_direction_deg: float, available: np.ndarray) -> list[list[int]]:
    cos_tol = math.cos(math.radians(same_direction_deg))
    c = e_B @ e_B.T
    return [[int(j) for j in np.flatnonzero(c[i] >= cos_tol - 1e-12) if available[j]]
            for i in range(len(e_B))]


def judge(row: dict[str, Any], det: tuple[int, int, str] | None, names: tuple[str, ...],
          grp: list[list[int]], tick_s: float) -> dict[str, Any]:
    """The replayed first detection judged as a run's would be (``summarise``)."""
    from hil.summary import summarise

    f = row["fault"]
    plant = []
    if f is not None:
        plant.append({"tick": 0, "t_s": f["t_s"], "faults_injected": [
            {"t_s": f["t_s"], "thruster": f.get("thruster"), "type": f["kind"],
             "fraction": f.get("fraction"), "clear_t_s": f.get("clear_t_s")}]})
    flight = []
    if det is not None:
        n, i, kind = det
        g = [names[j] for j in grp[i]] or [names[i]]
        flight.append({"tick": n, "t_s": round(n * tick_s, 6), "detection": {
            "t_s": round(n * tick_s, 6), "tick": n, "thruster": g[0] if len(g) == 1 else g,
            "type": kind}})
    s = summarise(scenario=row["name"], vehicle=row["vehicle"], mode="replay",
                  plant_records=plant, flight_records=flight, expect=None)
    d = s["detections"][0] if s["detections"] else None
    t_f = f["t_s"] if f else None
    return {"t_s": d["t_s"] if d else None, "correct": bool(d and d["correct"]),
            "latency_s": d["latency_s"] if d else None,
            "before_fault": bool(d and t_f is not None and d["t_s"] < t_f - 1e-9)}


def operating_points(entries: list[tuple[dict[str, Any], Path]], vehicle: dict[str, Any],
                     grid: Grid) -> list[dict[str, Any]]:
    """Every grid point's false-alarm rate, detection rate and latency over the runs."""
    e_B = directions(vehicle)
    sdd = float(vehicle["flight"]["detector"]["same_direction_deg"])
    names = tuple(t["name"] for t in vehicle["thrusters"])
    h = float(vehicle["timing"]["tick_s"])
    G = len(grid)
    judged: list[list[dict[str, Any]]] = [[] for _ in range(G)]
    kinds: list[dict[str, Any]] = []
    for row, npz in entries:
        with np.load(npz) as z:
            xi, on_ms, av = z["xi"], z["on_ms"], z["available"]
        firsts = replay(xi, on_ms, av, e_B, sdd, grid)
        grp = groups(e_B, sdd, av[-1])
        for g in range(G):
            judged[g].append(judge(row, firsts[g], names, grp, h))
        kinds.append(row)
    points = []
    for g in range(G):
        free = [j for j, r in zip(judged[g], kinds, strict=True) if r["fault"] is None]
        faulty = [(j, r) for j, r in zip(judged[g], kinds, strict=True)
                  if r["fault"] is not None and r["verdict"] != "unobservable"]
        fa = sum(j["t_s"] is not None for j in free)
        pre = sum(j["before_fault"] for j, _ in faulty)
        det = [j for j, _ in faulty if j["correct"]]
        lat = [j["latency_s"] for j in det]
        ci_fa = clopper_pearson(fa, len(free))
        ci_det = clopper_pearson(len(det), len(faulty))
        points.append({
            "threshold_on": float(grid.thr_on[g]), "threshold_off": float(grid.thr_off[g]),
            "forgetting_on": float(grid.w_on[g]), "forgetting_off": float(grid.w_off[g]),
            "fault_free_runs": len(free), "false_alarm_runs": fa,
            "false_alarm_rate": fa / len(free) if free else None,
            "false_alarm_ci95": list(ci_fa) if ci_fa else None,
            "fault_runs": len(faulty), "false_alarm_before_fault_runs": pre,
            "detected": len(det), "detection_rate": len(det) / len(faulty) if faulty else None,
            "detection_ci95": list(ci_det) if ci_det else None,
            "latency_p50_s": float(np.percentile(lat, 50)) if lat else None,
            "latency_p90_s": float(np.percentile(lat, 90)) if lat else None,
        })
    return points


def run_sweep(campaigns: list[Campaign], out: Path, *, thresholds: list[float] | None,
              forgetting: list[float] | None, workers: int | None, scheduler: str | None,
              progress: bool = True) -> dict[str, Any]:
    """Simulate (or resume) each campaign once with FDIR off, replay the grid, write outputs."""
    vehicles = {c.vehicle_name for c in campaigns}
    if len(vehicles) != 1:
        raise CampaignError("hil campaign sweep", "FILE", "campaigns of one vehicle",
                            sorted(vehicles))
    vehicle = campaigns[0].vehicle
    det = vehicle["flight"]["detector"]
    if thresholds is None:
        base = float(det["threshold_off"])
        thresholds = [round(base * f, 6) for f in (0.5, 0.75, 1.0, 1.5, 2.0, 3.0)]
    if forgetting is None:
        forgetting = sorted({float(det["forgetting_off"]), 0.8, 0.9, 0.95})
    entries: list[tuple[dict[str, Any], Path]] = []
    runs = 0
    for c in campaigns:
        sc = sweep_campaign(c)
        sub = out / c.name
        res = sub / "residuals"
        res.mkdir(parents=True, exist_ok=True)

        def save(row: dict[str, Any], res: Path = res) -> None:
            r = row.get("_residuals")
            if r is not None:
                np.savez_compressed(res / f"run-{row['run']:05d}.npz", **r)

        outcome = run_campaign(sc, sub, workers=workers, scheduler=scheduler, record=True,
                               kind="sweep", progress=progress, on_row=save)
        if outcome.interrupted:
            raise KeyboardInterrupt
        for row in read_rows(sub / "runs.jsonl"):
            npz = res / f"run-{row['run']:05d}.npz"
            if row["verdict"] not in FAILED and npz.exists():
                entries.append((row, npz))
        runs += c.runs
    grid = Grid.product(thresholds, forgetting)
    points = operating_points(entries, vehicle, grid)
    doc = {"vehicle": vehicle["name"], "campaigns": [c.name for c in campaigns],
           "runs": runs, "replayed_runs": len(entries),
           "configured": {"threshold_on": det["threshold_on"],
                          "threshold_off": det["threshold_off"],
                          "forgetting_on": det["forgetting_on"],
                          "forgetting_off": det["forgetting_off"],
                          "dead_zone_rad_s": det["dead_zone_rad_s"]},
           "points": points}
    (out / "sweep.json").write_text(json.dumps(doc, indent=2) + "\n")
    _plot(doc, out / "sweep.png")
    return doc


def _plot(doc: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = doc["points"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for w in sorted({p["forgetting_off"] for p in pts}):
        ps = sorted((p for p in pts if p["forgetting_off"] == w), key=lambda p: p["threshold_off"])
        fa = [p["false_alarm_rate"] if p["false_alarm_rate"] is not None else
              (p["false_alarm_before_fault_runs"] / p["fault_runs"] if p["fault_runs"] else 0)
              for p in ps]
        lat = [p["latency_p50_s"] for p in ps]
        det = [p["detection_rate"] for p in ps]
        axes[0].plot(fa, [x if x is not None else float("nan") for x in lat], "o-",
                     label=f"w = {w:g}")
        axes[1].plot(fa, [x if x is not None else float("nan") for x in det], "o-",
                     label=f"w = {w:g}")
        for p, x, y in zip(ps, fa, lat, strict=True):
            if y is not None:
                axes[0].annotate(f"{p['threshold_off']:g}", (x, y), fontsize=7)
    axes[0].set_ylabel("detection latency p50 (s)")
    axes[1].set_ylabel("detection rate (observable fault runs)")
    for ax in axes:
        ax.set_xlabel("false-alarm rate (fault-free runs; else before the fault)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{doc['vehicle']}: operating curve over thresholds (labels) and forgetting "
                 f"factors, {doc['replayed_runs']} runs replayed", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
