"""Outfits in Blender: layers listed in the Outfit panel, from the body out, transferred together.

The demo's banana body and two of its garments (a T-shirt under a shift dress, about 2K triangles each)
are made into objects from the OBJ arrays (metres, Z up, as the demo data is).
"""

from __future__ import annotations

from types import SimpleNamespace

import bpy
import numpy as np
import pytest
from test_panel import RecordingLayout

from conftest import scene_state, world_vertices
from garment_transfer.geometry.intersections import crossings, self_intersections
from garment_transfer.geometry.readings import readings_of
from garment_transfer.geometry.obj import read_obj
from garment_transfer.pipeline.outfit import OutfitError, transfer_outfit
from lab.paths import DEMO_DATA

INNER, OUTER = "tshirt", "shift_dress"


def mesh_object(mesh, name):
    """A Blender object of a core Mesh (its own polygons), in the scene collection."""
    polygons = [mesh.face_vertices[a:b].tolist() for a, b in zip(mesh.face_start[:-1], mesh.face_start[1:])]
    me = bpy.data.meshes.new(name)
    me.from_pydata(mesh.V.tolist(), [], polygons)
    me.update()
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    return obj


@pytest.fixture
def outfit(extension):
    """The demo's source body, a target body and the two garments as objects; the bodies chosen."""
    meshes = {"banana": read_obj(DEMO_DATA / "bodies" / "banana.obj"),
              "pear": read_obj(DEMO_DATA / "bodies" / "pear.obj")}
    for g in (INNER, OUTER):
        meshes[g] = read_obj(DEMO_DATA / "garments" / g / "banana.obj", name=g)
    objects = {name: mesh_object(m, name) for name, m in meshes.items()}
    bpy.context.view_layer.update()
    settings = bpy.context.scene.garment_transfer
    settings.source_body = objects["banana"]
    settings.target_body = objects["pear"]
    return SimpleNamespace(objects=objects, meshes=meshes, settings=settings)


def set_layers(settings, objects):
    settings.outfit_layers.clear()
    for obj in objects:
        settings.outfit_layers.add().garment = obj
    settings.outfit_index = 0


def core_meshes(extension, objects):
    convert = extension.operators.convert
    dg = bpy.context.evaluated_depsgraph_get()
    return [convert.core_mesh_from_object(o, dg) for o in objects]


def test_outfit_gives_the_core_result_with_no_crossings(outfit, extension):
    o = outfit.objects
    # Added in the wrong order (by name: shift_dress, tshirt), then put right in the panel's list.
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj.name in (INNER, OUTER, "banana"))
    assert bpy.ops.garment_transfer.outfit_add(source='SELECTED') == {'FINISHED'}
    settings = outfit.settings
    assert [layer.garment.name for layer in settings.outfit_layers] == [OUTER, INNER]  # bodies left out
    settings.outfit_index = 1
    assert bpy.ops.garment_transfer.outfit_move(direction='UP') == {'FINISHED'}
    assert [layer.garment.name for layer in settings.outfit_layers] == [INNER, OUTER]
    assert settings.outfit_index == 0

    before = set(bpy.data.objects)
    assert bpy.ops.garment_transfer.transfer_outfit() == {'FINISHED'}
    made = set(bpy.data.objects) - before
    assert {obj.name for obj in made} == {f"{INNER}_on_pear", f"{OUTER}_on_pear"}
    inner, outer = bpy.data.objects[f"{INNER}_on_pear"], bpy.data.objects[f"{OUTER}_on_pear"]
    assert settings.result == outer and {obj for obj in bpy.context.selected_objects} == {inner, outer}
    assert settings.last_outfit_registration == ""       # the source's own mesh: not registered

    source, target, g_in, g_out = core_meshes(extension, (o["banana"], o["pear"], o[INNER], o[OUTER]))
    expected = transfer_outfit(source, target, [g_in, g_out])
    got = [world_vertices(inner), world_vertices(outer)]
    for V, E in zip(got, expected.V):
        np.testing.assert_allclose(V, E, atol=1e-6)
    # Under every triangulation of the layers' and the body's quads.
    R_in, R_out, B = readings_of(g_in), readings_of(g_out), readings_of(target)
    for V, g, R in zip(got, (g_in, g_out), (R_in, R_out)):
        c = crossings(V, R, target.V, B)
        assert c["a_edge_pairs"] == 0 and c["b_edge_pairs"] == 0, g.name
    c = crossings(got[0], R_in, got[1], R_out)
    assert c["a_edge_pairs"] == 0 and c["b_edge_pairs"] == 0
    # As given, the two garments (each draped alone) pass through each other: the outfit separated them.
    assert sum(crossings(g_in.V, R_in, g_out.V, R_out)[k] for k in ("a_edge_pairs", "b_edge_pairs")) > 0
    assert self_intersections(got[0], R_in)[0] <= self_intersections(g_in.V, R_in)[0]


