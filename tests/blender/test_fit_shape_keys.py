"""Fit to body shape keys: driven keys that reproduce the transfer, rigging kept, undo, bad input."""

from __future__ import annotations

import importlib

import bpy
import numpy as np
import pytest

from conftest import GARMENT, import_obj, scene_state
from garment_transfer.geometry.mesh import mesh_from_polygons
from garment_transfer.pipeline.shape_keys import fit_shape_keys
from lab.paths import makehuman_folder

KEYS = {"pear": "female_pear", "slim": "female_slim_banana"}


@pytest.fixture
def keyed():
    """A body (female_average) with shape keys pear and slim from the other bodies, and a garment."""
    folder = makehuman_folder()
    if folder is None:
        pytest.skip("MakeHuman fixtures not found")
    body = import_obj(folder / "bodies" / "female_average.obj", "body")
    body.shape_key_add(name="Basis", from_mix=False)
    for key, file in KEYS.items():
        other = import_obj(folder / "bodies" / f"{file}.obj", f"tmp_{key}")
        assert np.allclose(np.array(other.matrix_world), np.array(body.matrix_world))
        co = np.empty(3 * len(other.data.vertices), dtype=np.float32)
        other.data.vertices.foreach_get("co", co)
        kb = body.shape_key_add(name=key, from_mix=False)
        kb.data.foreach_set("co", co)
        kb.value = 0.0
        me = other.data
        bpy.data.objects.remove(other)
        bpy.data.meshes.remove(me)
    garment = import_obj(folder / "garments" / GARMENT / "female_average.obj", "suit")
    settings = bpy.context.scene.garment_transfer
    settings.source_body = body
    settings.garment = garment
    bpy.context.view_layer.update()
    return body, garment


def world_of(obj, co):
    M = np.array(obj.matrix_world)
    return co.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3]


def key_world(obj, name):
    kb = obj.data.shape_keys.key_blocks[name]
    co = np.empty(3 * len(kb.data), dtype=np.float32)
    kb.data.foreach_get("co", co)
    return world_of(obj, co)


def mesh_of(obj, V):
    me = obj.data
    fv = np.empty(len(me.loops), dtype=np.int64)
    me.loops.foreach_get("vertex_index", fv)
    sizes = np.empty(len(me.polygons), dtype=np.int64)
    me.polygons.foreach_get("loop_total", sizes)
    return mesh_from_polygons(V, np.split(fv, np.cumsum(sizes)[:-1]), name=obj.name)


def expected_bands(body, fit):
    """The keep-outside bands of the core's fit (``keep_outside_bands``) on the body's faces as Blender splits
    them (the Shrinkwrap's view), read independently of the operator."""
    from garment_transfer.geometry.mesh import mesh_from_triangles
    from garment_transfer.pipeline.shape_keys import keep_outside_bands

    me = body.data
    me.calc_loop_triangles()
    tris = np.empty(3 * len(me.loop_triangles), dtype=np.int64)
    me.loop_triangles.foreach_get("vertices", tris)
    basis = mesh_from_triangles(key_world(body, "Basis"), tris.reshape(-1, 3))
    return keep_outside_bands(fit, basis, {k: key_world(body, k) for k in KEYS})


def group_members(obj, name):
    """The vertices of ``obj`` in its vertex group ``name`` and their weights."""
    index = obj.vertex_groups[name].index
    rows = {v.index: g.weight for v in obj.data.vertices for g in v.groups if g.group == index}
    return np.array(sorted(rows)), np.array([rows[i] for i in sorted(rows)])


def expected_fit(body, garment, **options):
    """The core's fit of the same inputs, read independently of the operator."""
    shapes = {k: key_world(body, k) for k in KEYS}
    basis = mesh_of(body, key_world(body, "Basis"))
    cloth = mesh_of(garment, world_of(garment, np.array([v.co for v in garment.data.vertices])))
    return fit_shape_keys(basis, shapes, cloth, **options)


def evaluated_world(obj):
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    me = ev.to_mesh()
    try:
        co = np.empty(3 * len(me.vertices), dtype=np.float32)
        me.vertices.foreach_get("co", co)
    finally:
        ev.to_mesh_clear()
    return world_of(ev, co)


def set_key(body, name, value):
    body.data.shape_keys.key_blocks[name].value = value
    bpy.context.view_layer.update()


