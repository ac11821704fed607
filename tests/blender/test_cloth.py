"""operators/cloth.py: Blender's cloth solver drapes a small garment on the source body and on a
target body; the result keeps its vertices, stays outside the body, and the scene is left as it was."""

from __future__ import annotations

import importlib

import bpy
import numpy as np
import pytest

from conftest import scene_state


@pytest.fixture(scope="module")
def small_case():
    from lab.procedural.garments import tube_garment
    from lab.procedural.mannequin import mannequin

    V, F = mannequin("banana")
    # A target 6% wider around the torso axis (cheaper than another preset, same topology).
    T = V * np.array([1.06, 1.06, 1.0])
    # Flared far beyond its hanging shape, so that gravity has to move it.
    g = tube_garment("test_skirt", 1.06, 0.85, 24, 8, flare=1.2)
    return V, F, T, g


def cloth_module(extension):
    return importlib.import_module(extension.__name__ + ".operators.cloth")


def test_drape_moves_the_garment_keeps_vertices_and_stays_outside(extension, small_case):
    from garment_transfer.geometry.proximity import TriangleSurface

    V, F, T, g = small_case
    assert 300 <= 2 * g.polygons.shape[0] <= 500
    report = []
    shapes = cloth_module(extension).drape_garment(g.V, g.polygons, V, F, [T], pin_group=g.pin,
                                                   frames=8, morph_frames=4, report=report)
    assert len(shapes) == 2 and len(report) == 2
    for S, body in zip(shapes, (V, T)):
        assert S.shape == g.V.shape and np.all(np.isfinite(S))
        sd = TriangleSurface(body, F).signed_distance(S)[0]
        assert sd.min() >= 0.0
    free = np.setdiff1d(np.arange(g.V.shape[0]), g.pin)
    assert np.linalg.norm(shapes[0][free] - g.V[free], axis=1).max() > 5e-3  # the cloth fell
    # Pinned waistband: in place on the source body, moved out with the wider target.
    assert np.abs(shapes[0][g.pin] - g.V[g.pin]).max() < 2e-3
    r0 = np.linalg.norm(shapes[0][g.pin, :2], axis=1).mean()
    r1 = np.linalg.norm(shapes[1][g.pin, :2], axis=1).mean()
    assert r1 > r0 * 1.03
    assert all(r["inside_after"] == 0 for r in report)


def test_drape_is_deterministic_and_restores_the_scene(extension, small_case):
    V, F, T, g = small_case
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 3, 50
    scene.frame_set(7)
    before = scene_state()
    counts = (len(bpy.data.objects), len(bpy.data.meshes), len(bpy.data.actions))
    drape = cloth_module(extension).drape_garment
    a = drape(g.V, g.polygons, V, F, [], pin_group=g.pin, frames=4)
    b = drape(g.V, g.polygons, V, F, [], pin_group=g.pin, frames=4)
    assert np.array_equal(a[0], b[0])
    assert scene_state() == before
    assert (len(bpy.data.objects), len(bpy.data.meshes), len(bpy.data.actions)) == counts
    assert (scene.frame_start, scene.frame_end, scene.frame_current) == (3, 50, 7)


def test_drape_refuses_a_target_of_another_topology(extension, small_case):
    errors = extension.garment_transfer
    V, F, T, g = small_case
    with pytest.raises(errors.MeshError, match="target body 0"):
        cloth_module(extension).drape_garment(g.V, g.polygons, V, F, [T[:-1]], frames=2)


def test_continuous_drape_is_one_simulation_from_the_start(extension, small_case):
    """continuous=True: a target that is the source body itself ends exactly where the source settling
    alone ends after as many frames (no restart between them); a wider target still moves the waistband out.
    Without it the restart from the settled garment lands elsewhere."""
    V, F, T, g = small_case
    drape = cloth_module(extension).drape_garment
    longer = drape(g.V, g.polygons, V, F, [], pin_group=g.pin, source_frames=12 + 4 + 4)[0]
    S = drape(g.V, g.polygons, V, F, [V, T], pin_group=g.pin, frames=4, morph_frames=4, source_frames=12,
              continuous=True)
    assert np.array_equal(S[1], longer)
    r0 = np.linalg.norm(S[0][g.pin, :2], axis=1).mean()
    assert np.linalg.norm(S[2][g.pin, :2], axis=1).mean() > r0 * 1.03
    restarted = drape(g.V, g.polygons, V, F, [V], pin_group=g.pin, frames=4, morph_frames=4, source_frames=12)
    assert np.abs(restarted[1] - longer).max() > 1e-3
