#!/usr/bin/env bash
# Creates a virtual environment with everything the project needs, and checks the system libraries
# that `import bpy` needs (installs them with apt-get where it can, else says which).
#   bash tools/setup.sh            .venv/        from requirements.txt (bpy 5.0)
#   bash tools/setup.sh --bpy45    .venv-bpy45/  from requirements-bpy45.txt (Blender 4.5 LTS)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
venv=.venv
reqs=requirements.txt
if [ "${1:-}" = "--bpy45" ]; then venv=.venv-bpy45; reqs=requirements-bpy45.txt; fi
PY="${PYTHON:-python3.11}"
command -v "$PY" >/dev/null 2>&1 || PY=python3
if ! "$PY" -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)'; then
  echo "setup: Python 3.11 is required (Blender's bpy module exists for 3.11 only); found $("$PY" --version 2>&1)" >&2
  exit 1
fi
if [ ! -x "$venv/bin/python" ]; then
  echo "setup: creating $venv" >&2
  "$PY" -m venv "$venv"
fi
stamp="$venv/.requirements.sha"
want="$(cat "$reqs" pyproject.toml | sha256sum | cut -d' ' -f1)"
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "setup: installing Python packages into $venv (first time takes a few minutes)" >&2
  "$venv/bin/python" -m pip install -q --upgrade pip
  "$venv/bin/python" -m pip install -q -r "$reqs"
  # The core and the lab, installed from this checkout (editable): one garment_transfer in every process.
  "$venv/bin/python" -m pip install -q --no-deps --no-build-isolation -e .
  echo "$want" > "$stamp"
fi
# System libraries for `import bpy` (Debian names).
if ! "$venv/bin/python" -c 'import bpy' >/dev/null 2>&1; then
  pkgs="libx11-6 libxrender1 libxfixes3 libxi6 libxkbcommon0 libxxf86vm1 libsm6 libgl1 libegl1"
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "setup: installing system libraries for bpy: $pkgs" >&2
    apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $pkgs >/dev/null
  fi
  if ! "$venv/bin/python" -c 'import bpy' >/dev/null 2>&1; then
    echo "setup: 'import bpy' fails; install these system libraries and run again: $pkgs" >&2
    "$venv/bin/python" -c 'import bpy' || true
    exit 1
  fi
fi
