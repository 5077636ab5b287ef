"""``hil soak``: a long run that measures what grows: memory of each process, output files.

``hil soak [--vehicle V | --scenario S] --hours H [--mode realtime|lockstep]`` runs one
scenario of H hours of simulated time through ``hil run``'s supervisor (lockstep runs as fast
as the CPU allows, real time takes H hours), samples every ``--sample-s`` wall seconds the
resident memory (``VmRSS``) of the plant and flight processes and the size of every output
file, and reports each as a growth rate per simulated hour (least-squares slope over the
second half of the run, after start-up transients) with the overruns and missed releases of
the run's summary. Writes ``DIR/soak.json`` beside the run's usual outputs; exit 0 when the
figures were measured (the run's verdict is printed, not judged: a soak measures).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hil.argtypes import number

FILES = ("plant.jsonl", "flight.jsonl", "run.rrd", "bus.log")


def rss_kb(pid: int) -> int | None:
    """Resident set size of ``pid`` in kB (``/proc/PID/status`` VmRSS), None when gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


def last_t_s(path: Path) -> float | None:
    """Simulated time of the last whole record of a JSON lines file (reads its tail only)."""
    try:
        with path.open("rb") as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - 65536))
            tail = f.read().decode("utf-8", "replace").splitlines()
    except OSError:
        return None
    for line in reversed(tail[1:] if len(tail) > 1 else tail):
        try:
            return float(json.loads(line)["t_s"])
        except (ValueError, KeyError, TypeError):
            continue
    return None


class Sampler(threading.Thread):
    """Samples process memory and file sizes of a run folder every ``period_s`` wall seconds."""

    def __init__(self, out: Path, period_s: float) -> None:
        super().__init__(daemon=True)
        self.out, self.period_s = out, period_s
        self.samples: list[dict[str, Any]] = []
        self._halt = threading.Event()

    def _pids(self) -> dict[str, int]:
        pids = {}
        for node in ("plant", "flight"):
            try:
                pids[node] = int((self.out / f"{node}.ready").read_text())
            except (OSError, ValueError):
                pass
        return pids

    def sample(self) -> None:
        t_sim = last_t_s(self.out / "plant.jsonl")
        if t_sim is None:
            return
        row: dict[str, Any] = {"wall_s": time.monotonic(), "sim_s": t_sim}
        for node, pid in self._pids().items():
            row[f"{node}_rss_kb"] = rss_kb(pid)
        for name in FILES:
            p = self.out / name
            row[f"{name}_bytes"] = p.stat().st_size if p.exists() else None
        self.samples.append(row)

    def run(self) -> None:
        while not self._halt.wait(self.period_s):
            self.sample()

    def stop(self) -> None:
        self._halt.set()
        self.join(5.0)


