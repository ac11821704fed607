import json
import subprocess
import sys
from pathlib import Path

import pytest
from meshes import icosphere, require_makehuman

from garment_transfer.geometry.mesh import mesh_from_triangles, require_same_topology
from garment_transfer.geometry.obj import read_obj, write_obj

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
    # The version a pipeline records: the package's, which the extension's manifest gives too.
    import tomllib

    from garment_transfer import __version__

    p = run("--version")
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert p.returncode == 0 and p.stdout == f"garment_transfer {__version__}\n" and manifest["version"] == __version__
    for experiment in ("bench", "demo"):
        assert run(experiment, "--help").returncode == 2      # the lab's, not the product's


def test_train_then_transfer_with_the_model(tmp_path, makehuman_pair):
    root = require_makehuman()
    model = tmp_path / "model.npz"
    p = run("train", "--kind", "shared", "--dataset", root, "--source", "female_average", "--targets",
            "female_pear,male_slim",
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


def as_written(V):
    """Coordinates as an OBJ written by the command line holds them (``obj.obj_text``: 9 digits)."""
    import numpy as np

    return np.vectorize(lambda x: float("%.9g" % x))(V)


def test_train_garment_kind_then_transfer_equals_the_core(tmp_path):
    pytest.importorskip("torch")
    import numpy as np
    from test_dataset import make_tiny_dataset

    from garment_transfer.learning.model_files import read_model_file
    from garment_transfer.pipeline.transfer import transfer_garment

    ds = make_tiny_dataset(tmp_path / "ds")
    model = tmp_path / "garment.npz"
    # The garment fit model is train's default kind.
    p = run("train", "--dataset", ds, "--source", "src", "--targets", "similar,pear",
            "--garments", "band,skirt", "--placement-epochs", "10", "--out", model, "--json")
    assert p.returncode == 0, p.stderr
    summary = json.loads(p.stdout)
    assert summary["kind"] == "garment" and summary["field"]["epochs"] == 3
    assert summary["placement"]["epochs"] == 10 and "train:" in p.stderr
    # The default placement: several members, averaged, in the one file.
    from garment_transfer.learning.garment_training import PLACEMENT_MEMBERS
    from garment_transfer.learning.placement import PlacementEnsemble

    assert PLACEMENT_MEMBERS > 1 and summary["placement"]["members"] == PLACEMENT_MEMBERS
    assert sorted(f.name for f in tmp_path.iterdir()) == ["ds", "garment.npz"]     # no temporary file left

    src, tgt, garment = (ds / "bodies" / "src.obj", ds / "bodies" / "pear.obj",
                         ds / "garments" / "top" / "src.obj")
    out = tmp_path / "top_on_pear.obj"
    p = run("transfer", "--model", model, "--source-body", src, "--target-body", tgt, "--garment", garment,
            "--out", out, "--json")
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    assert (data["method"], data["model"], data["model_kind"], data["field_share"], data["placement"]) == \
        ("model", str(model), "garment", 0.5, True)
    assert data["nearest_garments"] == summary["library"]["share"]
    loaded = read_model_file(model)
    # The networks mixed with the nearest garments' placement (the default share).
    from garment_transfer.learning.placement import LIBRARY_SHARE, MixedPlacement

    mixed = loaded.placement.model
    assert isinstance(mixed, MixedPlacement) and mixed.share == LIBRARY_SHARE == summary["library"]["share"]
    assert isinstance(mixed.model, PlacementEnsemble) and len(mixed.model.members) == PLACEMENT_MEMBERS
    # Each member learned the offset less the training garments' mean offset (placement format version 2).
    assert all(m.metadata["format_version"] == 2 and "offset_base" in m.arrays for m in mixed.model.members)
    expect = transfer_garment(read_obj(src), read_obj(tgt), read_obj(garment), method="model", model=loaded.model,
                              placement=loaded.placement).V
    # The same to the last digit of the file (9 significant digits).
    np.testing.assert_array_equal(read_obj(out).V, as_written(expect))
    p = run("transfer", "--model", model, "--source-body", src, "--target-body", tgt, "--garment", garment,
            "--out", tmp_path / "whole.obj", "--field-share", "1", "--no-placement")
    assert p.returncode == 0, p.stderr
    assert "model: garment fit model (garment.npz), field share 1, placement left out" in p.stdout
    whole = read_model_file(model, field_share=1.0, use_placement=False)
    expect_whole = transfer_garment(read_obj(src), read_obj(tgt), read_obj(garment), method="model",
                                    model=whole.model).V
    np.testing.assert_array_equal(read_obj(tmp_path / "whole.obj").V, as_written(expect_whole))
    assert np.abs(expect_whole - expect).max() > 1e-5
    # --placement-absolute --nearest-garments 0: the placement as before (format version 1, no mean offset,
    # no nearest garments).
    absolute = tmp_path / "absolute.npz"
    p = run("train", "--kind", "garment", "--dataset", ds, "--source", "src", "--targets", "similar,pear",
            "--garments", "band,skirt", "--placement-epochs", "10", "--placement-members", "1",
            "--placement-absolute", "--nearest-garments", "0", "--out", absolute, "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["library"] is None
    placed = read_model_file(absolute).placement.model
    assert placed.metadata["format_version"] == 1 and "offset_base" not in placed.arrays
    p = run("train", "--kind", "garment", "--dataset", ds, "--source", "src", "--targets", "similar,pear",
            "--garments", "band,skirt", "--nearest-garments", "1.5", "--out", tmp_path / "bad.npz")
    assert p.returncode == 2 and "--nearest-garments" in p.stderr and not (tmp_path / "bad.npz").exists()


def test_train_refuses_names_the_dataset_lacks_before_it_needs_torch(tmp_path):
    import os

    from test_dataset import make_tiny_dataset

    ds = make_tiny_dataset(tmp_path / "ds")
    # A torch that cannot be imported, found first: the names are checked before it is asked for.
    (tmp_path / "blocked" / "torch").mkdir(parents=True)
    (tmp_path / "blocked" / "torch" / "__init__.py").write_text("raise ImportError('blocked here')\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path / "blocked"), str(ROOT)]))
    out = tmp_path / "m.npz"

    def train(*args):
        return subprocess.run([sys.executable, "-m", "garment_transfer", "train", "--dataset", str(ds), "--out",
                               str(out), *args], cwd=ROOT, capture_output=True, text=True, timeout=120, env=env)

    for args, problem in ((("--source", "nope", "--targets", "pear"), "has no body 'nope'"),
                          (("--source", "src", "--targets", "pear,tall"), "has no body 'tall'"),
                          (("--source", "src", "--targets", "pear", "--garments", "top,hat"), "has no garment 'hat'"),
                          (("--source", "src", "--targets", "pear", "--hold-out", "hat"), "has no garment 'hat'")):
        p = train(*args)
        assert p.returncode == 1 and p.stderr.startswith(f"error: {ds}: ") and problem in p.stderr, p.stderr
    p = train("--source", "src", "--targets", "pear")
    assert p.returncode == 1 and "training needs torch (blocked here)" in p.stderr, p.stderr
    assert not out.exists()


def test_train_with_held_out_garments_checks_the_written_model_against_direct_transfer(tmp_path):
    pytest.importorskip("torch")
    import numpy as np
    from test_dataset import make_tiny_dataset

    from garment_transfer.learning.dataset import load_dataset
    from garment_transfer.learning.model_files import read_model_file
    from garment_transfer.pipeline.metrics import evaluate
    from garment_transfer.pipeline.transfer import transfer_garment

    ds = make_tiny_dataset(tmp_path / "ds")
    model = tmp_path / "m.npz"
    p = run("train", "--kind", "garment", "--dataset", ds, "--source", "src", "--targets", "similar,pear",
            "--hold-out", "top", "--placement-epochs", "10", "--placement-members", "1", "--out", model, "--json")
    assert p.returncode == 0, p.stderr
    summary = json.loads(p.stdout)
    assert summary["garments"] == ["band", "skirt"]          # trained without the held-out garment
    check = summary["check"]
    assert (check["garments"], check["targets"], check["model"]) == (["top"], ["similar", "pear"], str(model))
    data = load_dataset(ds)
    src, garment = data.body("src"), data.garment("top", "src")
    loaded = read_model_file(model)
    for t in ("similar", "pear"):
        body, ref = data.body(t), data.garment("top", t)
        expect = {"model": transfer_garment(src, body, garment, method="model", model=loaded.model, target=t,
                                            placement=loaded.placement).V,
                  "direct": transfer_garment(src, body, garment).V}
        for method, V in expect.items():
            e = evaluate(garment, garment.with_vertices(V), body, reference=ref, intersections=False)
            row = next(r for r in check["rows"] if r["target"] == t and r["method"] == method)
            np.testing.assert_allclose([row["vertex_error_mean"], row["mdc"]], [e["vertex_error_mean"], e["mdc"]],
                                       rtol=1e-9)
            assert row["penetrating_vertices"] == e["penetrating_vertices"]
        s = check["targets_summary"][t]
        assert s["vertex_ratio"] == pytest.approx(s["model"]["vertex_error_mean"] / s["direct"]["vertex_error_mean"])
        assert (t in check["beats_direct"]) == (s["vertex_ratio"] < 1)
    # The direct transfer of the tiny garments follows the body exactly on 'similar' (an affine map), not on pear.
    assert check["targets_summary"]["similar"]["direct"]["vertex_error_mean"] < 1e-6
    assert check["targets_summary"]["pear"]["direct"]["vertex_error_mean"] > 1e-3
    # As text: one line per target.
    p = run("train", "--kind", "shared", "--dataset", ds, "--source", "src", "--targets", "pear", "--epochs", "20",
            "--hold-out", "top,band", "--out", tmp_path / "shared.npz")
    assert p.returncode == 0, p.stderr
    assert "held out of training: top, band" in p.stdout
    assert sum(line.startswith("  pear: vertex error ") for line in p.stdout.splitlines()) == 1
    assert "below direct transfer's on" in p.stdout
    # Held-out garments that cannot be: refused before any training, nothing written.
    for held, extra, problem in (("nope", (), "has no garment 'nope'"),
                                 ("top", ("--garments", "top,band"), "top is also among the garments to train on"),
                                 ("top,band,skirt", (), "none is left to train on")):
        out = tmp_path / "refused.npz"
        p = run("train", "--dataset", ds, "--source", "src", "--targets", "pear", "--hold-out", held, *extra,
                "--out", out)
        assert p.returncode == 1 and problem in p.stderr and "train:" not in p.stderr, p.stderr
        assert not out.exists()
    # A held-out drape of other faces than the garment's: found by the check, after the file is written,
    # and said so.
    broken = tmp_path / "broken.npz"
    top = read_obj(ds / "garments" / "top" / "pear.obj")
    write_obj(ds / "garments" / "top" / "pear.obj", mesh_from_triangles(top.V, top.F[:-1]))
    p = run("train", "--kind", "shared", "--dataset", ds, "--source", "src", "--targets", "pear", "--epochs", "20",
            "--hold-out", "top", "--out", broken)
    assert p.returncode == 1 and broken.is_file(), p.stderr
    assert f"{broken} was written, but its check on the held-out garments failed: " in p.stderr
    assert "pear.obj" in p.stderr and "every file of one garment must have the same vertices" in p.stderr
    (ds / "garments" / "top" / "pear.obj").unlink()
    p = run("train", "--dataset", ds, "--source", "src", "--targets", "pear", "--hold-out", "top", "--out", out)
    assert p.returncode == 1 and "pear.obj" in p.stderr and not out.exists()


def test_wrong_or_damaged_model_files_are_refused_naming_them(tmp_path):
    from test_dataset import make_tiny_dataset

    ds = make_tiny_dataset(tmp_path / "ds")
    src, tgt, garment = (ds / "bodies" / "src.obj", ds / "bodies" / "pear.obj",
                         ds / "garments" / "top" / "src.obj")
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(b"PK\x03\x04" + bytes(100))
    newer = tmp_path / "newer.npz"
    import numpy as np

    np.savez(newer, metadata=np.array(json.dumps({"format": "garment_transfer.garment_fit_bundle",
                                                  "format_version": 9})))
    out = tmp_path / "out.obj"
    for bad, problem in ((src, "is not a model file (.npz, a zip archive) but a text file"),
                         (truncated, "is not a model file"),
                         (newer, "has format version 9"),
                         (tmp_path / "missing.npz", "model file not found")):
        p = run("transfer", "--model", bad, "--source-body", src, "--target-body", tgt, "--garment", garment,
                "--out", out)
        assert p.returncode == 1, p.stderr
        assert p.stderr.startswith(f"error: {bad}: ") and problem in p.stderr, p.stderr
        assert len(p.stderr.strip().splitlines()) == 1 and not out.exists()
    # Options of the other kind are usage errors.
    p = run("transfer", "--field-share", "0.5", "--source-body", src, "--target-body", tgt, "--garment", garment,
            "--out", out)
    assert p.returncode == 2 and "--field-share" in p.stderr
    p = run("transfer", "--model", newer, "--field-share", "1.5", "--source-body", src, "--target-body", tgt,
            "--garment", garment, "--out", out)
    assert p.returncode == 2 and "must be <= 1" in p.stderr
    p = run("train", "--kind", "garment", "--latent", "4", "--dataset", ds, "--source", "src", "--targets", "pear",
            "--out", tmp_path / "m.npz")
    assert p.returncode == 2 and "--latent is not for train --kind garment" in p.stderr
    # The garment fit model is the default kind: the shared kind's options without --kind say how to get it.
    p = run("train", "--unmasked", "--dataset", ds, "--source", "src", "--targets", "pear", "--out", tmp_path / "m.npz")
    assert p.returncode == 2
    assert "--unmasked is not for train --kind garment (the default): add --kind shared" in p.stderr
    p = run("train", "--kind", "shared", "--placement-members", "3", "--dataset", ds, "--source", "src",
            "--targets", "pear", "--out", tmp_path / "m.npz")
    assert p.returncode == 2 and "--placement-members is not for train --kind shared" in p.stderr
    p = run("train", "--kind", "shared", "--placement-absolute", "--dataset", ds, "--source", "src", "--targets",
            "pear", "--out", tmp_path / "m.npz")
    assert p.returncode == 2 and "--placement-absolute is not for train --kind shared" in p.stderr
    p = run("train", "--kind", "garment", "--placement-members", "0", "--dataset", ds, "--source", "src",
            "--targets", "pear", "--out", tmp_path / "m.npz")
    assert p.returncode == 2 and "--placement-members" in p.stderr and not (tmp_path / "m.npz").exists()
    p = run("train", "--kind", "garment", "--dataset", ds, "--source", "src", "--targets", "pear,nobody",
            "--out", tmp_path / "m.npz")
    assert p.returncode == 1 and "nobody" in p.stderr and not (tmp_path / "m.npz").exists()
    assert not out.exists()


def test_train_without_torch_says_how_to_get_it_and_writes_nothing(tmp_path, monkeypatch, capsys):
    from test_dataset import make_tiny_dataset

    from garment_transfer.cli import main

    ds = make_tiny_dataset(tmp_path / "ds")
    monkeypatch.setitem(sys.modules, "torch", None)
    for kind in ("shared", "garment"):
        code = main(["train", "--kind", kind, "--dataset", str(ds), "--source", "src", "--targets", "pear",
                     "--out", str(tmp_path / "m.npz")])
        assert code == 1 and "pip install torch==2.13.0" in capsys.readouterr().err
    assert not (tmp_path / "m.npz").exists()


def test_what_the_written_file_crosses_is_reported_with_every_warning_the_run_logged(tmp_path, monkeypatch, capsys):
    # A garment the pass cannot clear is still written, and the figures of the file as written (read back) say
    # what crosses; every warning the run logged is in the JSON too.
    import logging

    from garment_transfer.cli import main
    from garment_transfer.geometry import clearance
    from garment_transfer.geometry.intersections import crossings
    from garment_transfer.geometry.readings import readings_of

    V, F = icosphere(3)
    write_obj(tmp_path / "src.obj", mesh_from_triangles(V, F))
    write_obj(tmp_path / "tgt.obj", mesh_from_triangles(V * [1.2, 1.2, 1.0], F))
    GV, GF = icosphere(2, radius=1.03)
    write_obj(tmp_path / "g.obj", mesh_from_triangles(GV, GF))
    real = clearance.separate

    def defeated(V, *args, **kwargs):
        out, info = real(V, *args, **kwargs)
        out = out.copy()
        out[0] = -out[0]                    # one vertex taken across the body: its edges pass through it
        logging.getLogger("garment_transfer.geometry.clearance").warning("the pass gave up here")
        return out, info

    monkeypatch.setattr(clearance, "separate", defeated)
    argv = ["transfer", "--source-body", str(tmp_path / "src.obj"), "--target-body", str(tmp_path / "tgt.obj"),
            "--garment", str(tmp_path / "g.obj"), "--out", str(tmp_path / "out.obj")]
    assert main(argv + ["--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    written, target = read_obj(tmp_path / "out.obj"), read_obj(tmp_path / "tgt.obj")
    c = crossings(written.V, readings_of(written), target.V, readings_of(target))
    assert out["check"]["garment_edges_through_body"] == c["a_edges_through_b"] > 0
    assert out["check"]["body_edges_through_garment"] == c["b_edges_through_a"]
    assert out["check"]["min_body_distance"] == 0.0
    assert "crossings_after" not in out["info"]                     # the pass's own figure of the result
    assert any("garment edges pass through the body" in w and "out.obj" in w for w in out["warnings"])
    assert "the pass gave up here" in out["warnings"]
    assert main(argv) == 0
    assert "warning: " in capsys.readouterr().out
    # A transfer the pass clears has no warning, and its check says so.
    monkeypatch.setattr(clearance, "separate", real)
    assert main(argv + ["--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["warnings"] == [] and out["check"]["garment_edges_through_body"] == 0
    assert out["check"]["min_body_distance"] > 0
