"""Garments that move: an armature made from MakeHuman's rig, a rigged transfer result, the fit to the current
pose and its bake over frames, with the real bpy module."""

from __future__ import annotations

import json

import bpy
import numpy as np
import pytest
from conftest import import_obj, world_vertices

from garment_transfer import (Rig, bvh_rotations, fit_to_pose, posed_counts, read_bvh, read_joints, read_mdd, read_obj,
                              read_pc2, read_skeleton, read_weights, transfer_garment, write_pc2)

# Blender's OBJ import of a Y-up file in decimetres (conftest.import_obj): world = 0.1 * C @ file.
C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def kinds(obj):
    """The types of the object's modifiers, the Shrinkwraps of Keep Outside Body's bands counted once."""
    k = [m.type for m in obj.modifiers]
    return [t for i, t in enumerate(k) if not (t == 'SHRINKWRAP' and i and k[i - 1] == 'SHRINKWRAP')]

def to_world(P):
    return 0.1 * np.asarray(P) @ C.T


def extension_rigging():
    import sys

    return sys.modules[bpy.types.GARMENT_TRANSFER_OT_rig_garment.__module__]


@pytest.fixture
def character(makehuman):
    """The pear body with MakeHuman's skeleton as an armature, its weights as vertex groups and an Armature
    modifier; the average body and a suit on it as the source, all chosen in the Garment tab."""
    rigging = extension_rigging()
    skeleton = read_skeleton(makehuman / "rig" / "skeleton.json")
    joints = read_joints(makehuman / "rig" / "joints" / "female_pear.json")
    weights = read_weights(makehuman / "rig" / "weights.json", 13380)
    body = import_obj(makehuman / "bodies" / "female_pear.obj", "pear")
    source = import_obj(makehuman / "bodies" / "female_average.obj", "average")
    garment = import_obj(makehuman / "garments" / "female_sportsuit01" / "female_average.obj", "suit")
    armature = rigging.make_armature(bpy.context, "pear_rig", skeleton,
                                     {k: to_world(v) for k, v in joints.items()})
    rigging.write_vertex_groups(body, weights)
    mod = body.modifiers.new(name="Armature", type='ARMATURE')
    mod.object = armature
    settings = bpy.context.scene.garment_transfer
    settings.source_body, settings.target_body, settings.garment = source, body, garment
    core_rig = Rig(skeleton, {k: to_world(v) for k, v in joints.items()}, weights)
    return rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman


def local_evaluated(obj):
    """(n,3) float32: the object's evaluated vertices in its own space (what a point cache of it holds)."""
    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    me = ev.to_mesh()
    try:
        co = np.empty(3 * len(me.vertices), dtype=np.float32)
        me.vertices.foreach_get("co", co)
    finally:
        ev.to_mesh_clear()
    return co.reshape(-1, 3)


def evaluated_world(obj):
    M = np.array(obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).matrix_world)
    return local_evaluated(obj).astype(np.float64) @ M[:3, :3].T + M[:3, 3]


def pose(character, name):
    rigging, skeleton, core_rig, _, _, _, armature, _, makehuman = character
    # Blender's world is Z up like the BVH files: their rotations apply as they are.
    R = bvh_rotations(read_bvh(makehuman / "poses" / f"{name}.bvh"), skeleton, file_up="Z", body_up="Z")
    T = core_rig.transforms(R)
    rigging.pose_armature(armature, skeleton, T)
    bpy.context.view_layer.update()
    return T


def key_rest_to_pose(armature):
    """The armature's pose keyed at frame 3 and its rest at frame 1 (frame 2 halfway)."""
    for bone in armature.pose.bones:
        bone.keyframe_insert("location", frame=3)
        bone.keyframe_insert("rotation_quaternion", frame=3)
        bone.matrix_basis.identity()
        bone.keyframe_insert("location", frame=1)
        bone.keyframe_insert("rotation_quaternion", frame=1)


def test_an_armature_from_the_rig_has_its_bones_rolls_and_poses_the_body_as_the_core_does(character):
    rigging, skeleton, core_rig, body, *_ = character
    armature = character[6]
    bones = armature.data.bones
    assert len(bones) == skeleton.n_bones
    heads, tails = core_rig.rest()
    i = skeleton.index("lowerarm01.L")
    assert np.allclose(np.array(bones["lowerarm01.L"].head_local), heads[i], atol=1e-6)
    assert np.allclose(np.array(bones["lowerarm01.L"].tail_local), tails[i], atol=1e-6)
    from garment_transfer import bone_frames

    z = np.array(bones["lowerarm01.L"].matrix_local)[:3, 2]
    assert np.dot(z, bone_frames(skeleton, core_rig.joints)[i][:, 2]) > 0.9999
    T = pose(character, "run01")
    expected = core_rig.pose(world_vertices(body), T)
    posed = evaluated_world(body)
    assert np.abs(posed - world_vertices(body)).max() > 0.1          # it moved (metres)
    assert np.abs(posed - expected).max() < 1e-4                     # as the core's skinning, to 0.1 mm


