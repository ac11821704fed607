#!/usr/bin/env bash
# The project's two entry points. Both set everything up first (tools/setup.sh).
#   bash tools/run.sh demo [args]   the main job on built-in demo data
#   bash tools/run.sh test [args]   the test suite
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
cmd="${1:-}"; shift || true
bash tools/setup.sh
case "$cmd" in
  demo) exec .venv/bin/python -m garment_transfer demo "$@" ;;
  test) exec .venv/bin/python -m pytest -q "$@" ;;
  *) echo "usage: bash tools/run.sh demo|test [args]" >&2; exit 2 ;;
esac
