#!/usr/bin/env bash
# The project's two entry points. Both set everything up first (tools/setup.sh).
#   bash tools/run.sh demo [args]   the main job on the built-in demo data (results/)
#   bash tools/run.sh test [args]   the test suite; with no args also the Blender tests under
#                                   Blender 4.5 LTS (bpy 4.5, in .venv-bpy45/)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
cmd="${1:-}"; shift || true
case "$cmd" in
  demo)
    bash tools/setup.sh
    exec .venv/bin/python -m lab demo "$@" ;;
  test)
    bash tools/setup.sh
    if [ $# -gt 0 ]; then exec .venv/bin/python -m pytest -q "$@"; fi
    status=0
    echo "== tests under Blender 4.5 LTS (bpy 4.5): tests/blender ==" >&2
    bash tools/setup.sh --bpy45
    .venv-bpy45/bin/python -m pytest -q tests/blender || status=$?
    echo "== all tests under Blender 5.0 (bpy 5.0.1) ==" >&2
    .venv/bin/python -m pytest -q || status=$?
    exit $status ;;
  *) echo "usage: bash tools/run.sh demo|test [args]" >&2; exit 2 ;;
esac