def growth_per_hour(samples: list[dict[str, Any]], key: str) -> float | None:
    """Least-squares slope of ``key`` per simulated hour over the second half of the samples
    (start-up, imports and first allocations excluded); None with fewer than 4 points."""
    pts = [(s["sim_s"], s[key]) for s in samples if s.get(key) is not None]
    pts = pts[len(pts) // 2:]
    if len(pts) < 4 or pts[-1][0] - pts[0][0] <= 0:
        return None
    t, y = np.array(pts, dtype=float).T
    return float(np.polyfit(t / 3600.0, y, 1)[0])


def figures(samples: list[dict[str, Any]]) -> dict[str, Any]:
    """Start, end and growth per simulated hour of every sampled quantity (MB)."""
    out: dict[str, Any] = {"samples": len(samples)}
    if not samples:
        return out
    keys = [k for k in samples[-1] if k.endswith(("_rss_kb", "_bytes"))]
    for k in keys:
        scale = 1024.0 if k.endswith("_kb") else 1024.0 * 1024.0
        name = k.rsplit("_", 2 if k.endswith("_rss_kb") else 1)[0]
        vals = [s[k] for s in samples if s.get(k) is not None]
        slope = growth_per_hour(samples, k)
        out[name + ("_rss_mb" if k.endswith("_rss_kb") else "_mb")] = {
            "first": round(vals[0] / scale, 3) if vals else None,
            "last": round(vals[-1] / scale, 3) if vals else None,
            "per_sim_hour": None if slope is None else round(slope / scale, 3),
        }
    out["sim_s"] = samples[-1]["sim_s"]
    out["wall_s"] = round(samples[-1]["wall_s"] - samples[0]["wall_s"], 1)
    return out


def _scenario_file(args, tmp: Path) -> Path:
    duration = args.hours * 3600.0
    if args.scenario:
        from hil.config import read_config  # the bounded loader: one-line errors

        data = read_config(Path(args.scenario))
        data["duration_s"] = duration
        data["name"] = f"{data.get('name', 'soak')}-soak"
    else:
        data = {"name": f"soak-{args.vehicle}", "vehicle": args.vehicle, "duration_s": duration,
                "seed": 1, "initial": {"attitude": {"axis": [1.0, 0.5, 0.2], "angle_deg": 20.0}},
                "expect": {"no_false_alarm": True}}
    path = tmp / "soak.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    from hil.config import load_scenario

    load_scenario(path)  # config errors exit 2 before anything starts
    return path


def _cmd_soak(args) -> int:
    out = Path(args.out or f"runs/soak-{args.vehicle}").resolve()
    tmp = Path(tempfile.mkdtemp(prefix="hil-soak-"))
    try:
        return _soak(args, out, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)  # the generated scenario file


def _soak(args, out: Path, tmp: Path) -> int:
    from hil.config import load_scenario
    from hil.run import _batch_policy, maybe_in_netns, maybe_in_uml, resolve_bus, supervise

    scenario = _scenario_file(args, tmp)
    resolve_bus(args, load_scenario(scenario))  # --bus, else the scenario's bus:, else can
    argv = ["soak", "--hours", str(args.hours), "--mode", args.mode, "--out", str(out),
            "--sample-s", str(args.sample_s), "--interface", args.interface,
            "--channel", args.channel] + (["--bus", "can"] if args.interface != "lcm" else [])
    argv += ["--scenario", str(Path(args.scenario).resolve())] if args.scenario else \
        ["--vehicle", args.vehicle]
    rc = maybe_in_netns(args, argv)  # LCM: a private network namespace (hil.netns)
    if rc is None:
        rc = maybe_in_uml(args, argv)
    if rc is not None:
        return rc
    _batch_policy()
    out.mkdir(parents=True, exist_ok=True)
    sampler = Sampler(out, args.sample_s)
    sampler.start()
    args.rt_priority = False
    try:
        summary = supervise(scenario, out, args, quiet=True)
    finally:
        sampler.stop()
    sampler.sample()
    fig = figures(sampler.samples)
    fig.update(mode=args.mode, vehicle=summary["vehicle"], verdict=summary["verdict"],
               run_failures=summary["run_failures"], overruns=summary["overruns"],
               missed_releases=summary["missed_releases"],
               overruns_per_sim_hour=round(summary["overruns"] / max(fig.get("sim_s", 0) /
                                                                     3600.0, 1e-9), 3))
    (out / "soak.json").write_text(json.dumps({"figures": fig, "samples": sampler.samples},
                                              indent=2) + "\n")
    print(f"soak: {fig.get('sim_s', 0) / 3600:.2f} h simulated in {fig.get('wall_s', 0):.0f} s "
          f"wall ({args.mode}); growth per simulated hour (second half, least squares):")
    for k, v in fig.items():
        if isinstance(v, dict) and "per_sim_hour" in v:
            print(f"  {k:<22} {v['first']!s:>10} -> {v['last']!s:>10} MB, "
                  f"{v['per_sim_hour']!s:>8} MB/h")
    print(f"  overruns {fig['overruns']}, missed releases {fig['missed_releases']}, run "
          f"verdict {fig['verdict']}; {out / 'soak.json'}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("soak", help="long run measuring memory and file growth per hour",
                       description=__doc__.split("\n\n")[1])
    p.add_argument("--vehicle", default="orel", help="vehicle of a generated hold (orel)")
    p.add_argument("--scenario", help="scenario file instead (its duration is replaced)")
    p.add_argument("--hours", type=number(gt=0, le=168), required=True,
                   help="simulated hours (real time: wall hours too)")
    p.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    p.add_argument("--sample-s", type=number(gt=0, le=3600), default=5.0,
                   help="wall seconds between samples (5)")
    p.add_argument("--out", metavar="DIR", help="output folder (default runs/soak-<vehicle>)")
    p.add_argument("--interface", help="python-can interface (default socketcan)")
    p.add_argument("--channel", help="bus channel (default vcan0)")
    p.add_argument("--bus", choices=("can", "lcm"),
                   help="can (--interface/--channel) or lcm (a private network namespace; "
                        "docs/lcm.md); default: the scenario's bus:, else can")
    p.add_argument("--lcm-url", metavar="URL", help="LCM provider with --bus lcm")
    p.set_defaults(func=_cmd_soak, kill_flight_at=None)

