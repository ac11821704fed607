"""bpy.ops.garment_transfer.transfer on real meshes: what it makes, what it keeps, what it leaves alone."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from conftest import GARMENT, import_obj, scene_state, world_vertices


def transfer_result():
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    return bpy.context.scene.garment_transfer.result


def core(extension):
    """The core as the loaded extension sees it: its public API."""
    return extension.garment_transfer


def test_transfer_makes_a_new_object_next_to_the_garment(dressed, extension):
    coll = bpy.data.collections.new("Wardrobe")
    bpy.context.scene.collection.children.link(coll)
    coll.objects.link(dressed.garment)
    result = transfer_result()

    assert result.name == "sportsuit_on_pear"
    assert result is not dressed.garment and result.data is not dressed.garment.data
    assert {c.name for c in result.users_collection} == {"Wardrobe", "Scene Collection"}
    assert len(result.data.vertices) == len(dressed.garment.data.vertices)
    assert len(result.modifiers) == 0 and result.data.shape_keys is None

    # The same as calling the core on the same world-space meshes.
    convert = extension.operators.convert
    dg = bpy.context.evaluated_depsgraph_get()
    meshes = [convert.core_mesh_from_object(o, dg) for o in (dressed.source, dressed.target,
                                                             dressed.garment)]
    expected = core(extension).transfer_garment(*meshes).V
    np.testing.assert_allclose(world_vertices(result), expected, atol=1e-5)


def test_transfer_moves_the_garment_towards_its_fit_on_the_target(dressed):
    reference = import_obj(dressed.makehuman / "garments" / GARMENT / "female_pear.obj", "reference")
    result = transfer_result()
    before = np.linalg.norm(world_vertices(dressed.garment) - world_vertices(reference), axis=1).mean()
    after = np.linalg.norm(world_vertices(result) - world_vertices(reference), axis=1).mean()
    assert after < 0.5 * before


def test_inputs_are_unchanged(dressed):
    inputs = (dressed.source, dressed.target, dressed.garment)
    before = {o.name: scene_state()[f"object:{o.name}"] for o in inputs}
    uv_before = np.empty(2 * len(dressed.garment.data.loops), np.float32)
    dressed.garment.data.uv_layers["UVMap"].data.foreach_get("uv", uv_before)
    transfer_result()
    assert bpy.ops.garment_transfer.evaluate() == {'FINISHED'}
    after = scene_state()
    for obj in inputs:
        assert after[f"object:{obj.name}"] == before[obj.name], obj.name
    uv_after = np.empty_like(uv_before)
    dressed.garment.data.uv_layers["UVMap"].data.foreach_get("uv", uv_after)
    np.testing.assert_array_equal(uv_after, uv_before)


def test_result_keeps_uvs_vertex_groups_materials_seams_and_sharp_edges(dressed):
    garment = dressed.garment
    result = transfer_result()
    g, r = garment.data, result.data

    def loop_uvs(me):
        uv = np.empty(2 * len(me.loops), np.float32)
        me.uv_layers["UVMap"].data.foreach_get("uv", uv)
        return uv

    np.testing.assert_array_equal(loop_uvs(r), loop_uvs(g))
    assert [vg.name for vg in result.vertex_groups] == [vg.name for vg in garment.vertex_groups]
    for v_g, v_r in zip(g.vertices, r.vertices):
        assert [(e.group, round(e.weight, 6)) for e in v_g.groups] == \
               [(e.group, round(e.weight, 6)) for e in v_r.groups]
    assert [m.name for m in r.materials] == ["fabric", "trim"]
    for attr in ("material_index",):
        a = np.empty(len(g.polygons), np.int32)
        b = np.empty(len(r.polygons), np.int32)
        g.polygons.foreach_get(attr, a)
        r.polygons.foreach_get(attr, b)
        np.testing.assert_array_equal(a, b)
    for attr in ("use_seam", "use_edge_sharp"):
        a = np.empty(len(g.edges), bool)
        b = np.empty(len(r.edges), bool)
        g.edges.foreach_get(attr, a)
        r.edges.foreach_get(attr, b)
        np.testing.assert_array_equal(a, b)
        assert a.any()
    fv_g = np.empty(len(g.loops), np.int32)
    fv_r = np.empty(len(r.loops), np.int32)
    g.loops.foreach_get("vertex_index", fv_g)
    r.loops.foreach_get("vertex_index", fv_r)
    np.testing.assert_array_equal(fv_g, fv_r)


def test_transfer_works_in_world_space(dressed):
    # Without the penetration fix the core is exactly equivariant; with it, float32 rounding of the
    # moved inputs flips a few push-out decisions (seen: 9 of 1797 vertices by up to 5 mm).
    dressed.settings.fix_penetration = False
    first = world_vertices(transfer_result())
    # Move, turn and scale all three objects alike: the result must follow. The turn is a quarter
    # turn because the core's length scale (bounding box extent) changes under other rotations.
    rig = bpy.data.objects.new("rig", None)
    bpy.context.scene.collection.objects.link(rig)
    rig.location = (0.4, -1.2, 0.3)
    rig.rotation_euler = (0.0, 0.0, np.pi / 2)
    rig.scale = (1.5, 1.5, 1.5)
    for obj in (dressed.source, dressed.target, dressed.garment):
        obj.parent = rig
    bpy.context.view_layer.update()
    second_obj = transfer_result()
    M = np.array(rig.matrix_world)
    np.testing.assert_allclose(world_vertices(second_obj), first @ M[:3, :3].T + M[:3, 3], atol=1e-4)
    assert second_obj.parent is None


def test_a_target_character_facing_another_way_is_dressed_facing_it(dressed):
    # Only the target turned (a character placed facing another way in the scene): the same pose, dressed as in
    # place and turned with it (it was refused as "another pose": its arms pointed elsewhere in the world).
    first = world_vertices(transfer_result())
    before = np.array(dressed.target.matrix_world)
    dressed.target.rotation_euler[2] += np.pi / 2
    dressed.target.location = (2.0, 1.0, 0.0)
    bpy.context.view_layer.update()
    turned = transfer_result()
    M = np.array(dressed.target.matrix_world) @ np.linalg.inv(before)
    err = np.linalg.norm(world_vertices(turned) - (first @ M[:3, :3].T + M[:3, 3]), axis=1)
    assert err.mean() < 1e-4

def test_shape_keys_and_modifiers_evaluated_or_base(dressed):
    garment = dressed.garment
    n = len(garment.data.vertices)
    garment.shape_key_add(name="Basis")
    loose = garment.shape_key_add(name="Loose")
    co = np.empty(3 * n, np.float32)
    loose.data.foreach_get("co", co)
    loose.data.foreach_set("co", co * np.float32(1.01))
    loose.value = 1.0
    sub = garment.modifiers.new("Subdivision", 'SUBSURF')
    sub.levels = 1
    garment.modifiers.new("Displace", 'DISPLACE').strength = 0.0

    settings = dressed.settings
    settings.use_evaluated = True
    evaluated = transfer_result()
    assert len(evaluated.data.vertices) > n                 # subdivided, then transferred
    assert len(evaluated.modifiers) == 0 and evaluated.data.shape_keys is None

    settings.use_evaluated = False
    base = transfer_result()
    assert len(base.data.vertices) == n
    assert [m.name for m in base.modifiers] == ["Subdivision"]   # refines; Displace would move it
    assert base.data.shape_keys is None
    assert garment.data.shape_keys is not None and len(garment.modifiers) == 2


def test_model_method_uses_the_loaded_model(dressed, tmp_path, extension):
    pytest.importorskip("torch", reason="training a model needs torch")
    training = extension.garment_transfer
    make_tiny_dataset(dressed.makehuman, tmp_path / "ds", garments=("female_casualsuit01",
                                                                     "male_casualsuit04"))
    training.train_from_dataset(tmp_path / "ds", "female_average", ["female_pear"], epochs=30,
                                latent=2, out=tmp_path / "m.npz")
    settings = dressed.settings
    settings.method = 'MODEL'
    settings.model_path = str(tmp_path / "m.npz")
    assert [t.name for t in settings.model_targets] == ["female_pear"]
    assert settings.target_label == "female_pear"
    result = transfer_result()
    reference = import_obj(dressed.makehuman / "garments" / GARMENT / "female_pear.obj", "reference")
    error = np.linalg.norm(world_vertices(result) - world_vertices(reference), axis=1).mean()
    moved = np.linalg.norm(world_vertices(dressed.garment) - world_vertices(reference), axis=1).mean()
    # Seen: 0.20 of the untransferred garment's error; 0.55 when the model's frame is ignored.
    assert error < 0.35 * moved


def test_garment_fit_model_file_with_its_placement(dressed, tmp_path, extension):
    pytest.importorskip("torch", reason="training a model needs torch")
    training = model_files = extension.garment_transfer
    make_tiny_dataset(dressed.makehuman, tmp_path / "ds", garments=("female_casualsuit01", "male_casualsuit04"))
    path = tmp_path / "garment.npz"
    training.train_garment_fit_from_dataset(tmp_path / "ds", "female_average", ["female_pear"], epochs=2,
                                            placement_epochs=5, out=path, threads=1)
    settings = dressed.settings
    settings.method = 'MODEL'
    settings.model_path = str(path)
    assert settings.model_status == "Garment fit model + learned placement, 1 target(s)"
    assert settings.model_kind == 'GARMENT' and settings.target_label == "female_pear"
    assert settings.field_share == 0.5
    result = transfer_result()
    # One line: which method made the result, and what it gains.
    assert settings.last_model == ("Garment fit + placement (garment.npz, field share 0.5): 0.62x Direct's distance "
                                   "to a cloth simulation, design kept")

    # The same as the core with the file's models, in the model's frame (a Y-up dataset).
    convert = extension.operators.convert
    dg = bpy.context.evaluated_depsgraph_get()
    meshes = [convert.core_mesh_from_object(o, dg) for o in (dressed.source, dressed.target, dressed.garment)]
    loaded = model_files.read_model_file(path)
    frame = extension.operators.transfer.model_frame(loaded)
    expected = core(extension).transfer_garment(
        *[m.with_vertices(m.V @ frame.T) for m in meshes], method="model", model=loaded.model,
        placement=loaded.placement, target="female_pear").V @ frame
    np.testing.assert_allclose(world_vertices(result), expected, atol=1e-5)

    settings.field_share = 1.0
    whole = transfer_result()
    assert settings.last_model.startswith("Garment fit + placement (garment.npz, field share 1): ")
    assert np.abs(world_vertices(whole) - world_vertices(result)).max() > 1e-4
    settings.method = 'DIRECT'
    transfer_result()
    assert settings.last_model.startswith("Direct: the body's own deformation, no model")

    # A placement model alone is refused, naming the file, and nothing in the scene changes.
    placement_alone = tmp_path / "placement_alone.npz"
    placed = loaded.placement.model.model    # the default: an ensemble of placement networks (mixed with the
    getattr(placed, "members", [placed])[0].save(placement_alone)   # nearest garments'); one of them
    settings.method = 'MODEL'
    settings.model_path = str(placement_alone)
    assert "placement_alone.npz: holds a placement model alone" in settings.model_status
    assert settings.model_kind == 'NONE'
    before = scene_state()
    with pytest.raises(RuntimeError, match="placement_alone.npz"):
        bpy.ops.garment_transfer.transfer()
    assert scene_state() == before


def make_tiny_dataset(makehuman, folder, garments, bodies=("female_average", "female_pear")):
    """A dataset folder of links to the MakeHuman files."""
    (folder / "bodies").mkdir(parents=True)
    for body in bodies:
        (folder / "bodies" / f"{body}.obj").symlink_to(makehuman / "bodies" / f"{body}.obj")
    for garment in garments:
        (folder / "garments" / garment).mkdir(parents=True)
        for body in bodies:
            (folder / "garments" / garment / f"{body}.obj").symlink_to(
                makehuman / "garments" / garment / f"{body}.obj")
    (folder / "manifest.json").write_text('{"units": "decimetres", "up_axis": "Y"}')
    return folder


def test_the_panel_and_the_warnings_say_what_the_object_crosses_as_blender_has_it(dressed, extension, monkeypatch,
                                                                                   capfd):
    # The result is made and kept; its figures are those of the new object as Blender evaluates it (world space,
    # 32-bit coordinates) against the target as read, under every triangulation of both: the panel shows them
    # and the artist is told what crosses.
    import json
    import logging

    from garment_transfer.geometry import clearance

    real = clearance.separate

    def defeated(V, *args, **kwargs):
        out, info = real(V, *args, **kwargs)
        out = out.copy()
        out[0] = 2 * out[0] - out[1000]         # one vertex taken far off: its edges pass through the body
        logging.getLogger("garment_transfer.geometry.clearance").warning("the pass gave up here")
        return out, info

    gt = core(extension)

    def mesh_of(obj):
        me = obj.data
        fv = np.empty(len(me.loops), dtype=np.int64)
        me.loops.foreach_get("vertex_index", fv)
        sizes = np.empty(len(me.polygons), dtype=np.int64)
        me.polygons.foreach_get("loop_total", sizes)
        return gt.mesh_from_polygons(world_vertices(obj), np.split(fv, np.cumsum(sizes)[:-1]), name=obj.name)

    def independent(result):
        cloth, body = mesh_of(result), mesh_of(dressed.target)
        return gt.crossings(cloth.V, gt.readings_of(cloth), body.V, gt.readings_of(body))

    monkeypatch.setattr(clearance, "separate", defeated)
    result = transfer_result()
    assert result is not None and result.name == "sportsuit_on_pear"
    shown = json.loads(dressed.settings.last_metrics)
    c = independent(result)
    assert shown["garment_edges_through_body"] == c["a_edges_through_b"] > 0
    assert shown["body_edges_through_garment"] == c["b_edges_through_a"]
    err = capfd.readouterr()
    assert "sportsuit_on_pear: " in err.out + err.err and "garment edges pass through the body" in err.out + err.err
    monkeypatch.setattr(clearance, "separate", real)
    bpy.data.objects.remove(result)
    result = transfer_result()
    err = capfd.readouterr()
    assert "pass through the body" not in err.out + err.err
    shown = json.loads(dressed.settings.last_metrics)
    c = independent(result)
    assert shown["garment_edges_through_body"] == shown["body_edges_through_garment"] == 0
    assert c["a_edge_pairs"] + c["b_edge_pairs"] == 0 and shown["min_body_distance"] > 0


def test_a_garment_in_pieces_not_joined_at_their_seams_keeps_them_closed(dressed, tmp_path):
    from meshes import in_pieces

    from garment_transfer import mesh_from_triangles, read_obj, write_obj

    # The suit's left and right halves as pieces (each vertex on the seam between them written again), as a
    # pattern's pieces come out of other tools, imported as Blender imports them.
    suit = read_obj(dressed.makehuman / "garments" / GARMENT / "female_average.obj")
    V, F, seam, twin = in_pieces(suit.V, suit.F)
    write_obj(tmp_path / "pieces.obj", mesh_from_triangles(V, F, "pieces"))
    dressed.settings.garment = import_obj(tmp_path / "pieces.obj", "pieces")
    assert len(dressed.settings.garment.data.vertices) == suit.n_vertices + seam.size
    W = world_vertices(transfer_result())
    assert np.array_equal(W[twin], W[seam])
    assert np.abs(W[seam] - world_vertices(dressed.settings.garment)[seam]).max() > 1e-3     # moved, together