def test_reversed_order_is_refused_naming_both_garments(outfit):
    o = outfit.objects
    set_layers(outfit.settings, [o[OUTER], o[INNER]])
    before = scene_state()
    with pytest.raises(RuntimeError) as err:
        bpy.ops.garment_transfer.transfer_outfit()
    assert INNER in str(err.value) and OUTER in str(err.value)
    assert scene_state() == before
    assert outfit.settings.result is None and not outfit.settings.last_outfit


def test_layer_offsets_reach_the_core(outfit, extension):
    o = outfit.objects
    set_layers(outfit.settings, [o[INNER], o[OUTER]])
    outfit.settings.outfit_layers[1].auto_offset = False
    outfit.settings.outfit_layers[1].offset = 0.012
    assert bpy.ops.garment_transfer.transfer_outfit() == {'FINISHED'}
    from garment_transfer.geometry.intersections import minimum_distance

    source, target, g_in, g_out = core_meshes(extension, (o["banana"], o["pear"], o[INNER], o[OUTER]))
    inner = world_vertices(bpy.data.objects[f"{INNER}_on_pear"])
    outer = world_vertices(bpy.data.objects[f"{OUTER}_on_pear"])
    auto = transfer_outfit(source, target, [g_in, g_out])
    np.testing.assert_allclose(inner, auto.V[0], atol=1e-6)   # the inner layer keeps its automatic offset
    assert np.abs(outer - auto.V[1]).max() > 1e-3              # the outer one keeps its own, larger one
    assert minimum_distance(outer, g_out.F, inner, g_in.F) > minimum_distance(auto.V[1], g_out.F,
                                                                              auto.V[0], g_in.F)


def test_panel_lists_the_layers_in_order(outfit):
    o = outfit.objects
    set_layers(outfit.settings, [o[INNER], o[OUTER]])
    calls = []
    bpy.types.VIEW3D_PT_garment_transfer_outfit.draw(SimpleNamespace(layout=RecordingLayout(calls)),
                                                     bpy.context)
    lists = [a for kind, a, _ in calls if kind == "template_list"]
    assert lists and lists[0][0] == "GARMENT_TRANSFER_UL_outfit_layers" and lists[0][3] == "outfit_layers"
    assert "garment_transfer.transfer_outfit" in [a[0] for kind, a, _ in calls if kind == "operator"]

    rows = []
    ul = bpy.types.GARMENT_TRANSFER_UL_outfit_layers
    for k, layer in enumerate(outfit.settings.outfit_layers):
        row = []
        ul.draw_item(None, bpy.context, RecordingLayout(row), outfit.settings, layer, 0, outfit.settings,
                     "outfit_layers", k)
        rows.append([k_.get("text") for kind, _, k_ in row if kind == "label"]
                    + [a[0].garment.name for kind, a, _ in row if kind == "prop" and a[1] == "garment"])
    assert rows == [["1.", "auto offset", INNER], ["2.", "auto offset", OUTER]]


def test_add_a_collection_and_remove_a_layer(outfit):
    o = outfit.objects
    coll = bpy.data.collections.new("Outfit")
    bpy.context.scene.collection.children.link(coll)
    for name in (INNER, OUTER, "pear"):
        coll.objects.link(o[name])
    outfit.settings.outfit_collection = coll
    assert bpy.ops.garment_transfer.outfit_add(source='COLLECTION') == {'FINISHED'}
    assert [layer.garment.name for layer in outfit.settings.outfit_layers] == [OUTER, INNER]
    outfit.settings.outfit_index = 0
    assert bpy.ops.garment_transfer.outfit_remove() == {'FINISHED'}
    assert [layer.garment.name for layer in outfit.settings.outfit_layers] == [INNER]
    assert OUTER in bpy.data.objects