def test_keys_and_drivers_follow_the_body_sliders(keyed):
    body, garment = keyed
    before = scene_state()
    assert bpy.ops.garment_transfer.fit_shape_keys(keep_outside=False) == {'FINISHED'}
    result = bpy.data.objects["suit_fitted"]
    assert not result.modifiers
    after = scene_state()
    for name in before:
        if name.startswith("object:"):
            assert after[name] == before[name], name       # the inputs are unchanged
    blocks = result.data.shape_keys.key_blocks
    assert [kb.name for kb in blocks] == ["Basis", "pear", "slim", "Mix Lift"]
    drivers = {fc.data_path: fc.driver for fc in result.data.shape_keys.animation_data.drivers}
    for key in KEYS:
        drv = drivers[f'key_blocks["{key}"].value']
        (var,) = drv.variables
        assert var.targets[0].id == body.data.shape_keys
        assert var.targets[0].data_path == f'key_blocks["{key}"].value'
        assert blocks[key].relative_key == blocks["Basis"]
    # The lift of a mix: driven by how far the sliders add up beyond 1, with no Python to run (a Sum driver, a
    # Generator modifier taking 1 off, the key's slider range holding it at 0 below) and for any number of keys.
    fc, = [f for f in result.data.shape_keys.animation_data.drivers if f.data_path == 'key_blocks["Mix Lift"].value']
    assert fc.driver.type == 'SUM' and not fc.keyframe_points
    assert [v.targets[0].data_path for v in fc.driver.variables] == [f'key_blocks["{k}"].value' for k in KEYS]
    (generator,) = fc.modifiers
    assert generator.type == 'GENERATOR' and list(generator.coefficients) == [-1.0, 1.0]
    assert (blocks["Mix Lift"].slider_min, blocks["Mix Lift"].slider_max) == (0.0, 10.0)

    fit = expected_fit(body, garment)
    assert np.abs(evaluated_world(result) - fit.basis).max() < 1e-5        # every slider at 0
    for key in KEYS:
        set_key(body, key, 1.0)
        assert np.abs(evaluated_world(result) - fit.keys[key]).max() < 1e-5
        set_key(body, key, 0.0)
        assert np.abs(evaluated_world(result) - fit.basis).max() < 1e-5
    set_key(body, "pear", 0.3)
    set_key(body, "slim", 0.6)
    assert np.abs(evaluated_world(result) - fit.blend({"pear": 0.3, "slim": 0.6})).max() < 1e-5
    assert np.array_equal(fit.blend({"pear": 0.3, "slim": 0.6}), fit.blend({"pear": 0.3, "slim": 0.6}, lift=False))
    assert result.data.shape_keys.key_blocks["Mix Lift"].value == 0.0
    body.data.shape_keys.key_blocks["pear"].slider_max = 2.0     # beyond 1: extrapolated linearly, and lifted
    set_key(body, "pear", 1.5)
    assert np.abs(evaluated_world(result) - fit.blend({"pear": 1.5, "slim": 0.6})).max() < 1e-5
    lifted = fit.blend({"pear": 1.5, "slim": 0.6}) - fit.blend({"pear": 1.5, "slim": 0.6}, lift=False)
    assert np.linalg.norm(lifted, axis=1).max() > 1e-3
    assert result.data.shape_keys.key_blocks["Mix Lift"].value == pytest.approx(1.1)


def test_corrective_pair_key_makes_both_keys_at_one_exact(keyed):
    body, garment = keyed
    assert bpy.ops.garment_transfer.fit_shape_keys(correctives=True, keep_outside=False) == {'FINISHED'}
    result = bpy.data.objects["suit_fitted"]
    assert "pear+slim" in result.data.shape_keys.key_blocks
    drv = [fc.driver for fc in result.data.shape_keys.animation_data.drivers
           if fc.data_path == 'key_blocks["pear+slim"].value'][0]
    assert drv.type == 'SCRIPTED' and drv.expression == "a * b"
    fit = expected_fit(body, garment, pairs=[("pear", "slim")])
    set_key(body, "pear", 1.0)
    set_key(body, "slim", 1.0)
    both = evaluated_world(result)
    assert np.abs(both - fit.blend({"pear": 1.0, "slim": 1.0})).max() < 1e-5
    set_key(body, "slim", 0.0)
    assert np.abs(evaluated_world(result) - fit.keys["pear"]).max() < 1e-5


def evaluated_body_surface(body):
    from garment_transfer.geometry.proximity import TriangleSurface

    V = evaluated_world(body)
    return TriangleSurface(V, mesh_of(body, V).F)