def test_a_transfer_onto_a_rigged_posed_body_is_made_at_rest_and_rigged(character):
    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    pose(character, "standing01")
    settings.max_influences = 4
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    result = settings.result
    # Made on the rest pose: the base mesh is the transfer to the body at rest.
    src, tgt = (read_obj(makehuman / "bodies" / f"{n}.obj") for n in ("female_average", "female_pear"))
    cloth = read_obj(makehuman / "garments" / "female_sportsuit01" / "female_average.obj")
    at_rest = to_world(transfer_garment(src, tgt, cloth).V)
    # Within 1 mm (the scene holds float32 coordinates; the pose moves the cloth by decimetres).
    assert np.abs(world_vertices(result) - at_rest).max() < 1e-3
    assert kinds(result) == ['ARMATURE', 'SHRINKWRAP']
    assert result.modifiers[0].object == armature and result.modifiers[1].target == body
    # The Shrinkwrap keeps the transfer's cloth offset (world units; the modifier's offset is in the body's own
    # units, the Shrinkwrap snapping in its target's space): it moves nothing at rest.
    from garment_transfer import OFFSET_SHARE, body_scale

    assert body.matrix_world.to_scale()[0] == pytest.approx(0.1)          # scaled on import: the units matter
    # Keep Outside Body in bands: the last, limited to the vertices the cloth at rest holds that far, at the offset.
    assert [m.name for m in result.modifiers[1:]] == ["Keep Outside Body", "Keep Outside Body 2",
                                                      "Keep Outside Body 3", "Keep Outside Body 4"]
    assert result.modifiers[-1].offset * np.mean(np.array(body.matrix_world.to_scale())) == \
        pytest.approx(OFFSET_SHARE * body_scale(to_world(tgt.V)), rel=1e-5)
    bands = {m.vertex_group for m in result.modifiers if m.type == 'SHRINKWRAP' and m.vertex_group}
    assert len(bands) == 3
    groups = {g.index: g.name for g in result.vertex_groups if g.name not in bands}
    assert set(groups.values()) <= set(skeleton.names)
    counts = np.array([sum(g.group in groups for g in v.groups) for v in result.data.vertices])
    sums = np.array([sum(g.weight for g in v.groups if g.group in groups) for v in result.data.vertices])
    assert counts.max() <= 4 and np.allclose(sums, 1, atol=1e-4)
    assert not garment.vertex_groups and not garment.modifiers          # the input is unchanged
    moved = np.linalg.norm(evaluated_world(result) - world_vertices(result), axis=1)
    assert moved.max() > 0.05                                           # it follows the pose


def test_riding_the_body_surface_keeps_the_cloth_on_the_skin_at_the_bends(character):
    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    from garment_transfer import TriangleSurface, riding_share

    settings.ride_surface = True
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    result = settings.result
    assert kinds(result) == ['ARMATURE', 'SURFACE_DEFORM', 'SHRINKWRAP']
    ride = result.modifiers[1]
    assert ride.is_bound and ride.target == body and ride.vertex_group == rigging.RIDE_GROUP
    rest_body = read_obj(makehuman / "bodies" / "female_pear.obj")
    rest_body = rest_body.with_vertices(to_world(rest_body.V))
    cloth = world_vertices(result)
    # The garment as the operator reads it (its quads split by the extension).
    mesh = rigging.convert.core_mesh_from_object(result, bpy.context.evaluated_depsgraph_get(), False, "garment")
    share = riding_share(rest_body.V, rest_body.F, mesh.V, mesh.F)
    group = result.vertex_groups[rigging.RIDE_GROUP].index
    written = np.zeros(len(cloth))
    for v in result.data.vertices:
        for g in v.groups:
            if g.group == group:
                written[v.index] = g.weight
    on_skin = share > 0.9
    assert np.allclose(written, np.round(share, 4), atol=1e-3) and on_skin.sum() > 0.5 * len(share)
    # Without the Shrinkwrap, so that the Surface Deform is seen alone; the same weights without it as the
    # reference. In fight01, the cloth on the skin keeps its distance from the skinned body better.
    riding = result.copy()
    riding.data = result.data.copy()
    bpy.context.scene.collection.objects.link(riding)
    for mod in [m for m in riding.modifiers if m.type == 'SHRINKWRAP']:
        riding.modifiers.remove(mod)
    bones_only = riding.copy()
    bones_only.data = riding.data.copy()
    bpy.context.scene.collection.objects.link(bones_only)
    bones_only.modifiers.remove(bones_only.modifiers[1])
    # Bound at rest, and the Shrinkwrap at the cloth offset: at rest the whole rig moves nothing.
    assert np.abs(evaluated_world(result) - cloth).max() < 1e-5
    rest_distance = TriangleSurface(rest_body.V, rest_body.F).signed_distance(cloth)[0]
    pose(character, "fight01")
    posed = TriangleSurface(evaluated_world(body), rest_body.F)
    kept = [np.abs(posed.signed_distance(evaluated_world(o))[0] - rest_distance)[on_skin] for o in (riding, bones_only)]
    assert np.percentile(kept[0], 95) < 0.5 * np.percentile(kept[1], 95)
    assert np.linalg.norm(evaluated_world(riding) - cloth, axis=1).max() > 0.3           # it moved with the pose
    # Rigged again without it (Rig to Body, the body posed): the Surface Deform and its group go.
    settings.ride_surface = False
    assert bpy.ops.garment_transfer.rig_garment() == {'FINISHED'}
    assert kinds(result) == ['ARMATURE', 'SHRINKWRAP']
    assert rigging.RIDE_GROUP not in result.vertex_groups
    settings.ride_surface = True
    assert bpy.ops.garment_transfer.rig_garment() == {'FINISHED'}
    assert kinds(result) == ['ARMATURE', 'SURFACE_DEFORM', 'SHRINKWRAP']
    assert result.modifiers[1].is_bound