def test_bad_outfits_name_the_object_and_change_nothing(outfit):
    o = outfit.objects
    settings = outfit.settings
    set_layers(settings, [o[INNER], o[INNER]])
    before = scene_state()
    with pytest.raises(RuntimeError, match=f"{INNER}: is given as two layers"):
        bpy.ops.garment_transfer.transfer_outfit()
    set_layers(settings, [o[INNER], o["pear"]])
    with pytest.raises(RuntimeError, match="pear: is chosen both as a layer of the outfit and as a body"):
        bpy.ops.garment_transfer.transfer_outfit()
    settings.outfit_layers.clear()
    with pytest.raises(RuntimeError, match="Add the outfit's garments"):
        bpy.ops.garment_transfer.transfer_outfit()
    assert scene_state() == before


def test_an_outfit_onto_a_body_of_another_mesh_is_registered_once_and_clear_of_the_body_given(outfit, extension):
    from lab.registration import remesh

    from garment_transfer.geometry.mesh import mesh_from_triangles

    o, settings = outfit.objects, outfit.settings
    pear = outfit.meshes["pear"]
    other = mesh_object(mesh_from_triangles(*remesh(pear.V, pear.F, 20000), name="pear_remeshed"), "pear_remeshed")
    bpy.context.view_layer.update()
    set_layers(settings, [o[INNER], o[OUTER]])
    settings.target_body = other
    before = set(bpy.data.objects)
    assert bpy.ops.garment_transfer.transfer_outfit() == {'FINISHED'}
    inner, outer = (bpy.data.objects[f"{g}_on_pear_remeshed"] for g in (INNER, OUTER))
    assert set(bpy.data.objects) - before == {inner, outer}
    # The Outfit panel says how closely the source was fitted.
    assert settings.last_outfit_registration.startswith("Registered")
    calls = []
    bpy.types.VIEW3D_PT_garment_transfer_outfit.draw(SimpleNamespace(layout=RecordingLayout(calls)), bpy.context)
    assert settings.last_outfit_registration in [k.get("text") for kind, _, k in calls if kind == "label"]
    # The core's outfit onto that mesh (registered once), as Blender has the objects.
    source, target, g_in, g_out = core_meshes(extension, (o["banana"], other, o[INNER], o[OUTER]))
    expected = transfer_outfit(source, target, [g_in, g_out])
    assert expected.registration is not None and target.n_vertices != source.n_vertices
    got = [world_vertices(inner), world_vertices(outer)]
    for V, E in zip(got, expected.V):
        np.testing.assert_allclose(V, E, atol=1e-6)
    # Against the body given (not the fitted copy), under every triangulation; the layers apart.
    B = readings_of(target)
    for V, g in zip(got, (g_in, g_out)):
        c = crossings(V, readings_of(g), target.V, B)
        assert c["a_edge_pairs"] == 0 and c["b_edge_pairs"] == 0, g.name
    c = crossings(got[0], readings_of(g_in), got[1], readings_of(g_out))
    assert c["a_edge_pairs"] == 0 and c["b_edge_pairs"] == 0
    # Near the outfit onto the pear's own mesh (measured: 4.1 and 8.7 mm on average, each garment alone 4.1 and 8.1:
    # the registration's error).
    own = transfer_outfit(source, core_meshes(extension, (o["pear"],))[0], [g_in, g_out])
    for V, E in zip(got, own.V):
        assert np.linalg.norm(V - E, axis=1).mean() < 0.01


def test_model_method_needs_a_model_file(outfit):
    settings = outfit.settings
    set_layers(settings, [outfit.objects[INNER], outfit.objects[OUTER]])
    settings.method = 'MODEL'
    with pytest.raises(RuntimeError, match="Choose a model file"):
        bpy.ops.garment_transfer.transfer_outfit()


def test_outfit_error_is_an_outfit_error_in_the_core(outfit, extension):
    # The operator's refusal is the core's: the same arrays in the reversed order raise OutfitError.
    o = outfit.objects
    source, target, g_in, g_out = core_meshes(extension, (o["banana"], o["pear"], o[INNER], o[OUTER]))
    with pytest.raises(OutfitError, match=OUTER):
        transfer_outfit(source, target, [g_out, g_in])