def blender_triangles_surface(body):
    """The evaluated body with its quads split as Blender splits them (its loop triangles): the surface a
    Shrinkwrap on it sees."""
    from garment_transfer.geometry.proximity import TriangleSurface

    ev = body.evaluated_get(bpy.context.evaluated_depsgraph_get())
    me = ev.to_mesh()
    try:
        me.calc_loop_triangles()
        tris = np.empty(3 * len(me.loop_triangles), dtype=np.int64)
        me.loop_triangles.foreach_get("vertices", tris)
    finally:
        ev.to_mesh_clear()
    return TriangleSurface(evaluated_world(body), tris.reshape(-1, 3))


def test_each_key_at_one_is_the_transfer_to_that_shape_and_crosses_nothing(keyed):
    # With Keep Outside Body (the default), each key at 1, as Blender evaluates the garment, is within 1 mm of
    # the transfer to that shape, and no edge of either crosses the other under any triangulation of the faces.
    # Keep Outside Body is one Shrinkwrap per band of keep_outside_bands, in increasing order, each after the first
    # limited to a vertex group of weight 1 holding exactly its band's vertices.
    from garment_transfer.geometry.intersections import crossings
    from garment_transfer.geometry.readings import readings_of
    from garment_transfer.pipeline.transfer import transfer_garment

    body, garment = keyed
    assert bpy.ops.garment_transfer.fit_shape_keys() == {'FINISHED'}
    result = bpy.data.objects["suit_fitted"]
    fit = expected_fit(body, garment)
    bands = expected_bands(body, fit)
    assert len(bands) >= 3
    mods = list(result.modifiers)
    names = ["Keep Outside Body"] + [f"Keep Outside Body {i}" for i in range(2, len(bands) + 1)]
    assert [m.name for m in mods] == names
    scale = np.mean(np.array(body.matrix_world.to_scale()))      # the offset is in the target's units
    for i, (mod, (distance, only)) in enumerate(zip(mods, bands)):
        assert (mod.type, mod.wrap_mode, mod.wrap_method, mod.target) == \
            ('SHRINKWRAP', 'OUTSIDE', 'NEAREST_SURFACEPOINT', body)
        assert mod.offset * scale == pytest.approx(distance, rel=1e-6)        # world units
        if i == 0:
            assert mod.vertex_group == ""
        else:
            rows, weights = group_members(result, mod.vertex_group)
            assert np.array_equal(rows, np.flatnonzero(only)) and (weights == 1.0).all()
    basis = mesh_of(body, key_world(body, "Basis"))
    cloth = mesh_of(garment, world_of(garment, np.array([v.co for v in garment.data.vertices])))
    for key in KEYS:
        set_key(body, key, 1.0)
        shown = evaluated_world(result)
        alone = transfer_garment(basis, basis.with_vertices(key_world(body, key)), cloth).V
        assert np.abs(shown - alone).max() < 1e-3                 # 1 mm (metres)
        now = mesh_of(body, evaluated_world(body))
        c = crossings(shown, readings_of(cloth), now.V, readings_of(now))
        assert c["a_edge_pairs"] + c["b_edge_pairs"] == 0, key
        set_key(body, key, 0.0)


@pytest.mark.parametrize("mix", [{"pear": 1.0, "slim": 1.0}, {"pear": 0.6, "slim": 0.9}])
def test_keep_outside_catches_what_a_mix_clips_as_the_numpy_rule_does(keyed, mix):
    # Blender's stack of Shrinkwraps is keep_outside_banded: the study measures what the user gets.
    from garment_transfer.pipeline.shape_keys import keep_outside_banded, shrinkwrap_distance

    body, garment = keyed
    assert bpy.ops.garment_transfer.fit_shape_keys() == {'FINISHED'}
    result = bpy.data.objects["suit_fitted"]
    fit = expected_fit(body, garment)
    bands = expected_bands(body, fit)
    for name, value in mix.items():
        set_key(body, name, value)                 # a mix the keys were not made for
    blend = fit.blend(mix)
    surface = evaluated_body_surface(body)
    sd_blend = surface.signed_distance(blend)[0]
    shown = evaluated_world(result)
    sd_shown = surface.signed_distance(shown)[0]
    assert (sd_shown < -1e-3).sum() == 0                       # nothing more than 1 mm inside
    seen = blender_triangles_surface(body)
    expected = keep_outside_banded(blend, seen, bands)
    moved = np.linalg.norm(expected - blend, axis=1) > 1e-4
    assert moved.sum() > 5                                      # the rule does something
    assert np.abs(shown - expected).max() < 1e-6               # 1 micrometre: 32-bit rounding
    # As the Shrinkwrap measures: what no band reaches is the blend itself.
    sd_blend = shrinkwrap_distance(blend, seen)[0]
    last, only = bands[-1]
    far = sd_blend > last                                      # a quarter here: the last band is twice the offset
    assert far.mean() > 0.2 and (np.abs(shown[far] - blend[far]) < 1e-5).all()
    # A vertex outside the last band's group is not taken to its distance (the group limits the Shrinkwrap).
    skipped = ~only & bands[0][1] & (sd_blend < bands[-2][0])
    assert skipped.sum() > 5
    assert (shrinkwrap_distance(shown[skipped], seen)[0] < 0.95 * last).all()


