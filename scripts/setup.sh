#!/usr/bin/env bash
# Idempotent set-up for a fresh Debian machine with Python 3.11: Debian packages for vcan and
# user-mode Linux, a virtual environment in .venv, and this project installed into it.
set -euo pipefail
cd "$(dirname "$0")/.."

# util-linux: unshare and nsenter, for the private network namespace of LCM runs (hil.netns).
# tmux: the console test drives `hil up --console` in a real 80x24 terminal.
DEB_PACKAGES=(user-mode-linux busybox-static can-utils iproute2 kmod util-linux tmux)
missing=()
for p in "${DEB_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""
  if [ "$(id -u)" != 0 ]; then
    command -v sudo >/dev/null || { echo "error: setup: Debian packages ${missing[*]} are missing and this user is not root (no sudo)" >&2; exit 2; }
    SUDO="sudo"
  fi
  echo "setup: installing Debian packages: ${missing[*]}"
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}" </dev/null
fi

PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null || PY=python3
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $PY"
  "$PY" -m venv .venv
fi
# Reinstall only when the dependency list changed.
stamp=.venv/.hil-installed
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "setup: installing Python packages into .venv"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e ".[test]"
  echo "$want" > "$stamp"
fi
# Byte-compile the project once: the first process start inside user-mode Linux (slow CPU)
# would otherwise compile every module while the supervisor waits for it to be ready.
.venv/bin/python -m compileall -q common hil bus flight plant >/dev/null
