"""bpy.ops.garment_transfer.drape: Blender's cloth solver as the baseline, on real meshes (few frames)."""

from __future__ import annotations

import bpy
import numpy as np

from conftest import scene_state, world_vertices


def test_drape_makes_a_new_object_and_leaves_the_scene_as_it_was(dressed):
    settings = dressed.settings
    settings.drape_frames = 2
    settings.drape_pin_group = "pin"
    scene = bpy.context.scene
    scene.frame_set(7)
    inputs = (dressed.source, dressed.target, dressed.garment)
    before = scene_state()
    objects_before = set(bpy.data.objects)
    meshes_before = set(bpy.data.meshes)

    assert bpy.ops.garment_transfer.drape() == {'FINISHED'}

    result = settings.result
    assert result.name == "sportsuit_draped_on_pear"
    assert set(bpy.data.objects) - objects_before == {result}
    assert set(bpy.data.meshes) - meshes_before == {result.data}
    assert scene.frame_current == 7
    after = scene_state()
    for obj in inputs:
        assert after[f"object:{obj.name}"] == before[f"object:{obj.name}"], obj.name
    assert len(result.data.vertices) == len(dressed.garment.data.vertices)
    assert [g.name for g in result.vertex_groups] == ["waist", "pin"]
    V = world_vertices(result)
    assert np.all(np.isfinite(V))
    # The cloth moved (settled, then followed the body) but stayed on the body.
    moved = np.linalg.norm(V - world_vertices(dressed.garment), axis=1)
    assert 0 < np.median(moved) < 0.1
