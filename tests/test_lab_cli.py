"""``python -m lab``: the lab's commands run as a user runs them."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(*args):
    return subprocess.run([sys.executable, "-m", "lab", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


def test_help_on_every_lab_command():
    p = run("--help")
    assert p.returncode == 0
    for cmd in ("demo", "bench", "report", "heldout", "training-scale", "make-data", "render"):
        assert cmd in p.stdout
    for cmd in ("demo", "bench", "report", "heldout", "training-scale"):
        p = run(cmd, "--help")
        assert p.returncode == 0 and "usage" in p.stdout, (cmd, p.stderr)


def test_bench_small_runs():
    p = run("bench", "--sizes", "3000,6000", "--repeats", "1", "--targets", "2", "--json")
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    assert [r["requested"] for r in data["sizes"]] == [3000, 6000]
    for r in data["sizes"]:
        assert abs(r["triangles"] - r["requested"]) / r["requested"] < 0.05
        assert r["cold"]["penetrating_vertices"] == 0
    assert len(data["multi_target"]["per_target_seconds"]) == 2


def test_bench_refuses_sizes_and_repeats_out_of_range():
    for args in (("--repeats", "0"), ("--sizes", "-5"), ("--sizes", "")):
        p = run("bench", *args)
        assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr


def test_multigrid_study_compares_the_cycles_on_a_real_system():
    # A small benchmark dress (multigrid from 40K vertices: 90K triangles): every variant answers within
    # the tolerance of pyamg's cycle.
    p = subprocess.run([sys.executable, "-m", "lab.multigrid", "--sizes", "90000", "--repeats", "1"], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    rows = [line for line in p.stdout.splitlines() if "iterations" in line]
    assert len(rows) == 3
    for line in rows:
        assert float(line.rsplit("difference", 1)[1]) < 1e-6


def test_the_garment_model_study_passes_the_placement_options_given():
    import inspect
    from argparse import Namespace

    from garment_transfer.learning.garment_training import train_placement_model
    from lab.garment_model import placement_options

    unset = Namespace(placement_hidden=None, placement_lr=None, placement_schedule=None, placement_weight_decay=None,
                      placement_weighted=False, placement_residual=False)
    assert placement_options(unset) == {}
    given = Namespace(placement_hidden="128,96", placement_lr=0.003, placement_schedule="cosine",
                      placement_weight_decay=0.01, placement_weighted=True, placement_residual=True)
    options = placement_options(given)
    assert options == {"hidden": (128, 96), "lr": 0.003, "schedule": "cosine", "weight_decay": 0.01,
                       "weighted": True, "residual": True}
    assert set(options) <= set(inspect.signature(train_placement_model).parameters)
