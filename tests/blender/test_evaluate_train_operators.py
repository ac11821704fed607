"""bpy.ops.garment_transfer.evaluate and .train on real meshes and a small real dataset.

Training needs torch. Where torch is installed (Blender 4.2, 4.5 and 5.0 here) the training tests run;
where it is not (Blender 5.2: no CPU build of torch for its Python 3.13, and most Blender users have none
either) the test of what the user then sees runs instead.
"""

from __future__ import annotations

import importlib.util
import json
import sys
import time
from types import SimpleNamespace

import bpy
import numpy as np
import pytest
from test_panel import RecordingLayout
from test_transfer_operator import make_tiny_dataset

from conftest import GARMENT, import_obj, scene_state, world_vertices

TORCH_INSTALLED = importlib.util.find_spec("torch") is not None
NO_TORCH = "torch is not installed in this Python (training needs it)"


def test_evaluate_writes_metrics_and_a_heatmap(dressed, extension):
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    settings = dressed.settings
    result = settings.result
    settings.reference = import_obj(dressed.makehuman / "garments" / GARMENT / "female_pear.obj",
                                    "reference")
    assert bpy.ops.garment_transfer.evaluate() == {'FINISHED'}

    import json

    metrics = json.loads(settings.last_metrics)
    for key in ("mdc", "penetration_ratio", "max_penetration_depth", "drape_error",
                "drape_error_relative", "vertex_error_mean", "vertex_error_max"):
        assert metrics[key] is not None and np.isfinite(metrics[key]), key
    assert 0 < metrics["mdc"] < 0.2 and metrics["drape_error_relative"] < 1.0
    moved = np.linalg.norm(world_vertices(result) - world_vertices(dressed.garment), axis=1)
    assert metrics["vertex_error_mean"] < moved.mean()

    me = result.data
    colors = me.color_attributes["moved_distance"]
    assert colors.domain == 'POINT' and me.color_attributes.active_color.name == "moved_distance"
    rgba = np.empty(4 * len(me.vertices), np.float32)
    colors.data.foreach_get("color", rgba)
    assert np.all((rgba >= 0) & (rgba <= 1)) and np.ptp(rgba.reshape(-1, 4)[:, 0]) > 0.5
    values = np.empty(len(me.vertices), np.float32)
    me.attributes["moved_distance_value"].data.foreach_get("value", values)
    np.testing.assert_allclose(values, moved, rtol=1e-4, atol=1e-6)


def test_evaluate_without_reference_measures_against_the_body_fit(dressed):
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    assert bpy.ops.garment_transfer.evaluate() == {'FINISHED'}
    import json

    metrics = json.loads(dressed.settings.last_metrics)
    assert metrics["drape_error"] is not None and "vertex_error_mean" not in metrics


def test_train_writes_a_model_the_transfer_then_uses(dressed, tmp_path):
    pytest.importorskip("torch", reason=NO_TORCH)
    settings = dressed.settings
    settings.dataset_path = str(make_tiny_dataset(dressed.makehuman, tmp_path / "ds",
                                                  garments=("female_casualsuit01", "male_casualsuit04")))
    settings.dataset_source = "female_average"
    settings.train_output = str(tmp_path / "out" / "shared")
    (tmp_path / "out").mkdir()
    settings.train_kind = 'SHARED'
    settings.train_epochs = 20
    settings.train_latent = 2
    assert bpy.ops.garment_transfer.train() == {'FINISHED'}
    assert (tmp_path / "out" / "shared.npz").is_file()
    assert settings.method == 'MODEL' and settings.model_path.endswith("shared.npz")
    assert [t.name for t in settings.model_targets] == ["female_pear"]
    assert settings.train_progress == 100.0
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}


def test_train_the_garment_fit_model_with_its_placement(dressed, tmp_path, extension):
    pytest.importorskip("torch", reason=NO_TORCH)
    settings = dressed.settings
    settings.dataset_path = str(make_tiny_dataset(dressed.makehuman, tmp_path / "ds",
                                                  garments=("female_casualsuit01", "male_casualsuit04")))
    settings.dataset_source = "female_average"
    settings.train_output = str(tmp_path / "garment")
    assert settings.train_kind == 'GARMENT'       # the default
    assert bpy.ops.garment_transfer.train() == {'FINISHED'}
    assert settings.method == 'MODEL' and settings.model_path.endswith("garment.npz")
    # The last model trained is the one offered for this source body from now on.
    assert settings.last_trained_model == settings.found_model == str(tmp_path / "garment.npz")
    read = extension.garment_transfer.read_model_file(tmp_path / "garment.npz")
    assert read.kind == "garment" and read.has_placement and read.targets == ["female_pear"]
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    assert settings.last_model.startswith("Garment fit + placement (garment.npz, field share 0.5): ")


