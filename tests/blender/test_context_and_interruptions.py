"""Wrong context, linked library data, undo and interruptions.

Every operator refuses what it cannot do with a report (never a traceback) and leaves the scene as it
was; inputs linked from a library are read, never written, and give a local result; undo takes a
transfer back; an interrupted batch leaves whole files only.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

import batch_transfer
import bpy
import numpy as np
import pytest

from conftest import GARMENT, ROOT, world_vertices

OPERATORS = ("transfer", "evaluate", "train", "drape")
DATABLOCKS = ("objects", "meshes", "materials", "collections", "curves", "actions", "shape_keys",
              "images", "node_groups", "libraries", "scenes")


def object_state(obj):
    """What an operator must not change on an object (keyed by name_full: a local object and a linked
    one may share a name)."""
    entry = {"matrix": np.array(obj.matrix_world).round(9).tolist(),
             "collections": sorted(c.name_full for c in obj.users_collection),
             "modifiers": [m.name for m in obj.modifiers],
             "groups": [g.name for g in obj.vertex_groups],
             "data": obj.data.name_full if obj.data else None}
    if obj.type == 'MESH':
        me = obj.data
        co = np.empty(3 * len(me.vertices), dtype=np.float32)
        me.vertices.foreach_get("co", co)
        entry.update(co=hashlib.sha1(co.tobytes()).hexdigest(),
                     attributes=sorted(a.name for a in me.attributes),
                     materials=[m.name_full if m else None for m in me.materials],
                     shape_keys=[k.name for k in me.shape_keys.key_blocks] if me.shape_keys else [])
    return entry


def snapshot():
    """Every datablock by name, every object's state, the Garment tab's choices and the selection."""
    state = {kind: sorted(i.name_full for i in getattr(bpy.data, kind)) for kind in DATABLOCKS}
    state.update({f"object:{o.name_full}": object_state(o) for o in bpy.data.objects})
    settings = bpy.context.scene.garment_transfer
    for key in ("source_body", "target_body", "garment", "result", "reference"):
        obj = getattr(settings, key)
        state[f"setting:{key}"] = obj.name_full if obj else None
    for key in ("method", "model_path", "last_metrics", "train_progress"):
        state[f"setting:{key}"] = getattr(settings, key)
    layer = bpy.context.view_layer
    state["selected"] = sorted(o.name_full for o in layer.objects if o.select_get())
    state["active"] = layer.objects.active.name_full if layer.objects.active else None
    state["frame"] = bpy.context.scene.frame_current
    return state


def refused(name, *fragments):
    """Run operator ``name``: it must fail with a report holding every fragment, without a traceback,
    and leave everything as it was. Returns the report."""
    before = snapshot()
    with pytest.raises(RuntimeError) as info:
        getattr(bpy.ops.garment_transfer, name)()
    message = str(info.value)
    assert "Traceback (most recent call last)" not in message and "Python:" not in message, message
    for fragment in fragments:
        assert fragment in message, message
    assert snapshot() == before
    return message


def new_object(name, data=None):
    obj = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def ready_for_every_operator(dressed, tmp_path):
    """A result to evaluate and a dataset folder to train on, so that only the context is wrong."""
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    dressed.settings.dataset_path = str(tmp_path)
    dressed.settings.train_output = str(tmp_path / "model.npz")
    dressed.settings.drape_frames = 1


# -- wrong context ----------------------------------------------------------------------------------

def test_nothing_chosen(extension, tmp_path):
    settings = bpy.context.scene.garment_transfer
    refused("transfer", "poll()", "Choose the source body, the target body and the garment")
    refused("evaluate", "poll()", "Choose the result, the garment it came from and the target body")
    refused("drape", "poll()", "Choose the source body, the target body and the garment")
    refused("train", "poll()", "Choose a dataset folder")
    settings.dataset_path = str(tmp_path)
    settings.train_output = ""
    refused("train", "poll()", "Choose where to save the model")
    assert len(bpy.data.objects) == 0


def test_training_to_a_path_relative_to_an_unsaved_file(extension, tmp_path):
    settings = bpy.context.scene.garment_transfer
    settings.dataset_path = str(tmp_path)
    assert settings.train_output == "//garment_model.npz" and not bpy.data.filepath
    refused("train", "poll()", "The model file is relative to the .blend file, which is not saved yet")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    assert bpy.ops.garment_transfer.train.poll()


@pytest.mark.parametrize("mode, role", [("EDIT", "garment"), ("SCULPT", "target")])
def test_every_operator_refuses_outside_object_mode(dressed, tmp_path, mode, role):
    ready_for_every_operator(dressed, tmp_path)
    bpy.context.view_layer.objects.active = getattr(dressed, role)
    bpy.ops.object.mode_set(mode=mode)
    assert bpy.context.mode != 'OBJECT'
    for name in OPERATORS:
        refused(name, f"bpy.ops.garment_transfer.{name}.poll()", "Switch to Object Mode first")
    bpy.ops.object.mode_set(mode='OBJECT')
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}


def test_non_mesh_objects_for_evaluate_and_drape(dressed, tmp_path):
    # Transfer's non-mesh inputs are in test_bad_input.py.
    ready_for_every_operator(dressed, tmp_path)
    settings = dressed.settings
    result = settings.result
    hem = new_object("Hem", bpy.data.curves.new("Hem", 'CURVE'))
    hanger = new_object("Hanger")
    settings.result = hem
    refused("evaluate", "Hem: is a curve object; the result must be a mesh")
    settings.result = result
    settings.reference = hanger
    refused("evaluate", "Hanger: is an empty object; the reference must be a mesh")
    settings.reference = None
    settings.garment = hanger
    refused("drape", "Hanger: is an empty object; the garment must be a mesh")
    settings.garment = dressed.garment
    settings.source_body = hem
    refused("drape", "Hem: is a curve object; the source body must be a mesh")


def move_garment_out_of_the_view_layer(garment, where):
    scene = bpy.context.scene
    scene.collection.objects.unlink(garment)
    if where == "excluded collection":
        stored = bpy.data.collections.new("Stored")
        scene.collection.children.link(stored)
        stored.objects.link(garment)
        bpy.context.view_layer.layer_collection.children["Stored"].exclude = True
    else:
        bpy.data.scenes.new("Wardrobe").collection.objects.link(garment)
    bpy.context.view_layer.update()
    assert garment.name not in bpy.context.view_layer.objects


@pytest.mark.parametrize("where", ["excluded collection", "other scene"])
def test_garment_outside_the_view_layer_gives_a_result_in_it(dressed, where):
    move_garment_out_of_the_view_layer(dressed.garment, where)
    before = snapshot()
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    result = dressed.settings.result
    layer = bpy.context.view_layer
    assert list(result.users_collection) == [bpy.context.scene.collection]
    assert result.name in layer.objects and layer.objects.active == result and result.select_get()
    after = snapshot()
    assert after["objects"] == sorted(before["objects"] + [result.name])
    for obj in (dressed.source, dressed.target, dressed.garment):
        assert after[f"object:{obj.name}"] == before[f"object:{obj.name}"], obj.name


# -- linked library data ----------------------------------------------------------------------------

@pytest.fixture
def library(dressed, tmp_path):
    """library.blend: the bodies, the garment (in a collection "Wardrobe") and a transferred result
    "library_result"; the test then starts from an empty scene."""
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    result = dressed.settings.result
    result.name = "library_result"
    expected = world_vertices(result)
    scene = bpy.context.scene
    wardrobe = bpy.data.collections.new("Wardrobe")
    scene.collection.children.link(wardrobe)
    wardrobe.objects.link(dressed.garment)
    scene.collection.objects.unlink(dressed.garment)
    path = tmp_path / "library.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return SimpleNamespace(path=path, expected=expected, digest=hashlib.sha1(path.read_bytes()).digest())


def link(library, objects=(), collections=()):
    """Link ``objects`` and ``collections`` of the library into the scene; choose the bodies and the
    garment in the Garment tab. Returns the linked objects by name."""
    with bpy.data.libraries.load(str(library.path), link=True) as (_, into):
        into.objects = list(objects)
        into.collections = list(collections)
    scene = bpy.context.scene
    for obj in into.objects:
        scene.collection.objects.link(obj)
    for coll in into.collections:
        scene.collection.children.link(coll)
    bpy.context.view_layer.update()         # world matrices of the new objects
    linked = {o.name: o for o in bpy.data.objects if o.library is not None}
    settings = scene.garment_transfer
    settings.source_body, settings.target_body, settings.garment = (
        linked["average"], linked["pear"], linked["sportsuit"])
    return linked


def assert_linked_data_untouched(before, library):
    after = snapshot()
    linked = [key for key in before if key.startswith("object:") and "[library.blend]" in key]
    assert linked
    for key in linked:
        assert after[key] == before[key], key
    for kind in DATABLOCKS:
        assert ([n for n in after[kind] if "[library.blend]" in n]
                == [n for n in before[kind] if "[library.blend]" in n]), kind
    assert hashlib.sha1(library.path.read_bytes()).digest() == library.digest


def assert_local_result_in_view_layer(result):
    assert result.library is None and result.data.library is None and result.override_library is None
    assert result.name in bpy.context.view_layer.objects
    assert all(c.library is None for c in result.users_collection)


def test_linked_inputs_give_a_local_result(library):
    link(library, objects=("average", "pear", "sportsuit", "library_result"))
    settings = bpy.context.scene.garment_transfer
    before = snapshot()
    for evaluated in (True, False):
        settings.use_evaluated = evaluated
        assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
        result = settings.result
        assert_local_result_in_view_layer(result)
        np.testing.assert_allclose(world_vertices(result), library.expected, atol=1e-5)
        assert [m.name_full for m in result.data.materials] == ["fabric [library.blend]",
                                                                 "trim [library.blend]"]
    # Evaluate reads the linked garment and body and paints the local result.
    assert bpy.ops.garment_transfer.evaluate() == {'FINISHED'}
    assert "moved_distance" in result.data.color_attributes
    settings.drape_frames = 1
    assert bpy.ops.garment_transfer.drape() == {'FINISHED'}
    assert_local_result_in_view_layer(settings.result)
    assert settings.result.name == "sportsuit_draped_on_pear"
    assert_linked_data_untouched(before, library)


def test_garment_in_a_linked_collection(library):
    link(library, objects=("average", "pear"), collections=("Wardrobe",))
    wardrobe = bpy.data.collections["Wardrobe"]
    assert wardrobe.library is not None
    before = snapshot()
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    result = bpy.context.scene.garment_transfer.result
    # The garment's own collection is read-only: the result goes into the scene's.
    assert list(result.users_collection) == [bpy.context.scene.collection]
    assert_local_result_in_view_layer(result)
    assert [o.name for o in wardrobe.objects] == ["sportsuit"]
    assert_linked_data_untouched(before, library)


def test_evaluate_refuses_to_paint_a_linked_result(library, capsys):
    linked = link(library, objects=("average", "pear", "sportsuit", "library_result"))
    settings = bpy.context.scene.garment_transfer
    settings.result = linked["library_result"]
    before = snapshot()
    capsys.readouterr()
    assert bpy.ops.garment_transfer.evaluate() == {'FINISHED'}
    report = capsys.readouterr().out
    assert "Warning: library_result: MDC" in report, report
    assert (f"no heatmap: library_result's mesh is linked from the library {library.path}, which "
            "cannot be changed (make the result local to paint it)") in report, report
    assert "moved_distance" not in linked["library_result"].data.attributes
    assert json.loads(settings.last_metrics)["mdc"] < 0.2
    assert_linked_data_untouched(before, library)
    after = snapshot()
    assert {k: v for k, v in after.items() if k != "setting:last_metrics"} == \
           {k: v for k, v in before.items() if k != "setting:last_metrics"}


# -- undo -------------------------------------------------------------------------------------------

def test_undo_takes_a_transfer_and_an_evaluation_back(dressed):
    # Background mode starts without an undo stack; an explicit push starts one. bpy.ops pushes an
    # undo step for an operator only when asked to (its third argument), as the interface always does.
    bpy.ops.ed.undo_push(message="before the transfer")
    before = snapshot()
    assert bpy.ops.garment_transfer.transfer('EXEC_DEFAULT', True) == {'FINISHED'}
    after_transfer = snapshot()
    assert after_transfer["objects"] == sorted(before["objects"] + ["sportsuit_on_pear"])
    assert bpy.ops.garment_transfer.evaluate('EXEC_DEFAULT', True) == {'FINISHED'}
    painted = bpy.data.objects["sportsuit_on_pear"].data
    assert "moved_distance" in painted.color_attributes

    assert bpy.ops.ed.undo() == {'FINISHED'}
    assert snapshot() == after_transfer
    assert "moved_distance" not in bpy.data.objects["sportsuit_on_pear"].data.color_attributes
    assert bpy.ops.ed.undo() == {'FINISHED'}
    assert snapshot() == before
    assert "sportsuit_on_pear" not in bpy.data.meshes
    assert bpy.ops.ed.redo() == {'FINISHED'}
    assert snapshot() == after_transfer


def test_a_failed_operator_adds_no_undo_step(dressed):
    bpy.ops.ed.undo_push(message="start")
    assert not bpy.ops.ed.undo.poll()           # one step: nothing to undo
    far = new_object("Far", dressed.garment.data)
    far.matrix_world = dressed.garment.matrix_world
    far.location.x += 5.0
    bpy.context.view_layer.update()
    dressed.settings.garment = far
    bpy.ops.ed.undo_push(message="far garment")
    with pytest.raises(RuntimeError, match="is far from the source body"):
        bpy.ops.garment_transfer.transfer('EXEC_DEFAULT', True)
    assert bpy.ops.ed.undo() == {'FINISHED'}     # takes back the far garment, not a failed transfer
    assert "Far" not in bpy.data.objects
    assert not bpy.ops.ed.undo.poll()


# -- failures inside the operators ------------------------------------------------------------------

def failing(function, on_call, exc):
    """A stand-in for ``function`` that raises ``exc`` on call number ``on_call`` (from 1) instead."""
    calls = []

    def stand_in(*args, **kwargs):
        calls.append(1)
        if len(calls) == on_call:
            raise exc
        return function(*args, **kwargs)
    return stand_in


def test_failures_midway_leave_the_scene_as_it_was(dressed, tmp_path, extension, monkeypatch):
    ready_for_every_operator(dressed, tmp_path)
    convert, core, cloth = (importlib.import_module(f"{extension.__name__}.{name}") for name in
                            ("operators.convert", "garment_transfer", "operators.cloth"))
    with monkeypatch.context() as patch:
        # After the result object exists: it is removed again.
        patch.setattr(convert, "write_positions",
                      failing(convert.write_positions, 1, OSError("simulated failure")))
        refused("transfer", "Unexpected error (OSError: simulated failure)", "system console")
    with monkeypatch.context() as patch:
        patch.setattr(core, "per_vertex_change",
                      failing(core.per_vertex_change, 1, ValueError("simulated failure")))
        refused("evaluate", "Unexpected error (ValueError: simulated failure)")
    with monkeypatch.context() as patch:
        # In the second cloth run, once the body has morphed (shape keys, animation): all removed.
        patch.setattr(cloth, "_finish", failing(cloth._finish, 2, RuntimeError("simulated failure")))
        bpy.context.scene.frame_set(5)
        refused("drape", "Unexpected error (RuntimeError: simulated failure)")


def test_keyboard_interrupt_in_a_transfer_leaves_no_result(dressed, extension, monkeypatch):
    # Under the bpy module, Ctrl+C raises KeyboardInterrupt in the operator; bpy.ops turns it into a
    # RuntimeError (the batch script stops on it), and the half-made result is gone.
    convert = extension.operators.convert
    monkeypatch.setattr(convert, "write_positions",
                        failing(convert.write_positions, 1, KeyboardInterrupt()))
    before = snapshot()
    with pytest.raises(RuntimeError, match="KeyboardInterrupt"):
        bpy.ops.garment_transfer.transfer()
    assert snapshot() == before


# -- the batch script -------------------------------------------------------------------------------

def obj_counts(path):
    lines = path.read_text().splitlines()
    return sum(ln.startswith("v ") for ln in lines), sum(ln.startswith("f ") for ln in lines)


def batch_args(makehuman, out, garments, targets=("female_pear", "female_slim_banana", "male_slim")):
    args = ["--source-body", str(makehuman / "bodies" / "female_average.obj"), "--out", str(out),
            "--scale", "0.1"]
    for target in targets:
        args += ["--target-body", str(makehuman / "bodies" / f"{target}.obj")]
    for garment in garments:
        args += ["--garment", str(garment)]
    return args


def assert_whole_outputs(out, garment_files):
    """Only summary.json and complete OBJ files (as many vertices and faces as their garment) in
    ``out``; every pair the summary lists as done has its file. Returns the summary's records."""
    files = sorted(p.name for p in out.iterdir())
    assert "summary.json" in files and all(not f.startswith(".") for f in files), files
    records = json.loads((out / "summary.json").read_text())
    # Every garment file is called female_average.obj, so the batch labels it <folder>_female_average.
    expected = {f"{g.parent.name}_{g.stem}": obj_counts(g) for g in garment_files}
    for name in files:
        if name != "summary.json":
            garment = name.split("_on_")[0]
            assert obj_counts(out / name) == expected[garment], name
    for record in records:
        if "error" not in record:
            assert (out / f"{record['garment']}_on_{record['target']}.obj").is_file(), record
    assert records[-1] == {"error": batch_transfer.INTERRUPTED}
    return records