def test_fit_to_pose_and_bake(character, tmp_path):
    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    result = settings.result
    T = pose(character, "fight01")
    bpy.context.scene.frame_set(7)
    assert bpy.ops.garment_transfer.fit_pose() == {'FINISHED'}
    fitted = bpy.data.objects[f"{result.name}_fitted_7"]
    rest_body = read_obj(makehuman / "bodies" / "female_pear.obj")
    rest_body = rest_body.with_vertices(to_world(rest_body.V))
    cloth = rest_body.__class__(world_vertices(result), *[getattr(read_obj(
        makehuman / "garments" / "female_sportsuit01" / "female_average.obj"), k)
        for k in ("F", "face_vertices", "face_start", "tri_to_face")])
    expected = fit_to_pose(rest_body, core_rig.pose(rest_body.V, T), cloth)
    assert expected.info["crossings_outside_contact"] == 0
    # The scene's float32 coordinates can take the crossing pass another way here and there: within 1 mm on
    # average of the core's fit (the kick moves the cloth by decimetres).
    assert np.linalg.norm(world_vertices(fitted) - expected.V, axis=1).mean() < 1e-3
    assert not [m for m in fitted.modifiers if m.type in ('ARMATURE', 'SHRINKWRAP')]
    # Its figures are those of the object as Blender has it, against the body as posed, counted here afresh.
    posed_body = rest_body.with_vertices(evaluated_world(body))
    offset = expected.info["offset"]

    def counted():
        own = posed_counts(evaluated_world(fitted), cloth, posed_body, offset, rest_V=rest_body.V)
        return {k: v for k, v in own.items() if k != "warnings"}

    assert fitted[rigging.FIGURES].to_dict() == counted()
    assert counted()["crossings_outside_contact"] == 0
    # Untangled (Fit to Pose's option): another new object that crosses itself less and the body no more.
    before = set(bpy.data.objects)
    assert bpy.ops.garment_transfer.fit_pose(untangle=True) == {'FINISHED'}
    untangled, = set(bpy.data.objects) - before
    plain, figures = fitted[rigging.FIGURES].to_dict(), untangled[rigging.FIGURES].to_dict()
    assert 0 <= figures["self_intersections_new"] < plain["self_intersections_new"]
    assert figures["crossings_outside_contact"] == 0
    assert figures["crossings_at_contact"] <= plain["crossings_at_contact"]
    bpy.data.objects.remove(untangled)
    # Bake three frames: rest at 1, the kick at 3, keyed in between.
    key_rest_to_pose(armature)
    bpy.context.scene.frame_set(5)
    before = set(bpy.data.objects)
    steps = rigging.bake_steps(bpy.context, result, body, 1, 3)
    next(steps)
    steps.close()                                                       # cancelled: nothing made
    assert set(bpy.data.objects) == before and bpy.context.scene.frame_current == 5
    # Run to the end, a bake keeps of each frame its fit and the body's contact, not the binned body (about 20 MB
    # a frame): a long action fits in memory.
    steps = rigging.bake_steps(bpy.context, result, body, 2, 3)
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            kept = stop.value[2]["frames"]
            break
    assert len(kept) == 2 and all(o.obstacle is None and o.surface is None and o.contact is not None for _, o in kept)
    assert bpy.ops.garment_transfer.bake_pose_fit(frame_start=1, frame_end=3) == {'FINISHED'}
    baked = bpy.data.objects[f"{result.name}_baked"]
    keys = baked.data.shape_keys.key_blocks
    assert [k.name for k in keys] == ["Basis", "frame 1", "frame 2", "frame 3"]
    assert bpy.context.scene.frame_current == 5
    bpy.context.scene.frame_set(3)
    assert [round(k.value, 6) for k in keys[1:]] == [0.0, 0.0, 1.0]
    assert np.linalg.norm(evaluated_world(baked) - expected.V, axis=1).mean() < 1e-3   # frame 3: the kick's fit
    # The bake's figures: counted on the baked object as it plays back, frame by frame.
    played = []
    for frame in (1, 2, 3):
        bpy.context.scene.frame_set(frame)
        played.append(posed_counts(evaluated_world(baked), cloth, rest_body.with_vertices(evaluated_world(body)),
                                   offset, rest_V=rest_body.V))
    figures = baked[rigging.FIGURES].to_dict()
    assert figures["frames"] == 3
    for key in ("crossings_outside_contact", "crossings_at_contact", "penetrating_vertices", "self_intersections_new"):
        assert figures[key] == sum(p[key] for p in played)
    assert figures["frames_with_crossings"] == sum(1 for p in played if p["crossings_outside_contact"])
    # The same bake into a PC2 point cache, played by a Mesh Cache modifier: each frame as the keyed one plays it.
    cache = tmp_path / "suit.pc2"
    (tmp_path / "notes.pc2").write_text("not a cache")
    # A character's own point cache, played by a Mesh Cache modifier of the scene, is never replaced.
    write_pc2(tmp_path / "character.pc2", np.zeros((2, len(source.data.vertices), 3)))
    character_cache = source.modifiers.new(name="Character Cache", type='MESH_CACHE')
    character_cache.cache_format, character_cache.filepath = 'PC2', str(tmp_path / "character.pc2")
    character_cache.show_viewport = character_cache.show_render = False
    kept = (tmp_path / "character.pc2").read_bytes()
    for path in (tmp_path / "notes.pc2", tmp_path / "missing" / "suit.pc2", tmp_path / "character.pc2"):
        before = set(bpy.data.objects)
        with pytest.raises(RuntimeError, match=str(path.name)):
            bpy.ops.garment_transfer.bake_pose_fit(frame_start=1, frame_end=3, cache_file=str(path))
        assert set(bpy.data.objects) == before
    assert (tmp_path / "notes.pc2").read_text() == "not a cache"
    assert (tmp_path / "character.pc2").read_bytes() == kept
    source.modifiers.remove(character_cache)
    baked.name = "keyed"
    assert bpy.ops.garment_transfer.bake_pose_fit(frame_start=1, frame_end=3, cache_file=str(cache)) == {'FINISHED'}
    cached = bpy.data.objects[f"{result.name}_baked"]
    assert cached.data.shape_keys is None and cached.modifiers[0].type == 'MESH_CACHE'
    positions, start, _ = read_pc2(cache)
    assert positions.shape == (3, len(cached.data.vertices), 3) and start == 1.0
    for frame in (1, 2, 3):
        bpy.context.scene.frame_set(frame)
        assert np.abs(evaluated_world(cached) - evaluated_world(baked)).max() < 1e-5
    assert cached[rigging.FIGURES].to_dict() == figures
    # Baked again into the same cache: the PC2 file is replaced.
    assert bpy.ops.garment_transfer.bake_pose_fit(frame_start=2, frame_end=3, cache_file=str(cache)) == {'FINISHED'}
    assert read_pc2(cache)[0].shape[0] == 2 and read_pc2(cache)[1] == 2.0
    # Into an MDD file (named .mdd): its times the frames' at the scene's rate, played by the Mesh Cache as MDD.
    mdd = tmp_path / "suit.mdd"
    (tmp_path / "notes.mdd").write_text("not a cache")
    with pytest.raises(RuntimeError, match="notes.mdd: is not an MDD point cache"):
        bpy.ops.garment_transfer.bake_pose_fit(frame_start=1, frame_end=3, cache_file=str(tmp_path / "notes.mdd"))
    before = set(bpy.data.objects)
    assert bpy.ops.garment_transfer.bake_pose_fit(frame_start=1, frame_end=3, cache_file=str(mdd)) == {'FINISHED'}
    played, = set(bpy.data.objects) - before
    assert played.modifiers[0].type == 'MESH_CACHE' and played.modifiers[0].cache_format == 'MDD'
    positions, times = read_mdd(mdd)
    render = bpy.context.scene.render
    assert positions.shape[0] == 3 and np.array_equal(times, np.float32(np.arange(3) * render.fps_base / render.fps))
    for frame in (1, 2, 3):
        bpy.context.scene.frame_set(frame)
        assert np.abs(evaluated_world(played) - evaluated_world(baked)).max() < 1e-5
    # Baked again into it: an MDD file of an earlier bake is replaced.
    assert bpy.ops.garment_transfer.bake_pose_fit(frame_start=2, frame_end=3, cache_file=str(mdd)) == {'FINISHED'}
    assert read_mdd(mdd)[0].shape[0] == 2


