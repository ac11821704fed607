import json
import subprocess
import sys
from pathlib import Path

import pytest

from garment_transfer.obj import read_obj, write_obj
from garment_transfer.mesh import mesh_from_triangles, require_same_topology
from meshes import icosphere, require_makehuman

ROOT = Path(__file__).resolve().parents[1]


def run(*args):
    return subprocess.run([sys.executable, "-m", "garment_transfer", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture
def makehuman_pair(tmp_path):
    root = require_makehuman()
    g = root / "garments" / "female_sportsuit01"
    return root / "bodies" / "female_average.obj", root / "bodies" / "female_pear.obj", \
        g / "female_average.obj", g / "female_pear.obj"


def test_transfer_and_evaluate_json(tmp_path, makehuman_pair):
    src, tgt, garment, ref = makehuman_pair
    out = tmp_path / "result.obj"
    p = run("transfer", "--source-body", src, "--target-body", tgt, "--garment", garment, "--out", out,
            "--json")
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    assert data["penetrating_vertices"] == 0
    assert {"total", "field", "solve", "fix"} <= set(data["seconds"])
    result = read_obj(out)
    require_same_topology(read_obj(garment), result)    # the garment's own faces
    p = run("evaluate", "--source", garment, "--result", out, "--target-body", tgt, "--reference", ref,
            "--json")
    assert p.returncode == 0, p.stderr
    ev = json.loads(p.stdout)
    for key in ("mdc", "penetration_ratio", "max_penetration_depth", "drape_error", "drape_error_relative",
                "vertex_error_mean", "vertex_error_max"):
        assert isinstance(ev[key], float), key
    assert ev["penetration_ratio"] == 0.0
    assert 0 <= ev["drape_error_relative"] < 1


def test_bad_input_exits_1_names_the_file_and_writes_nothing(tmp_path, makehuman_pair):
    src, tgt, garment, _ = makehuman_pair
    bad = tmp_path / "broken.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    out = tmp_path / "out.obj"
    p = run("transfer", "--source-body", src, "--target-body", tgt, "--garment", bad, "--out", out)
    assert p.returncode == 1
    assert "broken.obj" in p.stderr and len(p.stderr.strip().splitlines()) == 1
    assert not out.exists()
    # Topology mismatch between the bodies.
    V, F = icosphere(1)
    other = tmp_path / "other_body.obj"
    write_obj(other, mesh_from_triangles(V, F))
    p = run("transfer", "--source-body", src, "--target-body", other, "--garment", garment, "--out", out)
    assert p.returncode == 1 and "other_body.obj" in p.stderr and not out.exists()
    p = run("transfer", "--source-body", src, "--target-body", tgt, "--garment", tmp_path / "missing.obj",
            "--out", out)
    assert p.returncode == 1 and "missing.obj: file not found" in p.stderr


def test_usage_error_exits_2():
    assert run("transfer").returncode == 2
    assert run("nonsense").returncode == 2


def test_help_on_every_command():
    for cmd in ("transfer", "evaluate", "train"):
        p = run(cmd, "--help")
        assert p.returncode == 0 and "usage" in p.stdout
    p = run("--help")
    assert p.returncode == 0 and "python -m lab" in p.stdout
    for experiment in ("bench", "demo"):
        assert run(experiment, "--help").returncode == 2      # the lab's, not the product's


def test_train_then_transfer_with_the_model(tmp_path, makehuman_pair):
    root = require_makehuman()
    model = tmp_path / "model.npz"
    p = run("train", "--dataset", root, "--source", "female_average", "--targets", "female_pear,male_slim",
            "--garments", "male_casualsuit02,male_casualsuit04", "--epochs", "5", "--out", model, "--json")
    assert p.returncode == 0, p.stderr
    summary = json.loads(p.stdout)
    assert summary["epochs"] == 5 and isinstance(summary["final_loss"], float) and summary["seconds"] > 0
    assert "train:" in p.stderr        # progress on stderr
    src, tgt, garment, _ = makehuman_pair
    out = tmp_path / "by_model.obj"
    p = run("transfer", "--method", "model", "--model", model, "--target", "female_pear",
            "--source-body", src, "--target-body", tgt, "--garment", garment, "--out", out, "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["penetrating_vertices"] == 0 and out.is_file()
    p = run("transfer", "--method", "model", "--model", model, "--target", "nobody",
            "--source-body", src, "--target-body", tgt, "--garment", garment, "--out", tmp_path / "x.obj")
    assert p.returncode == 1 and "nobody" in p.stderr and not (tmp_path / "x.obj").exists()
