#!/usr/bin/env bash
# The main job: set-up, then run the reference scenario of seed 000 (X+ thruster stuck on).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/hil config check configs/vehicles/*.yaml