def test_rigging_a_result_to_a_body_without_an_armature_says_so_and_changes_nothing(character):
    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    body.modifiers.remove(body.modifiers["Armature"])
    settings.result = garment
    groups = len(garment.vertex_groups)
    with pytest.raises(RuntimeError, match="pear: has no Armature modifier"):
        bpy.ops.garment_transfer.rig_garment()
    assert len(garment.vertex_groups) == groups and not garment.modifiers
    with pytest.raises(RuntimeError, match="pear: has no Armature, Mesh Cache or Mesh Sequence Cache modifier: "
                                           "there is no pose to fit to"):
        bpy.ops.garment_transfer.fit_pose()


def kick_played_by_a_cache(character, path):
    """The body's frames 1-3 (rest, halfway, the kick) as its armature plays them, written to the PC2 file ``path``;
    then the armature taken off and a Mesh Cache modifier playing the file in its place. Returns the frames (local
    float32 positions) and the modifier."""
    _, _, _, body, _, _, armature, _, _ = character
    pose(character, "fight01")
    key_rest_to_pose(armature)
    frames = []
    for frame in (1, 2, 3):
        bpy.context.scene.frame_set(frame)
        frames.append(local_evaluated(body))
    write_pc2(path, np.stack(frames), start_frame=1.0)
    body.modifiers.remove(body.modifiers["Armature"])
    cache = body.modifiers.new(name="Kick", type='MESH_CACHE')
    cache.cache_format, cache.filepath, cache.frame_start = 'PC2', str(path), 1.0
    return frames, cache


def test_a_character_animated_by_a_point_cache_is_dressed_at_rest_and_fitted_and_baked_frame_by_frame(character,
                                                                                                    tmp_path):
    # An animation handed on as a point cache: the body's frames 1-3 (rest, halfway, the kick) as its armature
    # plays them, written to a PC2 file; then the armature taken off and a Mesh Cache modifier plays the file.
    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    frames, cache = kick_played_by_a_cache(character, tmp_path / "kick.pc2")
    for frame in (1, 2, 3):
        bpy.context.scene.frame_set(frame)
        assert np.array_equal(local_evaluated(body), frames[frame - 1])
    # Transfer Garment at the kick's frame dresses the body at rest (the cache hidden meanwhile), as with the
    # cache off; Fit to Pose and Bake Pose Fit follow the cache from there.
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    result = settings.result
    assert cache.show_viewport and np.array_equal(local_evaluated(body), frames[2])
    cache.show_viewport = False
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    assert np.array_equal(world_vertices(settings.result), world_vertices(result))
    bpy.data.objects.remove(settings.result)
    cache.show_viewport = True
    settings.result = result
    rest_body = read_obj(makehuman / "bodies" / "female_pear.obj")
    rest_body = rest_body.with_vertices(world_vertices(body))
    cloth = rest_body.__class__(world_vertices(result), *[getattr(read_obj(
        makehuman / "garments" / "female_sportsuit01" / "female_average.obj"), k)
        for k in ("F", "face_vertices", "face_start", "tri_to_face")])
    M = np.array(body.matrix_world)
    posed = [f.astype(np.float64) @ M[:3, :3].T + M[:3, 3] for f in frames]
    # With no bones to weight it, the result follows the body's surface as the cache plays it: a Surface Deform
    # bound at rest and the Shrinkwraps that keep it outside, which move nothing at rest.
    assert kinds(result) == ['SURFACE_DEFORM', 'SHRINKWRAP'] and result.modifiers[0].is_bound
    assert not result.modifiers[0].vertex_group
    assert not [g for g in result.vertex_groups if g.name in armature.data.bones]
    bpy.context.scene.frame_set(1)
    assert np.abs(evaluated_world(result) - cloth.V).max() < 1e-5
    bpy.context.scene.frame_set(3)
    offset = fit_to_pose(rest_body, posed[2], cloth).info["offset"]
    live = posed_counts(evaluated_world(result), cloth, rest_body.with_vertices(posed[2]), offset, rest_V=rest_body.V)
    still = posed_counts(cloth.V, cloth, rest_body.with_vertices(posed[2]), offset, rest_V=rest_body.V)
    # At the kick, the cloth as Blender plays it crosses the body away from its own contact a few times (2 measured;
    # 1,268 left where it was at rest), with no vertex inside (331).
    assert live["crossings_outside_contact"] < 0.05 * still["crossings_outside_contact"]
    assert live["penetrating_vertices"] < 0.05 * still["penetrating_vertices"]
    # Rig to Body again: the same correction made anew, nothing else added.
    assert bpy.ops.garment_transfer.rig_garment() == {'FINISHED'}
    assert kinds(result) == ['SURFACE_DEFORM', 'SHRINKWRAP'] and result.modifiers[0].is_bound
    assert posed_counts(evaluated_world(result), cloth, rest_body.with_vertices(posed[2]), offset,
                        rest_V=rest_body.V)["crossings_outside_contact"] == live["crossings_outside_contact"]
    assert bpy.ops.garment_transfer.fit_pose() == {'FINISHED'}
    fitted = bpy.data.objects[f"{result.name}_fitted_3"]
    expected = fit_to_pose(rest_body, posed[2], cloth)
    assert np.linalg.norm(world_vertices(fitted) - expected.V, axis=1).mean() < 1e-3
    assert fitted[rigging.FIGURES]["crossings_outside_contact"] == 0
    assert bpy.ops.garment_transfer.bake_pose_fit(frame_start=1, frame_end=3) == {'FINISHED'}
    baked = bpy.data.objects[f"{result.name}_baked"]
    for frame in (1, 2, 3):
        bpy.context.scene.frame_set(frame)
        expected = fit_to_pose(rest_body, posed[frame - 1], cloth)
        assert np.linalg.norm(evaluated_world(baked) - expected.V, axis=1).mean() < 1e-3
    figures = baked[rigging.FIGURES].to_dict()
    assert figures["frames"] == 3 and figures["crossings_outside_contact"] == 0
    assert cache.show_viewport and bpy.context.scene.frame_current == 3
    # The same animation as an Alembic file, played by a Mesh Sequence Cache modifier: fitted the same way.
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj == body)
    assert bpy.ops.wm.alembic_export(filepath=str(tmp_path / "kick.abc"), start=1, end=3,
                                     selected=True) == {'FINISHED'}
    body.modifiers.remove(cache)
    before = set(bpy.data.objects)
    assert bpy.ops.wm.alembic_import(filepath=str(tmp_path / "kick.abc")) == {'FINISHED'}
    imported, = set(bpy.data.objects) - before
    sequence = body.modifiers.new(name="Kick", type='MESH_SEQUENCE_CACHE')
    sequence.cache_file, sequence.object_path = imported.modifiers[0].cache_file, imported.modifiers[0].object_path
    bpy.data.objects.remove(imported)
    bpy.context.scene.frame_set(2)
    assert np.allclose(local_evaluated(body), frames[1], atol=1e-6)
    assert bpy.ops.garment_transfer.fit_pose() == {'FINISHED'}
    fitted = bpy.data.objects[f"{result.name}_fitted_2"]
    expected = fit_to_pose(rest_body, posed[1], cloth)
    assert np.linalg.norm(world_vertices(fitted) - expected.V, axis=1).mean() < 1e-3
    assert fitted[rigging.FIGURES]["crossings_outside_contact"] == 0 and sequence.show_viewport
    # A body with nothing that moves it: the bake says so.
    sequence.show_viewport = False
    with pytest.raises(RuntimeError, match="pear: has no Armature, Mesh Cache or Mesh Sequence Cache modifier: "
                                           "there is no motion to bake"):
        bpy.ops.garment_transfer.bake_pose_fit(frame_start=1, frame_end=3)


