"""tools/setup.sh when pip fails: a full disk is said to be one, with the space left; anything else points at
the network. Run on a copy of the script beside an environment whose pip fails as pip does."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(shutil.which("bash") is None or os.name != "posix",
                                reason="the set-up is a bash script")


def set_up_with_failing_pip(root, pip_error):
    """Run a copy of tools/setup.sh --bpy42 in ``root``, whose .venv-bpy42's pip prints ``pip_error`` and fails."""
    (root / "tools").mkdir()
    shutil.copy(ROOT / "tools" / "setup.sh", root / "tools" / "setup.sh")
    for name in ("requirements-bpy42.txt", "pyproject.toml"):
        shutil.copy(ROOT / name, root / name)
    python = root / ".venv-bpy42" / "bin" / "python"
    python.parent.mkdir(parents=True)
    # Anything but pip runs this Python (a 3.11, as the environment's must be).
    python.write_text(f'#!/usr/bin/env bash\nif [ "$1 $2" = "-m pip" ]; then\n  echo "{pip_error}" >&2\n'
                      f'  exit 1\nfi\nexec {sys.executable} "$@"\n')
    python.chmod(0o755)
    return subprocess.run(["bash", str(root / "tools" / "setup.sh"), "--bpy42"], capture_output=True, text=True,
                          timeout=60)


def test_a_set_up_that_runs_out_of_disk_says_so(tmp_path):
    p = set_up_with_failing_pip(tmp_path, "ERROR: Could not install packages due to an OSError: [Errno 28] No "
                                          "space left on device")
    assert p.returncode == 1
    assert "could not install requirements-bpy42.txt into .venv-bpy42: the disk is full (" in p.stderr
    assert "GB free beside this checkout; each environment takes about 2 GB" in p.stderr
    assert "network" not in p.stderr
    assert "No space left on device" in p.stderr                                 # the end of pip's log
    assert not (tmp_path / ".venv-bpy42" / ".requirements.sha").exists()        # installed again next time


def test_a_set_up_that_fails_otherwise_points_at_the_network(tmp_path):
    p = set_up_with_failing_pip(tmp_path, "ERROR: Could not find a version that satisfies the requirement bpy")
    assert p.returncode == 1
    assert "could not install requirements-bpy42.txt into .venv-bpy42 (" in p.stderr
    assert "is the network reachable?" in p.stderr and "disk is full" not in p.stderr
