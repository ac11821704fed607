#!/usr/bin/env bash
# The project's two entry points. Both set everything up first (tools/setup.sh).
#   bash tools/run.sh demo [args]   the main job on the built-in demo data (results/)
#   bash tools/run.sh test [args]   the test suite under Blender 5.0 (.venv/). With no args: the whole
#                                   suite under Blender 5.0, then the Blender-layer tests (tests/blender,
#                                   but for the lab's own Blender scripts) under Blender 4.2 LTS, 4.5 LTS
#                                   and 5.2 (.venv-bpy42/, .venv-bpy45/, .venv-bpy52/); it fails if any
#                                   of them fails.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
# Python writes the compiled form of what it imports (.pyc, in __pycache__ folders: the environments', the
# checkout's, all ignored by git): without it, every process of the test suite and the demo compiles torch,
# scipy, bpy and the project again from source (seconds each; machines that set PYTHONDONTWRITEBYTECODE).
unset PYTHONDONTWRITEBYTECODE
cmd="${1:-}"; shift || true
case "$cmd" in
  demo)
    bash tools/setup.sh
    exec .venv/bin/python -m lab demo "$@" ;;
  test)
    bash tools/setup.sh
    if [ $# -gt 0 ]; then exec .venv/bin/python -m pytest -q "$@"; fi
    versions=("bpy42:Blender 4.2 LTS" "bpy45:Blender 4.5 LTS" "bpy52:Blender 5.2")
    # The other Blenders' environments are set up (mostly downloads) while the main suite runs.
    logs="$(mktemp -d)"
    trap 'rm -rf "$logs"' EXIT
    setups=()
    for version in "${versions[@]}"; do
      v="${version%%:*}"
      ( rc=0; bash tools/setup.sh "--$v" >"$logs/$v.log" 2>&1 || rc=$?; echo "$rc" >"$logs/$v.rc" ) &
      setups+=($!)
    done
    status=0
    echo "== all tests under Blender 5.0 (.venv) ==" >&2
    # On both cores: the tests are independent of each other (their own temporary folders).
    .venv/bin/python -m pytest -q -n 2 || status=$?
    for i in "${!versions[@]}"; do
      version="${versions[$i]}"
      v="${version%%:*}"
      echo "== tests/blender under ${version#*:} (.venv-$v) ==" >&2
      while [ ! -f "$logs/$v.rc" ] && kill -0 "${setups[$i]}" 2>/dev/null; do sleep 2; done
      cat "$logs/$v.log" >&2 2>/dev/null || true
      if [ "$(cat "$logs/$v.rc" 2>/dev/null)" = 0 ]; then
        # The lab's Blender scripts (renders, demo data) run in the project's own Blender only.
        ".venv-$v/bin/python" -m pytest -q -n 2 -m "not lab" tests/blender || status=$?
      else
        echo "run: the set-up of .venv-$v failed (above); its tests did not run" >&2
        status=1
      fi
    done
    wait "${setups[@]}" || true
    exit $status ;;
  *) echo "usage: bash tools/run.sh demo|test [args]" >&2; exit 2 ;;
esac