def test_rig_to_body_keeps_the_cloth_hanging_free_as_far_out_as_at_rest_and_moves_nothing_at_rest(character):
    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    from garment_transfer import OFFSET_SHARE, TriangleSurface, body_scale

    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    result = settings.result
    # The trouser legs below the knees made to hang free: moved 6 cm out from the body (twelve cloth offsets; the
    # cloth rides the skin up to 2% of the body's scale, 3.9 cm).
    rest_body = read_obj(makehuman / "bodies" / "female_pear.obj")
    rest_body = rest_body.with_vertices(to_world(rest_body.V))
    V = world_vertices(result)
    free = V[:, 2] < V[:, 2].min() + 0.3 * np.ptp(V[:, 2])
    closest = TriangleSurface(rest_body.V, rest_body.F).closest(V[free])[0]
    away = (V[free] - closest) / np.linalg.norm(V[free] - closest, axis=1, keepdims=True)
    V[free] += 0.06 * away
    M = np.array(result.matrix_world)
    local = (V - M[:3, 3]) @ np.linalg.inv(M[:3, :3]).T
    result.data.vertices.foreach_set("co", local.astype(np.float32).ravel())
    result.data.update()
    twin = result.copy()
    twin.data = result.data.copy()
    bpy.context.scene.collection.objects.link(twin)
    armature_obj, info = rigging.rig_to_body(bpy.context, result, body)
    rigging.rig_to_body(bpy.context, twin, body, hanging=False)
    offset = OFFSET_SHARE * body_scale(rest_body.V)
    scale = np.mean(np.array(body.matrix_world.to_scale()))
    shrinkwraps = [m for m in result.modifiers if m.type == 'SHRINKWRAP']
    beyond = [m for m in shrinkwraps if m.offset * scale > 1.01 * offset]
    # Beyond the cloth offset (the twin's last band), only the hanging cloth: bands up to four offsets.
    assert len(shrinkwraps) == len([m for m in twin.modifiers if m.type == 'SHRINKWRAP']) + len(beyond)
    assert [m.offset * scale for m in beyond] == pytest.approx([b * offset for b in (1.5, 2.0, 3.0, 4.0)], rel=1e-5)
    held = np.zeros(len(V), bool)
    for m in beyond:
        group = result.vertex_groups[m.vertex_group].index
        members = np.array([any(g.group == group for g in v.groups) for v in result.data.vertices])
        assert members.any() and not (members & ~free).any()
        held |= members
    # All but the rings next to the cloth left on the skin (its riding share is spread over three rings).
    assert info["hanging"] == held.sum() > 0.6 * free.sum()
    # At rest nothing moves (float32 coordinates).
    assert np.abs(evaluated_world(result) - world_vertices(result)).max() < 1e-5
    # Posed, only the hanging cloth differs from the rig without its bands.
    pose(character, "fight01")
    with_bands, without = evaluated_world(result), evaluated_world(twin)
    assert np.array_equal(with_bands[~held], without[~held])
    assert np.abs(with_bands[held] - without[held]).max() > 1e-4


def kick_as_rest_pose(character):
    """The pear's rest pose made the kick, as an artist does it: the Armature modifier applied, the pose applied as
    the armature's rest pose, the modifier added again. Returns the pear at rest (world space)."""
    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    T = pose(character, "fight01")
    rest_body = read_obj(makehuman / "bodies" / "female_pear.obj")
    rest_body = rest_body.with_vertices(to_world(rest_body.V))
    bpy.context.view_layer.objects.active = body
    bpy.ops.object.modifier_apply(modifier="Armature")
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode='POSE')
    bpy.ops.pose.armature_apply(selected=False)
    bpy.ops.object.mode_set(mode='OBJECT')
    body.modifiers.new(name="Armature", type='ARMATURE').object = armature
    bpy.context.view_layer.update()
    assert np.abs(world_vertices(body) - core_rig.pose(rest_body.V, T)).max() < 1e-4
    return rest_body


