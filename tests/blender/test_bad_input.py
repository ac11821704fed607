"""Every bad input is reported (an ERROR report, which bpy.ops turns into RuntimeError for a script) with
a message naming what is wrong, and the scene is left exactly as it was."""

from __future__ import annotations

import sys

import bpy
import numpy as np
import pytest

from conftest import GARMENT, import_obj, scene_state


def expect_report(operator, *fragments):
    """Run ``operator``; it must fail with a report holding every fragment and change nothing."""
    before = scene_state()
    with pytest.raises(RuntimeError) as info:
        operator()
    message = str(info.value)
    assert "Traceback" not in message and "Unexpected error" not in message, message
    for fragment in fragments:
        assert fragment in message, message
    assert scene_state() == before
    return message


def new_object(name, data):
    obj = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def test_missing_choice_names_what_to_choose(dressed):
    dressed.settings.garment = None
    message = expect_report(bpy.ops.garment_transfer.transfer, "Choose the garment")
    assert "poll()" in message
    dressed.settings.source_body = None
    expect_report(bpy.ops.garment_transfer.transfer, "Choose the source body and the garment")
    expect_report(bpy.ops.garment_transfer.evaluate, "Choose the result")
    expect_report(bpy.ops.garment_transfer.drape, "Choose the source body and the garment")


def test_non_mesh_object(dressed):
    dressed.settings.garment = new_object("Hanger", None)
    expect_report(bpy.ops.garment_transfer.transfer, "Hanger: is an empty object",
                  "the garment must be a mesh")
    curve = new_object("Hem", bpy.data.curves.new("Hem", 'CURVE'))
    dressed.settings.garment = dressed.garment
    dressed.settings.target_body = curve
    expect_report(bpy.ops.garment_transfer.transfer, "Hem: is a curve object")


def test_empty_mesh(dressed):
    dressed.settings.garment = new_object("Nothing", bpy.data.meshes.new("Nothing"))
    expect_report(bpy.ops.garment_transfer.transfer, "Nothing", "no vertices")


def test_mesh_without_faces(dressed):
    me = bpy.data.meshes.new("Points")
    me.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [])
    dressed.settings.garment = new_object("Points", me)
    expect_report(bpy.ops.garment_transfer.transfer, "Points", "no faces")


def broken_copy(obj, name, vertex, value):
    """A copy of ``obj`` with one coordinate of one vertex set to ``value`` (foreach_set passes NaN and
    inf through; assigning ``co`` clamps them)."""
    me = obj.data.copy()
    co = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", co)
    co[3 * vertex + 1] = value
    me.vertices.foreach_set("co", co)
    me.update()
    broken = new_object(name, me)
    broken.matrix_world = obj.matrix_world
    return broken


def test_nan_or_inf_coordinates(dressed):
    dressed.settings.garment = broken_copy(dressed.garment, "Broken", 17, np.nan)
    expect_report(bpy.ops.garment_transfer.transfer, "Broken", "vertex 17", "NaN")
    dressed.settings.garment = dressed.garment
    dressed.settings.target_body = broken_copy(dressed.target, "InfBody", 3, np.inf)
    expect_report(bpy.ops.garment_transfer.transfer, "InfBody", "vertex 3", "infinite")


def test_a_target_body_that_is_not_a_body(dressed):
    # Another mesh is registered first; a garment chosen as the target body cannot be fitted, and the
    # refusal names the figure and its limit.
    other = import_obj(dressed.makehuman / "garments" / GARMENT / "female_pear.obj", "not_a_body")
    dressed.settings.target_body = other
    expect_report(bpy.ops.garment_transfer.transfer, "not_a_body", "registration failed", "limit")


def test_garment_far_from_the_body(dressed):
    far = new_object("Far", dressed.garment.data)
    far.matrix_world = dressed.garment.matrix_world
    far.location.x += 5.0
    bpy.context.view_layer.update()
    dressed.settings.garment = far
    expect_report(bpy.ops.garment_transfer.transfer, "Far", "is far from the source body")


def test_missing_or_broken_model_file(dressed, tmp_path):
    settings = dressed.settings
    settings.method = 'MODEL'
    settings.model_path = str(tmp_path / "nowhere.npz")
    assert "not found" in settings.model_status and len(settings.model_targets) == 0
    expect_report(bpy.ops.garment_transfer.transfer, "nowhere.npz", "not found")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file at all")
    settings.model_path = str(junk)
    expect_report(bpy.ops.garment_transfer.transfer, "junk.npz")
    settings.model_path = ""
    expect_report(bpy.ops.garment_transfer.transfer, "Choose a model file")


def test_evaluate_refuses_inputs_and_other_topologies(dressed):
    dressed.settings.result = dressed.garment
    expect_report(bpy.ops.garment_transfer.evaluate, "sportsuit", "is an input")
    dressed.settings.result = new_object("Other", dressed.source.data)
    expect_report(bpy.ops.garment_transfer.evaluate, "Other", "vertices")


def test_training_without_torch_says_how_to_get_it(dressed, monkeypatch, tmp_path):
    dressed.settings.dataset_path = str(tmp_path)
    dressed.settings.train_output = str(tmp_path / "model.npz")
    monkeypatch.setitem(sys.modules, "torch", None)
    expect_report(bpy.ops.garment_transfer.train, "pip install torch==2.13.0",
                  "transfer works without it")
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}


def test_training_on_a_missing_dataset(dressed, tmp_path):
    pytest.importorskip("torch", reason="the dataset is read once torch is there")
    dressed.settings.dataset_path = str(tmp_path / "no_dataset")
    dressed.settings.train_output = str(tmp_path / "model.npz")
    expect_report(bpy.ops.garment_transfer.train, "no_dataset", "not found")
