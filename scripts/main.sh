#!/usr/bin/env bash
# The main job: set-up, then the reference scenario of seed 000 (X+ thruster stuck on at 18 s)
# run end to end: plant and flight processes over vcan0 in lockstep (inside user-mode Linux
# where the kernel has no CAN), with summary.json, bus.log and run.rrd in runs/S000-stuck.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export RERUN_ANALYTICS=0
.venv/bin/hil run configs/scenarios/S000-stuck.yaml --mode lockstep --out runs/S000-stuck "$@"
