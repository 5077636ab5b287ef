"""Flood figures (docs/hostile-bus.md): a real-time run of a reference scenario over vcan0
with a third process flooding the bus, per traffic class and rate. Prints a table; asserts
nothing (a benchmark, docs/style.md habit 8). Run inside user-mode Linux:

    .venv/bin/hil vcan exec -- .venv/bin/python bench/hostile_flood.py [--out DIR]
        [--scenario S.yaml] [--load foreign:5000 catalog-bad-crc:1000 ...]

``none`` is the quiet reference. Figures: flight ticks run / due, missed releases, overruns,
plant safe-state records, safe events, release jitter p99 (ms), frames rejected by class.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
HIL = [sys.executable, "-m", "hil.cli"]


def one(scenario: str, out: Path, load: str, tree: Path | None = None) -> dict:
    flood = None
    if load != "none":
        kind, rate = load.split(":")
        flood = subprocess.Popen(HIL + ["flood", "--class", kind, "--rate", rate,
                                        "--seconds", "0"], stdout=subprocess.PIPE, text=True,
                                 cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        # --tree: the run uses another checkout of the code (the "before" figures).
        env = {**os.environ, "PYTHONPATH": str(tree or ROOT)}
        r = subprocess.run(HIL + ["run", scenario, "--mode", "realtime", "--out", str(out)],
                           capture_output=True, text=True, timeout=900, cwd=tree or ROOT,
                           env=env)
    finally:
        if flood is not None:
            flood.send_signal(signal.SIGINT)
            try:
                flood_out = flood.communicate(timeout=10)[0].strip()
            except subprocess.TimeoutExpired:
                flood.kill()
                flood_out = "killed"
    s = json.loads((out / "summary.json").read_text())
    precs = [json.loads(x) for x in (out / "plant.jsonl").read_text().splitlines()]
    due = int(round(s.get("sim_s", 0) / 0.2)) if s.get("sim_s") else s["ticks"]
    fb = s["bus"]["flight"]
    return {
        "load": load, "exit": r.returncode, "flight_ticks": s["flight_ticks"], "due": due,
        "missed_releases": s.get("missed_releases"), "overruns": s["overruns"],
        "plant_safe_records": sum(1 for p in precs if p.get("safe")),
        "safe_events": len(s["safe_events"]),
        "jitter_p99_ms": (s.get("release_jitter_ms") or {}).get("p99"),
        "flight_rejects": {k: fb.get(k, 0) for k in ("unknown_id", "bad_crc", "kernel_drops",
                                                    "polls_capped") if fb.get(k)},
        "false_alarms": len(s["false_alarms"]), "flood": flood_out if flood else "",
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="runs/flood")
    ap.add_argument("--scenario", default=str(ROOT / "configs/scenarios/S000-stuck.yaml"))
    ap.add_argument("--tree", type=Path, help="run the nodes from this checkout instead")
    ap.add_argument("--load", nargs="*", default=["none", "foreign:5000", "catalog-bad-crc:1000"])
    a = ap.parse_args()
    rows = []
    for k, load in enumerate(a.load):
        row = one(a.scenario, Path(a.out).resolve() / f"{k}-{load.replace(':', '-')}", load,
                  a.tree)
        rows.append(row)
        print(json.dumps(row), flush=True)
    print("| load | flight ticks run / due | missed releases | overruns | plant safe records | "
          "jitter p99 ms | flight rejects | false alarms |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['load']} | {r['flight_ticks']} / {r['due']} | {r['missed_releases']} | "
              f"{r['overruns']} | {r['plant_safe_records']} | {r['jitter_p99_ms']} | "
              f"{r['flight_rejects']} | {r['false_alarms']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