def rig_the_source(character):
    """The source body rigged as the pear is: the same skeleton on its own joints, the same weights."""
    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    joints = read_joints(makehuman / "rig" / "joints" / "female_average.json")
    source_armature = rigging.make_armature(bpy.context, "average_rig", skeleton,
                                            {k: to_world(v) for k, v in joints.items()})
    source.modifiers.new(name="Armature", type='ARMATURE').object = source_armature
    rigging.write_vertex_groups(source, core_rig.weights)


def against_the_kick(character, rest_body, result):
    """The reference: the suit transferred to the pear at rest by the core, on
    the files, then fitted to the kick the pear stands in (``fit_to_pose``); and the result's counts against the
    kicking pear as Blender has it (``posed_counts``: the source at rest tells which parts the kick pressed)."""
    _, _, _, body, source, _, _, _, makehuman = character
    src = read_obj(makehuman / "bodies" / "female_average.obj")
    cloth = read_obj(makehuman / "garments" / "female_sportsuit01" / "female_average.obj")
    at_rest = cloth.with_vertices(to_world(transfer_garment(src, read_obj(makehuman / "bodies" / "female_pear.obj"),
                                                            cloth).V))
    expected = fit_to_pose(rest_body, world_vertices(body), at_rest)
    counted = posed_counts(world_vertices(result), cloth, rest_body.with_vertices(world_vertices(body)),
                           expected.info["offset"], rest_V=world_vertices(source))
    return expected, counted


def test_a_character_in_another_rest_pose_gets_the_source_and_its_garment_posed_into_it_first(character):
    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    rest_body = kick_as_rest_pose(character)
    # The character's skeleton came from another tool, its bones in a namespace (Blender renames the body's vertex
    # groups with them): matched by name all the same.
    for bone in armature.data.bones:
        bone.name = f"character1:{bone.name}"
    assert "character1:upperarm01.L" in body.vertex_groups
    # The source without an armature: the pose difference is refused, naming the target and what would do, and
    # nothing is made.
    before = set(bpy.data.objects)
    with pytest.raises(RuntimeError, match="pear: is in another pose than the source body .* give both bodies an "
                                           "Armature modifier"):
        bpy.ops.garment_transfer.transfer()
    assert set(bpy.data.objects) == before
    # The source rigged alike (the same skeleton on its own joints, the same weights): posed into the kick first.
    joints = read_joints(makehuman / "rig" / "joints" / "female_average.json")
    source_armature = rigging.make_armature(bpy.context, "average_rig", skeleton,
                                            {k: to_world(v) for k, v in joints.items()})
    source.modifiers.new(name="Armature", type='ARMATURE').object = source_armature
    with pytest.raises(RuntimeError, match="give average vertex groups named as the bones of average_rig"):
        bpy.ops.garment_transfer.transfer()
    rigging.write_vertex_groups(source, core_rig.weights)
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    result = settings.result
    assert "posed into the target's rest pose first" in settings.last_registration
    assert result.modifiers[0].type == 'ARMATURE' and result.modifiers[0].object == armature     # rigged (default)
    # As if transferred at rest and then fitted to the kick (the core, on the files): within 3 mm on average.
    expected, counted = against_the_kick(character, rest_body, result)
    assert np.linalg.norm(world_vertices(result) - expected.V, axis=1).mean() < 3e-3
    # The figures are the object's against the posed character as Blender has it, counted afresh: none away from
    # where the kick makes the body cross or close on itself (the source at rest tells which parts it pressed).
    metrics = json.loads(settings.last_metrics)
    assert counted["crossings_outside_contact"] == 0 and counted["penetrating_vertices"] == 0
    assert metrics["crossings_outside_contact"] == 0
    assert metrics["crossings_at_contact"] == counted["crossings_at_contact"] == \
        metrics["garment_edges_through_body"] + metrics["body_edges_through_garment"]
    assert metrics["penetrating_vertices"] == 0
    # Posing the source folded the suit through itself where its source is not (measured: 25 pairs); with Untangle
    # (the Motion panel's) the transfer undoes it, said in the panel's line, and the kick is crossed no more.
    assert metrics["self_intersections_new"] > 0 and "untangled" not in settings.last_registration
    settings.untangle = True
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    untangled = json.loads(settings.last_metrics)
    assert untangled["self_intersections_new"] == 0 and "untangled: " in settings.last_registration
    assert untangled["crossings_outside_contact"] == 0 and untangled["penetrating_vertices"] == 0
    assert untangled["crossings_at_contact"] <= metrics["crossings_at_contact"]
    assert np.linalg.norm(world_vertices(settings.result) - expected.V, axis=1).mean() < 3e-3
    settings.untangle = False
    # The Evaluation panel shows them.
    from types import SimpleNamespace

    from test_panel import RecordingLayout

    calls = []
    bpy.types.VIEW3D_PT_garment_transfer_evaluation.draw(SimpleNamespace(layout=RecordingLayout(calls)), bpy.context)
    shown = [k.get("text") for kind, _, k in calls if kind == "label"]
    row = shown.index("Crossings away from body contact")
    assert shown[row + 1] == "0" and shown[row + 2] == "Crossings where body meets itself"


