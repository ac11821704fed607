"""The quick demo's results folder, made once per test run for the tests that read it (tests/test_demo.py and
tests/blender/test_demo_renders.py), also across pytest-xdist's workers: the first test to ask makes it under a
file lock in the run's shared temporary folder, the others find it made. A test that writes into the folder
works on its own copy (``copy_of``)."""

from __future__ import annotations

import json
import shutil

from lab.demo import run_demo

#: The paper's model's epochs in the quick demo (its quality assertions hold from about 20).
EPOCHS = 20


def quick_demo_results(tmp_path_factory, worker_id):
    """``(results folder, its results.json)`` of ``run_demo(quick=True, epochs=EPOCHS, render=False)``."""
    base = tmp_path_factory.getbasetemp()
    shared = base if worker_id == "master" else base.parent
    folder = shared / "quick_demo"
    out = folder / "results"
    try:
        import fcntl
    except ImportError:  # no POSIX file locks: each worker makes its own
        folder, out = base / "quick_demo", base / "quick_demo" / "results"
        fcntl = None
    with open(shared / "quick_demo.lock", "w") as lock:
        if fcntl is not None:
            fcntl.flock(lock, fcntl.LOCK_EX)
        if not (folder / "made").is_file():
            shutil.rmtree(folder, ignore_errors=True)
            run_demo(out, quick=True, epochs=EPOCHS, render=False)
            (folder / "made").touch()
    return out, json.loads((out / "results.json").read_text())


def copy_of(results, where):
    """A copy of the results folder ``results`` at ``where`` (for a test that writes into it)."""
    shutil.copytree(results, where)
    return where