def test_undo_takes_the_fitted_garment_back(keyed):
    bpy.ops.ed.undo_push(message="before fitting")
    before = scene_state()
    assert bpy.ops.garment_transfer.fit_shape_keys('EXEC_DEFAULT', True) == {'FINISHED'}
    after = scene_state()
    assert "object:suit_fitted" in after
    assert bpy.ops.ed.undo() == {'FINISHED'}
    assert scene_state() == before
    assert bpy.ops.ed.redo() == {'FINISHED'}
    assert scene_state() == after


def rig(body, garment):
    """An armature with one bone; the body skinned to it above the garment's mid-height."""
    z0 = float(np.median(world_of(garment, np.array([v.co for v in garment.data.vertices]))[:, 2]))
    arm_data = bpy.data.armatures.new("rig")
    arm = bpy.data.objects.new("rig", arm_data)
    bpy.context.scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode='EDIT')
    bone = arm_data.edit_bones.new("spine")
    bone.head = (0.0, 0.0, z0)
    bone.tail = (0.0, 0.0, z0 + 0.4)
    bpy.ops.object.mode_set(mode='OBJECT')
    z = world_of(body, np.array([v.co for v in body.data.vertices]))[:, 2]
    group = body.vertex_groups.new(name="spine")
    for i in np.flatnonzero(z > z0):
        group.add([int(i)], 1.0, 'REPLACE')
    mod = body.modifiers.new(name="Armature", type='ARMATURE')
    mod.object = arm
    return arm


def test_weights_from_the_body_and_posing_deforms_the_result(keyed):
    body, garment = keyed
    arm = rig(body, garment)
    bpy.context.view_layer.objects.active = body
    # Without the Shrinkwrap, which would also move unweighted cloth where the posed body meets it.
    assert bpy.ops.garment_transfer.fit_shape_keys(weights_from_body=True, keep_outside=False) == {'FINISHED'}
    result = bpy.data.objects["suit_fitted"]
    assert [g.name for g in result.vertex_groups] == ["spine"]
    assert [(m.type, m.object) for m in result.modifiers] == [('ARMATURE', arm)]
    assert not garment.vertex_groups and not garment.modifiers      # the input is unchanged
    rest = evaluated_world(result)
    arm.pose.bones["spine"].rotation_mode = 'XYZ'
    arm.pose.bones["spine"].rotation_euler = (0.0, 0.5, 0.0)
    bpy.context.view_layer.update()
    posed = evaluated_world(result)
    moved = np.linalg.norm(posed - rest, axis=1)
    weight = np.zeros(len(result.data.vertices))
    for v in result.data.vertices:
        for g in v.groups:
            weight[v.index] = g.weight
    assert moved[weight > 0.99].min() > 1e-3 and moved[weight == 0].max() < 1e-6
    set_key(body, "pear", 1.0)                     # the sliders still work on the posed garment
    assert np.abs(evaluated_world(result) - posed).max() > 1e-3


def test_rigging_the_result_replaces_every_keep_outside_band(keyed, extension):
    # Rig to Body on a fitted result takes off the bands (modifiers and vertex groups) and adds its own.
    rigging = importlib.import_module(f"{extension.__name__}.operators.rigging")
    body, garment = keyed
    arm = rig(body, garment)
    assert bpy.ops.garment_transfer.fit_shape_keys(weights_from_body=False) == {'FINISHED'}
    result = bpy.data.objects["suit_fitted"]
    assert len(result.modifiers) >= 3 and len(result.vertex_groups) >= 2
    rigging.rig_to_body(bpy.context, result, body)
    mods = list(result.modifiers)
    assert (mods[0].type, mods[0].name, mods[0].object) == ('ARMATURE', "Armature", arm)
    assert all(m.type == 'SHRINKWRAP' and m.target == body for m in mods[1:])
    # Its own bands, from the result at rest (no key at 1 any more): every group is one of them or the bone's.
    assert [g.name for g in result.vertex_groups] == ["spine"] + [m.vertex_group for m in mods if m.vertex_group]