def test_train_with_held_out_garments_checks_the_model_on_them(dressed, tmp_path, extension):
    pytest.importorskip("torch", reason=NO_TORCH)
    core = extension.garment_transfer
    settings = dressed.settings
    ds = make_tiny_dataset(dressed.makehuman, tmp_path / "ds", garments=("female_casualsuit01", "male_casualsuit04"))
    settings.dataset_path = str(ds)
    settings.dataset_source = "female_average"
    settings.train_output = str(tmp_path / "shared.npz")
    settings.train_kind = 'SHARED'
    settings.train_epochs = 20
    settings.train_latent = 2
    settings.train_hold_out = "male_casualsuit04"
    assert bpy.ops.garment_transfer.train() == {'FINISHED'}
    check = json.loads(settings.train_check)
    assert (check["garments"], check["targets"]) == (["male_casualsuit04"], ["female_pear"])
    # The direct transfer it was compared with is the core's, measured against the garment's own drape.
    data = core.load_dataset(ds)
    src, body = data.body("female_average"), data.body("female_pear")
    garment, ref = data.garment("male_casualsuit04", "female_average"), data.garment("male_casualsuit04", "female_pear")
    V = core.transfer_garment(src, body, garment).V
    e = core.evaluate(garment, garment.with_vertices(V), body, reference=ref, intersections=False)
    direct = check["targets_summary"]["female_pear"]["direct"]
    assert direct["vertex_error_mean"] == pytest.approx(e["vertex_error_mean"], rel=1e-9)
    lines = extension.ui.panels.check_summary_lines(settings.train_check)
    assert lines[0] == "Held out: male_casualsuit04" and lines[1].startswith("female_pear: vertex error ")
    # A garment the dataset lacks: refused before training, nothing written.
    settings.train_output = str(tmp_path / "never.npz")
    settings.train_hold_out = "no_such_garment"
    with pytest.raises(RuntimeError, match="no_such_garment"):
        bpy.ops.garment_transfer.train()
    assert not (tmp_path / "never.npz").exists()
    # Esc during the check: the model is written, the check stops.
    train = extension.operators.train
    settings.train_output = str(tmp_path / "checked.npz")
    settings.train_hold_out = "male_casualsuit04"
    run = train.TrainingRun(train.training_call(train.training_plan(settings)))
    steps = run.steps()
    for fraction in steps:
        if fraction >= train.TRAINING_SHARE:
            break
        time.sleep(0.01)
    steps.close()
    assert type(run.error).__name__ == "Cancelled" and "held-out" in str(run.error)
    assert (tmp_path / "checked.npz").is_file()
    # A training without held-out garments clears the last check.
    settings.train_hold_out = ""
    settings.train_output = str(tmp_path / "plain.npz")
    assert bpy.ops.garment_transfer.train() == {'FINISHED'}
    assert settings.train_check == ""


def test_cancelled_training_writes_nothing(dressed, tmp_path, extension):
    pytest.importorskip("torch", reason=NO_TORCH)
    train = extension.operators.train
    settings = dressed.settings
    settings.dataset_path = str(make_tiny_dataset(dressed.makehuman, tmp_path / "ds",
                                                  garments=("female_casualsuit01",)))
    settings.train_output = str(tmp_path / "never.npz")
    settings.train_kind = 'SHARED'
    settings.train_epochs = 5000
    run = train.TrainingRun(train.training_call(train.training_plan(settings)))
    steps = run.steps()
    for fraction in steps:
        if fraction > 0.1:          # reading done, training started
            break
        time.sleep(0.01)
    steps.close()                   # what Esc does
    assert not run._thread.is_alive()
    assert type(run.error).__name__ == "Cancelled"
    assert not (tmp_path / "never.npz").exists()
    assert not list(tmp_path.glob("*.npz*")) and not list(tmp_path.glob(".*"))