def test_a_failure_while_making_the_objects_leaves_the_scene_as_it_was(outfit, extension, monkeypatch):
    # The second layer's object cannot be made: the first one, already made, is taken back.
    convert = extension.operators.convert
    made = []

    def failing_second(garment, *args, **kwargs):
        if made:
            raise MemoryError("no room for the second layer")
        made.append(real(garment, *args, **kwargs))
        return made[-1]

    real = convert.new_result_object
    monkeypatch.setattr(convert, "new_result_object", failing_second)
    set_layers(outfit.settings, [outfit.objects[INNER], outfit.objects[OUTER]])
    before = scene_state()
    with pytest.raises(RuntimeError, match="MemoryError"):
        bpy.ops.garment_transfer.transfer_outfit()
    assert len(made) == 1 and scene_state() == before


def test_undo_takes_the_outfit_and_a_reordering_back(outfit):
    set_layers(outfit.settings, [outfit.objects[OUTER], outfit.objects[INNER]])
    outfit.settings.outfit_index = 1
    bpy.ops.ed.undo_push(message="before")
    names = sorted(o.name for o in bpy.data.objects)

    def layers():
        return [layer.garment.name for layer in bpy.context.scene.garment_transfer.outfit_layers]

    assert bpy.ops.garment_transfer.outfit_move('EXEC_DEFAULT', True, direction='UP') == {'FINISHED'}
    assert layers() == [INNER, OUTER]
    assert bpy.ops.garment_transfer.transfer_outfit('EXEC_DEFAULT', True) == {'FINISHED'}
    assert sorted(o.name for o in bpy.data.objects) == sorted(names + [f"{INNER}_on_pear", f"{OUTER}_on_pear"])
    assert bpy.ops.ed.undo() == {'FINISHED'}
    assert sorted(o.name for o in bpy.data.objects) == names and layers() == [INNER, OUTER]
    assert bpy.ops.ed.undo() == {'FINISHED'}
    assert layers() == [OUTER, INNER]


def test_outfit_with_a_model_file_says_which_model_it_used(outfit, extension, tmp_path):
    pytest.importorskip("torch", reason="training a model needs torch")
    training = model_files = extension.garment_transfer
    path = tmp_path / "shared.npz"
    training.train_from_dataset(DEMO_DATA, "banana", ["pear"], garments=["aline_skirt", "tank_top"], epochs=5,
                                latent=2, out=path)
    o, settings = outfit.objects, outfit.settings
    set_layers(settings, [o[INNER], o[OUTER]])
    settings.method = 'MODEL'
    settings.model_path = str(path)
    assert bpy.ops.garment_transfer.transfer_outfit() == {'FINISHED'}
    assert settings.last_outfit_model == "Model: " + model_files.read_model_file(path).describe()
    assert settings.last_outfit_model.startswith("Model: ") and "shared.npz" in settings.last_outfit_model
    calls = []
    bpy.types.VIEW3D_PT_garment_transfer_outfit.draw(SimpleNamespace(layout=RecordingLayout(calls)), bpy.context)
    assert settings.last_outfit_model in [k.get("text") for kind, _, k in calls if kind == "label"]
    # The transfer panel's own line is the single transfer's, left as it was.
    assert settings.last_model == ""
    settings.method = 'DIRECT'
    assert bpy.ops.garment_transfer.transfer_outfit() == {'FINISHED'}
    assert settings.last_outfit_model == ""


def test_an_outfit_onto_a_target_under_a_subdivision_surface(outfit, extension):
    o = outfit.objects
    set_layers(outfit.settings, (o[INNER], o[OUTER]))
    subsurf = o["pear"].modifiers.new("Subdivision", 'SUBSURF')
    subsurf.levels = 1
    assert bpy.ops.garment_transfer.transfer_outfit() == {'FINISHED'}
    # The mesh it subdivides is the source's: not registered; the layers fitted to the surface the viewport shows.
    assert outfit.settings.last_outfit_registration == ""
    assert subsurf.show_viewport
    target, g_in, g_out = core_meshes(extension, (o["pear"], o[INNER], o[OUTER]))
    assert target.n_vertices > 2 * len(o["pear"].data.vertices)
    got = [world_vertices(bpy.data.objects[f"{g}_on_pear"]) for g in (INNER, OUTER)]
    R_in, R_out, B = readings_of(g_in), readings_of(g_out), readings_of(target)
    for V, R in zip(got, (R_in, R_out)):
        c = crossings(V, R, target.V, B)
        assert c["a_edge_pairs"] == 0 and c["b_edge_pairs"] == 0
    c = crossings(got[0], R_in, got[1], R_out)
    assert c["a_edge_pairs"] == 0 and c["b_edge_pairs"] == 0