def test_the_garments_own_rigging_is_kept(keyed):
    body, garment = keyed
    arm = rig(body, garment)
    garment.parent = arm
    group = garment.vertex_groups.new(name="own")
    group.add(list(range(0, len(garment.data.vertices), 2)), 0.5, 'REPLACE')
    mod = garment.modifiers.new(name="Skin", type='ARMATURE')
    mod.object = arm
    bpy.context.view_layer.update()
    assert bpy.ops.garment_transfer.fit_shape_keys(weights_from_body=True) == {'FINISHED'}
    result = bpy.data.objects["suit_fitted"]
    assert result.parent == arm
    mods = list(result.modifiers)
    assert (mods[0].name, mods[0].object) == ("Skin", arm)
    assert [m.name for m in mods[1:]] == ["Keep Outside Body"] + [f"Keep Outside Body {i}" for i in range(2, len(mods))]
    assert all(m.type == 'SHRINKWRAP' and m.target == body for m in mods[1:])
    assert [g.name for g in result.vertex_groups] == ["own"] + [m.name for m in mods[2:]]
    assert np.allclose(np.array(result.matrix_world), np.array(garment.matrix_world))


def test_a_garment_with_shape_keys_keeps_them(keyed):
    body, garment = keyed
    garment.shape_key_add(name="Basis", from_mix=False)
    wind = garment.shape_key_add(name="wind", from_mix=False)
    co = np.empty(3 * len(wind.data), dtype=np.float32)
    wind.data.foreach_get("co", co)
    wind.data.foreach_set("co", co + 0.01)
    assert bpy.ops.garment_transfer.fit_shape_keys() == {'FINISHED'}
    result = bpy.data.objects["suit_fitted"]
    names = [kb.name for kb in result.data.shape_keys.key_blocks]
    assert names == ["Basis", "wind", "pear", "slim", "Mix Lift"]
    offset = key_world(result, "wind") - key_world(result, "Basis")
    assert np.allclose(offset, key_world(garment, "wind") - key_world(garment, "Basis"), atol=1e-5)


def driven_garment(garment, target_obj):
    garment.shape_key_add(name="Basis", from_mix=False)
    kb = garment.shape_key_add(name="flutter", from_mix=False)
    fc = kb.driver_add("value")
    var = fc.driver.variables.new()
    var.type = 'TRANSFORMS'
    var.targets[0].id = target_obj
    fc.driver.type = 'AVERAGE'


@pytest.mark.parametrize("case, message", [
    ("no keys", "has no shape keys besides its basis"),
    ("relative to a key", "is relative to 'pear', not to the basis"),
    ("deleted driver target", "drivers whose target was deleted"),
    ("name clash", "already has shape keys named like"),
])
def test_bad_input_is_refused_and_nothing_changes(keyed, case, message):
    body, garment = keyed
    if case == "no keys":
        body.shape_key_clear()
    elif case == "relative to a key":
        body.data.shape_keys.key_blocks["slim"].relative_key = body.data.shape_keys.key_blocks["pear"]
    elif case == "deleted driver target":
        empty = bpy.data.objects.new("wind_source", None)
        bpy.context.scene.collection.objects.link(empty)
        driven_garment(garment, empty)
        bpy.data.objects.remove(empty)
    else:
        garment.shape_key_add(name="Basis", from_mix=False)
        garment.shape_key_add(name="pear", from_mix=False)
    bpy.context.view_layer.update()
    before = scene_state()
    with pytest.raises(RuntimeError, match=message):
        bpy.ops.garment_transfer.fit_shape_keys()
    assert scene_state() == before
    assert "suit_fitted" not in bpy.data.objects


def test_cancelling_between_steps_makes_nothing(keyed, extension):
    # The modal operator closes its step generator on Esc; execute drains the same generator.
    ops = importlib.import_module(f"{extension.__name__}.operators.shape_keys")
    body, garment = keyed
    before = scene_state()
    steps = ops.fit_steps(bpy.context, body, garment)
    assert 0.0 < next(steps) < 1.0
    steps.close()
    assert scene_state() == before
    steps = ops.fit_steps(bpy.context, body, garment)
    result, fit, kept, note, warnings = ops.drain(steps)
    assert result.name == "suit_fitted" and set(fit.keys) == set(KEYS) and kept == [] and note == ""
    assert warnings == []                     # each key at 1, as stored, crosses nothing