@pytest.mark.parametrize("where", ["transfer", "rename"])
def test_batch_interrupted_on_the_second_pair(makehuman, tmp_path, extension, monkeypatch, where):
    garment = makehuman / "garments" / GARMENT / "female_average.obj"
    if where == "transfer":
        transfer = extension.operators.transfer
        monkeypatch.setattr(transfer, "transfer_objects",
                            failing(transfer.transfer_objects, 2, KeyboardInterrupt()))
    else:
        # The second output is written in full to its temporary file, then Ctrl+C before the rename.
        monkeypatch.setattr(batch_transfer.os, "replace",
                            failing(batch_transfer.os.replace, 2, KeyboardInterrupt()))
    out = tmp_path / "out"
    args = batch_args(makehuman, out, [tmp_path / "missing.obj", garment])
    handler = signal.getsignal(signal.SIGINT)
    assert batch_transfer.main(["batch_transfer.py", *args]) == 130
    assert signal.getsignal(signal.SIGINT) is handler
    records = assert_whole_outputs(out, [garment])
    assert [r.get("target") for r in records[1:-1]] == ["female_pear"]
    assert "missing.obj" in records[0]["garment"] and "not found" in records[0]["error"]
    assert sorted(p.name for p in out.iterdir()) == [
        f"{GARMENT}_female_average_on_female_pear.obj", "summary.json"]


