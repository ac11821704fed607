#!/usr/bin/env bash
# The README's two commands (demo, test), and the other Blenders' tests (versions). Each sets up what it
# needs first (tools/setup.sh).
#   bash tools/run.sh demo [args]   the main job on the built-in demo data (results/)
#   bash tools/run.sh test [args]   the test suite under Blender 5.0 (.venv/): with no args the whole
#                                   suite on both cores, else pytest with these args.
#   bash tools/run.sh versions      the Blender-layer tests (tests/blender, but for the lab's own Blender
#                                   scripts) under Blender 4.2 LTS, 4.5 LTS and 5.2 (.venv-bpy42/,
#                                   .venv-bpy45/, .venv-bpy52/); it fails if any of them fails.
# CI (.ci/run) runs test, then versions.
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
    echo "== all tests under Blender 5.0 (.venv) ==" >&2
    # On both cores: the tests are independent of each other (their own temporary folders). A file's tests
    # run in one worker (--dist loadscope), so that a module's fixtures (bodies, transfers, a quick demo) are
    # made once, not once in each worker that draws one of its tests.
    exec .venv/bin/python -m pytest -q -n 2 --dist loadscope ;;
  versions)
    if [ $# -gt 0 ]; then echo "usage: bash tools/run.sh versions (it takes no arguments)" >&2; exit 2; fi
    versions=("bpy42:Blender 4.2 LTS" "bpy45:Blender 4.5 LTS" "bpy52:Blender 5.2")
    # The Blenders' environments are set up one at a time, each while the tests of the one before it
    # run: at most two of them are being set up or used at once. With GARMENT_TRANSFER_DISCARD_ENVS=1
    # (.ci/run: a fresh machine, whose disk is small) each is removed once its tests have run, so the run
    # never holds more than two of them (about 2 GB each).
    discard="${GARMENT_TRANSFER_DISCARD_ENVS:-0}"
    logs="$(mktemp -d)"
    trap 'rm -rf "$logs"' EXIT
    setup_pid=""
    start_setup() {  # start_setup V: set up .venv-V in the background; its exit status lands in $logs/V.rc
      ( rc=0; bash tools/setup.sh "--$1" >"$logs/$1.log" 2>&1 || rc=$?; echo "$rc" >"$logs/$1.rc" ) &
      setup_pid=$!
    }
    start_setup "${versions[0]%%:*}"
    status=0
    for i in "${!versions[@]}"; do
      version="${versions[$i]}"
      v="${version%%:*}"
      echo "== tests/blender under ${version#*:} (.venv-$v) ==" >&2
      wait "$setup_pid" || true
      next="${versions[$((i + 1))]:-}"
      if [ -n "$next" ]; then start_setup "${next%%:*}"; fi
      cat "$logs/$v.log" >&2 2>/dev/null || true
      if [ "$(cat "$logs/$v.rc" 2>/dev/null)" = 0 ]; then
        # The lab's Blender scripts (renders, demo data) run in the project's own Blender only.
        ".venv-$v/bin/python" -m pytest -q -n 2 --dist loadscope -m "not lab" tests/blender || status=$?
      else
        echo "run: the set-up of .venv-$v failed (above); its tests did not run" >&2
        status=1
      fi
      if [ "$discard" = 1 ]; then rm -rf ".venv-$v"; fi
    done
    exit $status ;;
  *) echo "usage: bash tools/run.sh demo [args] | test [args] | versions" >&2; exit 2 ;;
esac
