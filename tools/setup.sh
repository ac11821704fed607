#!/usr/bin/env bash
# Creates the virtual environments the project needs, and checks the system libraries that `import bpy`
# needs (installs them with apt-get where it can, else says which).
#   bash tools/setup.sh            .venv/        Python 3.11, requirements.txt       (Blender 5.0, torch: the main one)
#   bash tools/setup.sh --bpy42    .venv-bpy42/  Python 3.11, requirements-bpy42.txt (Blender 4.2 LTS)
#   bash tools/setup.sh --bpy45    .venv-bpy45/  Python 3.11, requirements-bpy45.txt (Blender 4.5 LTS)
#   bash tools/setup.sh --bpy52    .venv-bpy52/  Python 3.13, requirements-bpy52.txt (Blender 5.2, no torch)
# Each environment is installed once; it is installed again only when its requirements file or
# pyproject.toml change (a hash stamp in the environment).
# Where Python 3.13 is not on PATH it is looked for in pyenv's versions; PYTHON311 / PYTHON313 name an
# interpreter explicitly.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"

case "${1:-}" in
  "")       venv=.venv;       reqs=requirements.txt;       want_py=3.11; blender="Blender 5.0" ;;
  --bpy42)  venv=.venv-bpy42; reqs=requirements-bpy42.txt; want_py=3.11; blender="Blender 4.2 LTS" ;;
  --bpy45)  venv=.venv-bpy45; reqs=requirements-bpy45.txt; want_py=3.11; blender="Blender 4.5 LTS" ;;
  --bpy52)  venv=.venv-bpy52; reqs=requirements-bpy52.txt; want_py=3.13; blender="Blender 5.2" ;;
  *) echo "usage: bash tools/setup.sh [--bpy42|--bpy45|--bpy52]" >&2; exit 2 ;;
esac

is_python() {  # is_python EXE VERSION: EXE runs and is that Python version
  "$1" -c "import sys; sys.exit(0 if '%d.%d' % sys.version_info[:2] == '$2' else 1)" >/dev/null 2>&1
}

find_python() {  # find_python VERSION: print an interpreter of that version, or nothing
  local ver="$1" var="PYTHON${1/./}" cand
  if [ -n "${!var:-}" ]; then
    is_python "${!var}" "$ver" && { echo "${!var}"; return; }
    echo "setup: $var=${!var} is not a Python $ver interpreter" >&2
    return
  fi
  # A pyenv shim is on PATH even when that version is not selected, so every candidate is run.
  for cand in "python$ver" "/usr/bin/python$ver" "/usr/local/bin/python$ver" \
              "$(pyenv root 2>/dev/null || echo "$HOME/.pyenv")"/versions/"$ver"*/bin/python"$ver"; do
    if is_python "$cand" "$ver"; then command -v "$cand"; return; fi
  done
  if [ "$ver" = 3.11 ] && is_python python3 3.11; then command -v python3; fi
}

if [ ! -x "$venv/bin/python" ]; then
  PY="$(find_python "$want_py")"
  if [ -z "$PY" ]; then
    echo "setup: Python $want_py is missing: $venv ($blender) needs it, because Blender's bpy module" \
         "for $blender exists for Python $want_py only. Install it (e.g. 'pyenv install $want_py') or" \
         "name it with PYTHON${want_py/./}=/path/to/python$want_py, and run again." >&2
    exit 1
  fi
  echo "setup: creating $venv with $PY" >&2
  "$PY" -m venv "$venv"
fi
if ! is_python "$venv/bin/python" "$want_py"; then
  echo "setup: $venv has $("$venv/bin/python" --version 2>&1), not Python $want_py; delete it and run again" >&2
  exit 1
fi

stamp="$venv/.requirements.sha"
want="$(cat "$reqs" pyproject.toml | sha256sum | cut -d' ' -f1)"
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "setup: installing Python packages into $venv ($blender; the first time takes a few minutes)" >&2
  log="$venv/pip.log"
  # Several environments may be set up at once (by hand: tools/run.sh sets them up one at a time): the
  # editable install writes into this checkout, so it takes a lock. --no-compile: Python compiles what
  # is imported, when it is.
  lock=(); command -v flock >/dev/null 2>&1 && lock=(flock "$root/tools/setup.sh")
  if ! { "$venv/bin/python" -m pip install -q --upgrade pip &&
         "$venv/bin/python" -m pip install -q --no-compile -r "$reqs" &&
         # The core and the lab, installed from this checkout (editable): one garment_transfer in every process.
         ${lock[@]+"${lock[@]}"} "$venv/bin/python" -m pip install -q --no-deps --no-build-isolation -e . ; } >"$log" 2>&1; then
    if grep -q "No space left on device" "$log"; then
      free="$(df -Pk "$root" | awk 'NR == 2 {printf "%.1f", $4 / 1048576}')"
      echo "setup: pip could not install $reqs into $venv: the disk is full ($free GB free beside this" \
           "checkout; each environment takes about 2 GB). Free some space and run again. The end of $log:" >&2
    else
      echo "setup: pip could not install $reqs into $venv (the first install downloads from PyPI: is the" \
           "network reachable?). The end of $log:" >&2
    fi
    tail -n 15 "$log" >&2
    exit 1
  fi
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
    echo "setup: 'import bpy' fails in $venv; install these system libraries and run again: $pkgs" >&2
    "$venv/bin/python" -c 'import bpy' || true
    exit 1
  fi
fi