def test_a_character_of_another_mesh_in_another_rest_pose_is_registered_and_clear_of_its_own_body(character):
    from lab.registration import remesh
    from test_outfit_operator import mesh_object

    from garment_transfer.geometry.mesh import mesh_from_triangles
    from garment_transfer.geometry.proximity import TriangleSurface

    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    rest_body = kick_as_rest_pose(character)
    rig_the_source(character)
    # The kick as another mesh (a character made elsewhere), under the same armature (its bones as they stand),
    # skinned with the pear's weights at each vertex's place on the kicking pear.
    import scipy.sparse as sp

    from garment_transfer.rigging.skinning import SkinWeights

    F = rest_body.F
    U, G = remesh(world_vertices(body), F, 30000)
    _, _, tri, bary = TriangleSurface(world_vertices(body), F).closest(U)
    other = mesh_object(mesh_from_triangles(U, G, name="kick_remeshed"), "kick_remeshed")
    at = sp.csr_matrix((bary.ravel(), (np.repeat(np.arange(len(U)), 3), F[tri].ravel())),
                       shape=(len(U), rest_body.n_vertices))
    rigging.write_vertex_groups(other, SkinWeights(core_rig.weights.groups, (at @ core_rig.weights.W).tocsr()))
    other.modifiers.new(name="Armature", type='ARMATURE').object = armature
    bpy.context.view_layer.update()
    settings.target_body = other
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    result = settings.result
    assert settings.last_registration.startswith("Registered")
    assert "posed into the target's rest pose first" in settings.last_registration
    # Counted afresh against the character as given, with where its parts were at rest read from the kicking pear
    # it was made from (each vertex at its closest point there, at the same place of the source at rest: the pear
    # is the source's mesh), not from the registration: none away from where the kick makes the body cross or
    # close on itself, as the object's figures say.
    expected, _ = against_the_kick(character, rest_body, result)
    rest = np.einsum("pk,pkj->pj", bary, world_vertices(source)[F[tri]])
    cloth = read_obj(makehuman / "garments" / "female_sportsuit01" / "female_average.obj")
    counted = posed_counts(world_vertices(result), cloth, mesh_from_triangles(U, G), expected.info["offset"],
                           rest_V=rest, own=False)
    metrics = json.loads(settings.last_metrics)
    assert counted["crossings_outside_contact"] == 0 == metrics["crossings_outside_contact"]
    assert metrics["penetrating_vertices"] == counted["penetrating_vertices"]
    # Near the suit transferred at rest and fitted to the kick on the pear's own mesh (measured: 4.8 mm on average,
    # as the command line with the bones' rolls; the registration onto a posed body most of it).
    assert np.linalg.norm(world_vertices(result) - expected.V, axis=1).mean() < 6e-3


def test_an_outfit_onto_a_character_in_another_rest_pose_is_posed_layer_by_layer(character):
    from test_outfit_operator import mesh_object, set_layers

    from garment_transfer.geometry.intersections import crossings
    from lab.makehuman_procedural import MANNEQUIN, fit
    from lab.paths import DEMO_DATA

    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    # A T-shirt under a shift dress (two of the catalogue's garments) on the source, as objects in world space.
    src = read_obj(makehuman / "bodies" / "female_average.obj")
    mannequin = read_obj(DEMO_DATA / "bodies" / f"{MANNEQUIN}.obj")
    inner, _, _, registration = fit("tshirt", mannequin, src)
    outer, _, _, _ = fit("shift_dress", mannequin, src, registration)
    cloths = [m.with_vertices(to_world(m.V)) for m in (inner, outer)]
    set_layers(settings, [mesh_object(m, name) for m, name in zip(cloths, ("tshirt", "dress"))])
    rest_body = kick_as_rest_pose(character)
    rig_the_source(character)
    assert bpy.ops.garment_transfer.transfer_outfit() == {'FINISHED'}
    results = [bpy.data.objects[f"{name}_on_pear"] for name in ("tshirt", "dress")]
    assert all(r.modifiers[0].type == 'ARMATURE' and r.modifiers[0].object == armature for r in results)
    # As Blender has them, against the kicking character: nothing through it away from where it crosses itself,
    # the dress not through the T-shirt.
    from garment_transfer import OFFSET_SHARE, body_scale

    posed = rest_body.with_vertices(world_vertices(body))
    offset = OFFSET_SHARE * body_scale(world_vertices(source))
    for result, cloth in zip(results, cloths):
        counts = posed_counts(world_vertices(result), cloth, posed, offset, rest_V=world_vertices(source))
        assert counts["crossings_outside_contact"] == 0 and counts["penetrating_vertices"] == 0
    c = crossings(world_vertices(results[1]), cloths[1].F, world_vertices(results[0]), cloths[0].F)
    assert c["a_edge_pairs"] + c["b_edge_pairs"] == 0


def test_a_character_whose_skeleton_is_named_otherwise_is_matched_by_its_landmarks(character):
    from garment_transfer.rigging import skeleton_from_dict
    from lab.rest_pose_study import named_bones

    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    # The kick as the character's rest pose, its skeleton Mixamo's (as an FBX from Mixamo names it), its joints
    # where a rig made for the body puts them; the source rigged with MakeHuman's.
    T = core_rig.transforms(bvh_rotations(read_bvh(makehuman / "poses" / "fight01.bvh"), skeleton, file_up="Z",
                                          body_up="Z"))
    rest_body = kick_as_rest_pose(character)
    bones = named_bones(skeleton, core_rig.posed_joints(T), "Mixamo", prefix="mixamorig:")
    mixamo = rigging.make_armature(
        bpy.context, "mixamo_rig", skeleton_from_dict({"bones": {b: {"parent": p, "head": f"{b} head",
                                                                     "tail": f"{b} tail"}
                                                                 for b, (p, _, _) in bones.items()}}),
        {f"{b} {end}": point for b, (_, h, t) in bones.items() for end, point in (("head", h), ("tail", t))})
    body.modifiers["Armature"].object = mixamo
    rig_the_source(character)
    # The pear's vertex groups are MakeHuman's bones, not Mixamo's: the result is not rigged to it here.
    settings.rig_result = False
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    result = settings.result
    assert "posed into the target's rest pose first" in settings.last_registration
    assert "the Mixamo skeleton matched by 27 segments" in settings.last_registration
    # As if transferred at rest and then fitted to the kick: within 3 mm on average (1.6 mm measured; a finger's
    # last joint and the toes are not in the landmarks).
    expected, counted = against_the_kick(character, rest_body, result)
    assert np.linalg.norm(world_vertices(result) - expected.V, axis=1).mean() < 3e-3
    assert counted["crossings_outside_contact"] == 0 and counted["penetrating_vertices"] == 0


