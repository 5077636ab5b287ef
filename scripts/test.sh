#!/usr/bin/env bash
# The test command: set-up, then the unit tests, then the integration tests over a real vcan0
# (native where the kernel has CAN, otherwise inside user-mode Linux: never skipped).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export RERUN_ANALYTICS=0
echo "== unit tests"
.venv/bin/python -m pytest -m "not vcan and not reference and not lcm" -q -p no:cacheprovider "$@"
echo "== integration tests over vcan0"
.venv/bin/hil vcan exec -- .venv/bin/python -m pytest -m vcan -q -p no:cacheprovider "$@"
echo "== integration tests over LCM (udpm in a private network namespace: never skipped)"
.venv/bin/hil netns exec -- .venv/bin/python -m pytest -m lcm -q -p no:cacheprovider "$@"
echo "== reference scenarios over vcan0 (hil run-all: native, or user-mode Linux instances)"
.venv/bin/python -m pytest -m reference -q -p no:cacheprovider "$@"
