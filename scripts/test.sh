#!/usr/bin/env bash
# The test command: set-up, then the unit tests, then the integration tests over a real vcan0
# (native where the kernel has CAN, otherwise inside user-mode Linux).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/python -m pytest -m "not vcan" -q "$@"
