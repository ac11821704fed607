"""The model file trained for the scene's source body is found where the user keeps it and offered."""

from __future__ import annotations

import os
from types import SimpleNamespace

import bpy
import pytest
from test_panel import RecordingLayout
from test_transfer_operator import make_tiny_dataset


def drawn_main_panel():
    calls = []
    bpy.types.VIEW3D_PT_garment_transfer.draw(SimpleNamespace(layout=RecordingLayout(calls)), bpy.context)
    return calls


def test_the_source_bodys_model_beside_the_blend_file_is_offered_and_used(dressed, tmp_path, extension):
    pytest.importorskip("torch", reason="training a model needs torch")
    core = extension.garment_transfer
    settings = dressed.settings
    ds = make_tiny_dataset(dressed.makehuman, tmp_path / "ds", garments=("female_casualsuit01", "male_casualsuit04"))
    folder = tmp_path / "project"
    folder.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "scene.blend"))

    # Nothing beside the .blend file yet: nothing offered, and Find Model says so and changes nothing.
    settings.source_body = dressed.source
    assert settings.found_model == "" and settings.found_model_text == ""
    assert bpy.ops.garment_transfer.find_model() == {'CANCELLED'}
    assert settings.method == 'DIRECT' and settings.model_path == ""

    garment = folder / "garment.npz"
    core.train_garment_fit_from_dataset(ds, "female_average", ["female_pear"], epochs=1, placement_epochs=2,
                                        placement_members=1, out=garment, threads=1)
    # Newer files that are not for this body are passed over: a model of another source body, and no model.
    other = folder / "other_body.npz"
    core.train_from_dataset(ds, "female_pear", ["female_average"], epochs=5, latent=2, out=other)
    (folder / "broken.npz").write_bytes(b"PK\x03\x04" + bytes(64))
    os.utime(garment, (1e9, 1e9))

    settings.source_body = dressed.source
    assert settings.found_model == str(garment)
    assert settings.found_model_text == "garment.npz: garment fit model + placement for average"
    # Offered beside the method while Direct is chosen; the method is the user's to change.
    assert settings.method == 'DIRECT'
    calls = drawn_main_panel()
    labels = [k.get("text") for kind, _, k in calls if kind == "label"]
    assert settings.found_model_text in labels
    assert ("operator", ("garment_transfer.find_model",), {"text": "Use"}) in calls

    assert bpy.ops.garment_transfer.find_model() == {'FINISHED'}
    assert settings.method == 'MODEL' and settings.model_path == str(garment)
    assert settings.model_status == "Garment fit model + learned placement, 1 target(s)"
    texts = [k.get("text") for kind, _, k in drawn_main_panel() if kind == "label"]
    assert settings.found_model_text not in texts          # in use: no longer offered
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    assert settings.last_model.startswith("Garment fit + placement (garment.npz, field share 0.5): 0.62x Direct's")

    # Choosing the Model method with no file chosen takes the found one.
    settings.method = 'DIRECT'
    settings.model_path = ""
    settings.method = 'MODEL'
    assert settings.model_path == str(garment)
