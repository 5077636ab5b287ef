"""Flood figures on a scenario file (docs/hostile-bus.md sections 5 and 7): ``hil bench --parts
hostile`` (``hil.hostile``) runs the bench's generated scenario; this runs the same campaign on
any scenario (S000-stuck by default, the one of the first figures). Prints the table; asserts
nothing (a benchmark, docs/style.md habit 8). Run where vcan0 exists:

    .venv/bin/hil vcan exec -- .venv/bin/python bench/hostile_flood.py [--out DIR]
        [--scenario S.yaml] [--load none foreign:5000 catalog-bad-crc:1000 ...]
        [--duration S]

``none`` is the quiet reference; the classes are ``hil flood``'s.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import yaml

from hil.config import REPO_ROOT
from hil.hostile import format_rows, judge, load_name, parse_loads, run_one


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="runs/flood")
    ap.add_argument("--scenario", default=str(REPO_ROOT / "configs/scenarios/S000-stuck.yaml"))
    ap.add_argument("--load", nargs="*", default=["none", "foreign:5000", "catalog-bad-crc:1000"])
    ap.add_argument("--duration", type=float, help="seconds of each run (default the scenario's)")
    ap.add_argument("--channel", default="vcan0")
    a = ap.parse_args()
    scenario = yaml.safe_load(Path(a.scenario).read_text())
    if a.duration:
        scenario["duration_s"] = a.duration
    a.rt = False
    rows = []
    for k, (kind, rate) in enumerate(parse_loads(",".join(a.load))):
        name = load_name(kind, rate)
        row = run_one(kind, rate, scenario, Path(a.out).resolve() / f"{k}-{name.replace(':', '-')}",
                      a, seed=k + 1)
        rows.append(row)
        print(json.dumps(row), flush=True)
    print("\n".join(format_rows({"vehicle": scenario["vehicle"],
                                 "duration_s": scenario["duration_s"], "runs": rows,
                                 **judge(rows)})))
    return 0


if __name__ == "__main__":
    sys.exit(main())