@pytest.mark.skipif(TORCH_INSTALLED, reason="torch is installed in this Python: the training tests run")
def test_without_torch_the_panel_and_train_say_how_to_install_it(dressed, tmp_path):
    assert "torch" not in sys.modules
    calls = []
    bpy.types.VIEW3D_PT_garment_transfer_training.draw(
        SimpleNamespace(layout=RecordingLayout(calls)), bpy.context)
    labels = [k.get("text", "") for kind, _, k in calls if kind == "label"]
    assert "Training needs PyTorch (not installed)" in labels and "pip install torch==2.13.0" in labels
    assert ("operator", ("garment_transfer.train",), {"icon": 'PLAY'}) in calls

    settings = dressed.settings
    settings.dataset_path = str(make_tiny_dataset(dressed.makehuman, tmp_path / "ds",
                                                  garments=("female_casualsuit01",)))
    settings.train_output = str(tmp_path / "out.npz")
    before = scene_state()
    with pytest.raises(RuntimeError) as info:
        bpy.ops.garment_transfer.train()
    message = str(info.value)
    # The exact command for this Blender's own Python, which a user can paste into a terminal.
    assert f'"{sys.executable}" -m pip install torch==2.13.0' in message, message
    assert "transfer works without it" in message and "Traceback" not in message
    assert scene_state() == before and settings.method == 'DIRECT'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}


def test_the_model_file_is_refused_in_the_dataset_it_reads_before_training(dressed, tmp_path, extension):
    # The core's one check of outputs against inputs, before any training (and without torch): never in the
    # dataset's bodies/ or garments/, however the path is spelled. (Save Model As ends in .npz: ".npz" is
    # added to a name without it, so a body's own file name cannot be reached.)
    train = extension.operators.train
    settings = dressed.settings
    ds = make_tiny_dataset(dressed.makehuman, tmp_path / "ds", garments=("female_casualsuit01",))
    settings.dataset_path = str(ds)
    (tmp_path / "alias").symlink_to(ds / "garments")
    (tmp_path / "sub").mkdir()
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    for out, problem in ((ds / "bodies" / "female_pear.obj", "lies inside the input folder"),
                         (ds / "bodies", "is the input folder"),
                         (tmp_path / "alias" / "model.npz", "lies inside the input folder"),
                         (tmp_path / "sub" / ".." / "ds" / "garments" / "female_casualsuit01" / "m.npz",
                          "lies inside the input folder")):
        settings.train_output = str(out)
        with pytest.raises(extension.garment_transfer.OutputError, match=problem):
            train.training_plan(settings)
    assert sorted(str(p) for p in tmp_path.rglob("*")) == before
    settings.train_output = str(ds / "model.npz")      # beside bodies/ and garments/: fine
    assert train.training_plan(settings)["out"] == str(ds / "model.npz")


def test_evaluate_after_a_transfer_onto_a_subdivided_target_or_another_mesh(dressed, extension):
    import json

    gt, convert = extension.garment_transfer, extension.operators.convert
    subsurf = dressed.target.modifiers.new("Subdivision", 'SUBSURF')
    subsurf.levels = 1
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    # The body fit is carried onto the mesh the target subdivides (it was refused: "has 53514 vertices but
    # average has 13380").
    assert bpy.ops.garment_transfer.evaluate() == {'FINISHED'}
    metrics = json.loads(dressed.settings.last_metrics)
    assert metrics["drape_error"] is not None and np.isfinite(metrics["drape_error"])
    assert subsurf.show_viewport
    dg = bpy.context.evaluated_depsgraph_get()
    body = convert.core_mesh_from_object(dressed.target, dg)
    cloth = convert.core_mesh_from_object(dressed.settings.result, dg)
    c = gt.crossings(cloth.V, gt.readings_of(cloth), body.V, gt.readings_of(body))
    assert metrics["garment_edges_through_body"] == c["a_edges_through_b"] == 0
    # A Displace after it: another mesh, no body fit to measure against; the other figures all there.
    dressed.target.modifiers.new("Displace", 'DISPLACE').strength = 0.001
    assert bpy.ops.garment_transfer.evaluate() == {'FINISHED'}
    metrics = json.loads(dressed.settings.last_metrics)
    assert metrics["drape_error"] is None
    assert metrics["mdc"] > 0 and metrics["garment_edges_through_body"] is not None