def test_rig_to_body_says_where_the_bodys_weights_leave_the_cloth_unweighted_and_refuses_weights_that_move_nothing(
        character, capfd):
    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    from test_outfit_operator import set_layers

    from garment_transfer import RigError

    settings.rig_result = False
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    result = settings.result
    Z = world_vertices(body)[:, 2]
    everyone = list(range(len(body.data.vertices)))
    # The body's lower legs left unpainted (below 20% of its height): the suit's trouser legs there have no weight.
    low = [int(i) for i in np.flatnonzero(Z < Z.min() + 0.2 * np.ptp(Z))]
    for group in body.vertex_groups:
        group.remove(low)
    _, info = rigging.rig_to_body(bpy.context, result, body)
    # Weighted by a bone (the Keep Outside bands' vertex groups are not bones).
    bones = {g.index for g in result.vertex_groups if g.name in set(rigging.deform_bones(armature))}
    weighted = np.array([any(g.group in bones and g.weight > 0 for g in v.groups) for v in result.data.vertices])
    assert info["unweighted"] == int((~weighted).sum()) > 0
    assert any(w.startswith(f"{info['unweighted']} of the {len(weighted)} vertices of {result.name} have no weight")
               for w in info["warnings"])
    # A rigged outfit says it too, for each layer (Blender's reports, printed by the bpy module).
    settings.rig_result = True
    set_layers(settings, [garment])
    capfd.readouterr()
    assert bpy.ops.garment_transfer.transfer_outfit() == {'FINISHED'}
    layer = settings.result
    said = [line for line in capfd.readouterr().out.splitlines() if "have no weight" in line]
    assert len(said) == 1 and said[0].startswith("Warning: ") and f"vertices of {layer.name} have no weight" in said[0]
    # Only the head painted: none of the suit's vertices gets a weight; refused, the result left as it was.
    head = Z > Z.min() + 0.88 * np.ptp(Z)
    for group in body.vertex_groups:
        group.remove([i for i in everyone if not head[i]])
    groups, modifiers = [g.name for g in result.vertex_groups], [m.name for m in result.modifiers]
    with pytest.raises(RigError, match=f"none of the {len(weighted)} vertices of {result.name} has a weight"):
        rigging.rig_to_body(bpy.context, result, body)
    assert [g.name for g in result.vertex_groups] == groups and [m.name for m in result.modifiers] == modifiers


def test_rig_to_body_on_a_subdivided_body_moves_nothing_at_rest(character):
    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    # The character smoothed in the viewport: its Subdivision Surface after the Armature.
    body.modifiers.new("Subdivision", 'SUBSURF').levels = 1
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    assert settings.last_registration == "Same mesh as the source body under its subdivision: no registration"
    result = settings.result
    rigging.rig_to_body(bpy.context, result, body)
    # The Shrinkwraps keep the cloth outside the surface they see, the subdivided one: their bands are measured on
    # it (measured on the mesh it subdivides, 21 vertices moved at rest, by up to 0.08 mm).
    assert np.abs(evaluated_world(result) - world_vertices(result)).max() < 1e-5


def test_a_sculpted_character_its_multiresolution_before_its_armature_is_dressed_on_its_base_mesh(character):
    # A sculpted character's stack: the Multiresolution first, the Armature after it.
    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    plain = world_vertices(settings.result)
    mod = body.modifiers.new("Multires", 'MULTIRES')
    with bpy.context.temp_override(object=body, active_object=body):
        assert bpy.ops.object.multires_subdivide(modifier=mod.name, mode='CATMULL_CLARK') == {'FINISHED'}
    body.modifiers.move(len(body.modifiers) - 1, 0)
    assert [m.type for m in body.modifiers] == ['MULTIRES', 'ARMATURE']
    pose(character, "fight01")
    assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
    assert settings.last_registration == "Same mesh as the source body under its subdivision: no registration"
    result = settings.result
    assert np.linalg.norm(world_vertices(result) - plain, axis=1).mean() < 0.0015
    assert kinds(result)[0] == 'ARMATURE' and mod.show_viewport and armature.data.pose_position == 'POSE'


def test_an_outfit_onto_a_character_played_by_a_point_cache_is_dressed_at_rest_and_follows_its_surface(character,
                                                                                                      tmp_path):
    from test_outfit_operator import mesh_object, set_layers

    from lab.makehuman_procedural import MANNEQUIN, fit
    from lab.paths import DEMO_DATA

    rigging, skeleton, core_rig, body, source, garment, armature, settings, makehuman = character
    src = read_obj(makehuman / "bodies" / "female_average.obj")
    mannequin = read_obj(DEMO_DATA / "bodies" / f"{MANNEQUIN}.obj")
    inner, _, _, registration = fit("tshirt", mannequin, src)
    outer, _, _, _ = fit("shift_dress", mannequin, src, registration)
    set_layers(settings, [mesh_object(m.with_vertices(to_world(m.V)), name)
                          for m, name in zip((inner, outer), ("tshirt", "dress"))])
    # The kick written to a PC2 file from the armature, then played by a Mesh Cache in its place.
    frames, cache = kick_played_by_a_cache(character, tmp_path / "kick.pc2")
    # At the kick's frame, each layer is made on the body at rest (as with the cache off) and follows its surface.
    assert bpy.ops.garment_transfer.transfer_outfit() == {'FINISHED'}
    results = [bpy.data.objects[f"{name}_on_pear"] for name in ("tshirt", "dress")]
    assert all(kinds(r) == ['SURFACE_DEFORM', 'SHRINKWRAP'] and r.modifiers[0].is_bound for r in results)
    assert cache.show_viewport and np.array_equal(local_evaluated(body), frames[2])
    made = [world_vertices(r) for r in results]
    for r in results:
        bpy.data.objects.remove(r)
    cache.show_viewport = False
    assert bpy.ops.garment_transfer.transfer_outfit() == {'FINISHED'}
    again = [bpy.data.objects[f"{name}_on_pear"] for name in ("tshirt", "dress")]
    assert all(np.array_equal(world_vertices(r), m) for r, m in zip(again, made))