@pytest.mark.parametrize("raised, code, said", [
    (RuntimeError("a fault the batch does not know"), 1, "a fault the batch does not know"),
    (KeyboardInterrupt(), 130, ""),
    (SystemExit(2), 2, ""),
    (SystemExit("bad arguments"), 1, "bad arguments"),
    (SystemExit(None), 0, "")])
def test_the_batch_leaves_with_its_code_after_removing_blenders_session_folder(monkeypatch, capsys, raised, code,
                                                                                said):
    """Whatever ends the run, the script leaves without exit handlers (where the bpy 4.5 module can hang), with
    the run's exit code, once Blender's folder for the session is removed; an error nothing caught is said with
    its traceback and ends the run as a failure (not in the interpreter's exit, with its handlers)."""
    def main():
        raise raised

    done = []
    monkeypatch.setattr(batch_transfer, "main", main)
    monkeypatch.setattr(batch_transfer, "remove_session_folder", lambda: done.append("removed"))
    monkeypatch.setattr(batch_transfer.os, "_exit", lambda c: done.append(c))
    batch_transfer.leave()
    assert done == ["removed", code]
    err = capsys.readouterr().err
    assert said in err
    assert ("Traceback" in err) == isinstance(raised, RuntimeError)


def test_batch_stopped_by_sigint(makehuman, tmp_path):
    garments = [makehuman / "garments" / g / "female_average.obj"
                for g in (GARMENT, "female_casualsuit01")]
    out = tmp_path / "out"
    cmd = [sys.executable, str(ROOT / "scripts" / "batch_transfer.py"),
           *batch_args(makehuman, out, garments, ("female_pear", "female_slim_banana", "male_slim",
                                                   "male_average"))]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, encoding="utf-8",
                            errors="replace", cwd=tmp_path)
    try:
        deadline = time.monotonic() + 120
        while not (out.is_dir() and any(p.suffix == ".obj" and not p.name.startswith(".")
                                        for p in out.iterdir())):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.01)
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, stderr
    assert "interrupted (Ctrl+C)" in stderr
    records = assert_whole_outputs(out, garments)
    assert len([p for p in out.iterdir() if p.suffix == ".obj"]) < 8
    assert len(records) - 1 < 8
