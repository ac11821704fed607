"""Garments that move with the character: weights and an Armature modifier from the body's armature, a fit to
the current pose, and a fit baked over a frame range.

- **Rig**: a result (transfer, outfit, size shape keys) gets the body's bones as vertex groups, with weights
  matched where the cloth lies on the skin and inpainted elsewhere (the core's ``inpainted_weights``), at most
  a few per vertex, an Armature modifier on the body's armature, and a Shrinkwrap (Outside) after it, so that
  playback is live and the skin stays under the cloth. Weights are computed with the armature in its rest
  position (the body and the cloth as modelled).
- **Fit to Pose**: the garment fitted to the body as posed at the current frame (the core's ``fit_to_pose``):
  a new object ``<garment>_fitted_<frame>``.
- **Bake Pose Fit**: the same for every frame of a range, one preparation: a new object ``<garment>_baked``
  with a shape key per frame, keyed so that each shows at its own frame. Playback of the bake is exact where
  the live rig is approximate.
"""

from __future__ import annotations

import contextlib
import os
import time

import bpy
import numpy as np
from bpy.props import BoolProperty, IntProperty, StringProperty
from mathutils import Matrix

from . import convert
from .reporting import ModalSteps, poll_objects, report_failure

#: Names of the modifiers a rigged result gets.
ARMATURE_MODIFIER = "Armature"
RIDE_MODIFIER = "Ride Body Surface"
KEEP_OUTSIDE_MODIFIER = "Keep Outside Body"
#: The Shrinkwrap's distance from the skin, a share of the transfer's cloth offset: the offset the transfer keeps
#: at rest, so that it moves nothing at rest and catches the skin through the cloth in a pose (half of it let
#: 1.03-1.10x as many crossings through over 16 poses in Blender, ``lab/notes/motion-study.md``).
KEEP_OUTSIDE_SHARE = 1.0
#: The vertex group that says how much each vertex rides the body's surface (not a bone: the Armature modifier
#: leaves it alone).
RIDE_GROUP = "Garment Transfer Ride"


def body_armature(body):
    """The armature object of the body's first Armature modifier that has one, or None."""
    for mod in body.modifiers:
        if mod.type == 'ARMATURE' and mod.object is not None:
            return mod.object
    return None


#: Modifiers that play a body's animation without an armature: a point cache (Mesh Cache: PC2, MDD) or an
#: Alembic or USD file (Mesh Sequence Cache), as an animation handed on from another tool arrives.
CACHE_MODIFIERS = frozenset({"MESH_CACHE", "MESH_SEQUENCE_CACHE"})


def body_caches(body):
    """The body's modifiers shown in the viewport that play an animation from a file (``CACHE_MODIFIERS``)."""
    return [mod for mod in body.modifiers if mod.type in CACHE_MODIFIERS and mod.show_viewport]


def body_moves(body):
    """Whether something moves the body: an Armature modifier with its armature, or a cache modifier
    (``body_caches``)."""
    return body_armature(body) is not None or bool(body_caches(body))


def require_motion(body, what):
    """Raise MeshError unless something moves the body (``body_moves``); ``what``: "pose to fit to", "motion to
    bake"."""
    from ..garment_transfer import MeshError

    if not body_moves(body):
        raise MeshError(body.name, f"has no Armature, Mesh Cache or Mesh Sequence Cache modifier: there is no "
                                   f"{what}")


@contextlib.contextmanager
def at_rest(body):
    """The body at rest for the block: its armature in its rest position (``rest_position``) and the modifiers
    that play its animation from a file (``body_caches``) hidden; then all as they were."""
    caches = body_caches(body)
    with rest_position(body_armature(body)):
        try:
            for mod in caches:
                mod.show_viewport = False
            if caches:
                bpy.context.view_layer.update()
            yield
        finally:
            for mod in caches:
                mod.show_viewport = True
            if caches:
                bpy.context.view_layer.update()


def made_at_rest(body, rig_result):
    """Where a transfer onto ``body`` is made: with ``rig_result`` (the result follows the body's motion: rigged,
    fitted to a pose, baked) on the body at rest (``at_rest``), else as the viewport shows it."""
    return at_rest(body) if rig_result else contextlib.nullcontext()


@contextlib.contextmanager
def rest_position(*armatures):
    """The armatures in their rest position for the block (``pose_position`` REST), then as they were."""
    armatures = [a for a in armatures if a is not None]
    before = [a.data.pose_position for a in armatures]
    try:
        for a in armatures:
            a.data.pose_position = 'REST'
        if armatures:
            bpy.context.view_layer.update()
        yield
    finally:
        for a, state in zip(armatures, before):
            a.data.pose_position = state
        if armatures:
            bpy.context.view_layer.update()


def deform_bones(armature):
    """Names of the armature's deforming bones."""
    return [b.name for b in armature.data.bones if b.use_deform]


@contextlib.contextmanager
def pose_remedy(why_not):
    """A pose difference refused in the block (``PoseError``) names what would have carried it: ``why_not`` of
    ``rest_pose_rigs`` (nothing changes when it is "": the rigs were there)."""
    from ..garment_transfer import PoseError

    try:
        yield
    except PoseError as e:
        if not why_not:
            raise
        raise PoseError(e.name, e.difference, f"Pose the two bodies alike first, or {why_not}") from None


def vertex_group_weights(obj, names):
    """The object's vertex groups called ``names`` as a core SkinWeights (groups it lacks come out empty)."""
    from ..garment_transfer import weights_from_dict

    index = {g.index: g.name for g in obj.vertex_groups if g.name in set(names)}
    pairs = {name: [] for name in names}
    for v in obj.data.vertices:
        for g in v.groups:
            name = index.get(g.group)
            if name is not None and g.weight > 0:
                pairs[name].append((v.index, g.weight))
    return weights_from_dict(pairs, len(obj.data.vertices), f"{obj.name}'s vertex groups")


def armature_bones(armature, depsgraph, evaluated=True):
    """Every bone of the armature in world space: {name: (parent name or None, head, tail, frame)}, the frame
    (3,3) the bone's axes (X, Y along the bone, Z: its roll) as a rotation. ``evaluated``: as posed now (the pose
    the Armature modifier gives its body, its rest position included); else at rest, as the mesh is without its
    modifiers."""
    A = convert.matrix_array(armature.matrix_world)
    if evaluated:
        items = [(b.name, b.parent.name if b.parent else None, b.head, b.tail, b.matrix)
                 for b in armature.evaluated_get(depsgraph).pose.bones]
    else:
        items = [(b.name, b.parent.name if b.parent else None, b.head_local, b.tail_local, b.matrix_local)
                 for b in armature.data.bones]
    bones = {}
    for name, parent, head, tail, matrix in items:
        M = A[:3, :3] @ convert.matrix_array(matrix)[:3, :3]
        # The nearest rotation to the bone's axes (an armature's or a bone's scale stretches them); a mirrored
        # armature's axes are left-handed: X turned back, so that Y (along the bone) and Z (its roll) are kept.
        U, _, Vt = np.linalg.svd(M)
        R = U @ Vt
        if np.linalg.det(R) < 0:
            R[:, 0] *= -1.0
        bones[name] = (parent, A[:3, :3] @ np.array(head) + A[:3, 3], A[:3, :3] @ np.array(tail) + A[:3, 3], R)
    return bones


def matched_bones(bones, names):
    """``bones`` ({name: ...}) under the names of ``names`` that they match: by name, else by ``bone_key`` where
    one bone alone has that key; the others under their own names."""
    from ..garment_transfer import bone_key

    by_key = {}
    for name in bones:
        by_key.setdefault(bone_key(name), []).append(name)
    out = dict(bones)
    for name in names:
        if name not in bones and len(by_key.get(bone_key(name), [])) == 1:
            out[name] = bones[by_key[bone_key(name)][0]]
    return out


def rest_pose_rigs(source_body, target_body, depsgraph, evaluated, n_vertices, frame, model=None):
    """What a transfer needs to pose the source body into the target's rest pose (the core's
    ``transfer_across_rest_poses``): both bodies have an armature (an Armature modifier) whose bones carry the
    source's vertex groups, with the same names (or the same but for a namespace and case: ``bone_key``); or
    skeletons named in two of the ways the core knows (MakeHuman's, Mixamo's, Rigify's, Unreal's: ``NAMINGS``),
    matched by the joints a body bends at (the core's ``Landmarks``).

    Parameters
    ----------
    source_body, target_body : bpy.types.Object
    depsgraph : bpy.types.Depsgraph
    evaluated : bool
        The bodies read as posed now (else at rest, without modifiers).
    n_vertices : int
        The source body's vertices as read: its vertex groups must name the same ones.
    frame : (3,3) float
        The rotation from world space to the frame the bodies are given to the core in.
    model : optional
        The model the transfer uses: none is posed (it is trained on the source's pose).

    Returns
    -------
    rigs : (source Rig, target joints or Landmarks, target frames or None) or None
        None where the rest poses cannot be matched bone by bone or by landmarks.
    why_not : str
        Without rigs, what would give them, in a few words (for the error if the poses then differ); "" with them.
    """
    from ..garment_transfer import landmarks_of, naming_of, rig_from_bones

    if model is not None:
        return None, "use the Direct method: a model is trained on the source's pose"
    source_armature, target_armature = body_armature(source_body), body_armature(target_body)
    if source_armature is None or target_armature is None:
        return None, ("give both bodies an Armature modifier, with the same bones, to pose the source into the "
                      "target's rest pose")
    bones = armature_bones(source_armature, depsgraph, evaluated)
    groups = {g.name for g in source_body.vertex_groups} & {b for b in deform_bones(source_armature)}
    if not groups:
        return None, (f"give {source_body.name} vertex groups named as the bones of {source_armature.name} to "
                      "pose it into the target's rest pose")
    needed = set()
    for name in groups:
        while name is not None and name not in needed:
            needed.add(name)
            name = bones[name][0]
    target_bones = armature_bones(target_armature, depsgraph, evaluated)
    target = matched_bones(target_bones, needed)
    missing = sorted(needed - set(target))
    # Named otherwise: matched by the joints a body bends at, where both namings are known.
    by_landmarks = bool(missing) and naming_of(bones) is not None and naming_of(target_bones) is not None
    if missing and not by_landmarks:
        return None, (f"give {target_armature.name} the bones of {source_armature.name} that move "
                      f"{source_body.name}: it lacks {len(missing)} (first: {', '.join(missing[:3])}), or a "
                      "skeleton named as MakeHuman's, Mixamo's, Rigify's or Unreal's, like the source's")
    if len(source_body.data.vertices) != n_vertices:
        return None, (f"turn off Use Modifiers and Shape Keys: a modifier of {source_body.name} changes its "
                      f"vertex count ({len(source_body.data.vertices)} to {n_vertices}), so its vertex groups "
                      "cannot pose it")
    # By landmarks, every bone of the source's naming (the landmarks' included), not only those its vertex groups
    # need.
    names = [b for b in bones if by_landmarks or b in needed]
    rig = rig_from_bones({b: (bones[b][0], bones[b][1] @ frame.T, bones[b][2] @ frame.T, frame @ bones[b][3])
                          for b in names}, vertex_group_weights(source_body, sorted(groups)), source_armature.name)
    if by_landmarks:
        landmarks = landmarks_of({b: (p, h @ frame.T, t @ frame.T) for b, (p, h, t, _) in target_bones.items()},
                                 target_armature.name)
        return (rig, landmarks, None), ""
    joints = {}
    for b in names:
        joints[f"{b} head"] = target[b][1] @ frame.T
        joints[f"{b} tail"] = target[b][2] @ frame.T
    frames = np.array([frame @ target[b][3] for b in rig.skeleton.names])
    return (rig, joints, frames), ""


def skeletons_text(pose):
    """How the two skeletons were matched, where not by the bones' names (``info["rest_pose"]["skeletons"]``)."""
    matched = pose.get("skeletons") or {}
    if matched.get("by") != "landmarks":
        return ""
    return f"; the {matched['target']} skeleton matched by {matched['segments']} segments"


def write_vertex_groups(obj, weights):
    """Every group of ``weights`` (core SkinWeights) as a vertex group of ``obj`` (made, or replaced)."""
    from ..garment_transfer import weights_to_dict

    for name, pairs in weights_to_dict(weights, digits=9).items():
        if not pairs:
            continue
        rows = np.array([p[0] for p in pairs], dtype=np.int64)
        vals = np.array([p[1] for p in pairs], dtype=np.float64)
        group = obj.vertex_groups.get(name)
        if group is not None:
            obj.vertex_groups.remove(group)
        group = obj.vertex_groups.new(name=name)
        # One call per distinct weight: vertex groups take a list of vertices and one weight.
        order = np.argsort(vals, kind="stable")
        values, starts = np.unique(vals[order], return_index=True)
        for k, value in enumerate(values):
            stop = starts[k + 1] if k + 1 < len(starts) else len(order)
            group.add(rows[order[starts[k]:stop]].tolist(), float(value), 'REPLACE')


def add_armature_modifier(obj, armature):
    """An Armature modifier on ``armature`` at the top of the stack (deform first, refine after)."""
    mod = obj.modifiers.new(name=ARMATURE_MODIFIER, type='ARMATURE')
    mod.object = armature
    mod.use_vertex_groups = True
    mod.use_bone_envelopes = False
    obj.modifiers.move(len(obj.modifiers) - 1, 0)
    return mod


def add_keep_outside(obj, body, distance, only=None, name=KEEP_OUTSIDE_MODIFIER):
    """A Shrinkwrap (Outside mode, nearest surface point) on ``body`` at the end of the stack (after any Armature
    modifier, so that posed cloth meets the posed body): it moves only the vertices inside the body or closer to
    it than ``distance`` (world units), out to that distance: what a pose or a mix of size keys clips
    (``shape_keys.keep_outside`` is the same rule). The live correction of playback and of size shape keys.

    Parameters
    ----------
    only : (g,) bool, optional
        The vertices it applies to: a vertex group ``<name>`` of weight 1 holding them (made, or replaced) limits
        the modifier (Blender's Shrinkwrap moves no vertex outside its group); default every vertex.
    """
    mod = obj.modifiers.new(name=name, type='SHRINKWRAP')
    mod.target = body
    mod.wrap_method = 'NEAREST_SURFACEPOINT'
    mod.wrap_mode = 'OUTSIDE'
    # The Shrinkwrap snaps in the target's space: its offset is in the body's own units.
    mod.offset = distance / float(np.mean(np.array(body.matrix_world.to_scale())))
    if only is not None:
        mod.vertex_group = write_share_group(obj, name, np.asarray(only, dtype=np.float64)).name
    return mod


def shrinkwrap_surface(body, V_world):
    """The body's surface at ``V_world`` (its vertices, world space) split into triangles as Blender splits its
    faces (its loop triangles): what a Shrinkwrap on it sees."""
    from ..garment_transfer import TriangleSurface

    return TriangleSurface(V_world, _loop_triangles(body.data))


def _loop_triangles(me):
    """(m,3) int64: a mesh's faces split into triangles as Blender splits them (its loop triangles)."""
    me.calc_loop_triangles()
    tris = np.empty(3 * len(me.loop_triangles), dtype=np.int64)
    me.loop_triangles.foreach_get("vertices", tris)
    return tris.reshape(-1, 3)


def evaluated_shrinkwrap_surface(body, depsgraph):
    """What a Shrinkwrap on ``body`` sees in ``depsgraph``: its evaluated mesh (every modifier, a Subdivision
    Surface included, and its shape keys) in world space, split into triangles as Blender splits its faces."""
    from ..garment_transfer import TriangleSurface

    ev = body.evaluated_get(depsgraph)
    me = ev.to_mesh()
    try:
        co = np.empty(3 * len(me.vertices), dtype=np.float32)
        me.vertices.foreach_get("co", co)
        tris = _loop_triangles(me)
    finally:
        ev.to_mesh_clear()
    M = convert.matrix_array(ev.matrix_world)
    return TriangleSurface(co.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3], tris)


def add_keep_outside_bands(obj, body, bands):
    """``add_keep_outside`` per band of ``shape_keys.keep_outside_bands`` (distance, vertices), in increasing
    order: ``KEEP_OUTSIDE_MODIFIER``, ``KEEP_OUTSIDE_MODIFIER 2``, ``3``..., each limited to a vertex group of the
    same name holding its vertices (none for a band of every vertex)."""
    mods = []
    for i, (distance, only) in enumerate(bands):
        only = np.asarray(only, dtype=bool)
        if not only.any():
            # Not even an empty group: on a mesh with no vertex in any group, Blender applies the modifier to all.
            continue
        name = KEEP_OUTSIDE_MODIFIER if i == 0 else f"{KEEP_OUTSIDE_MODIFIER} {i + 1}"
        mods.append(add_keep_outside(obj, body, distance, None if only.all() else only, name))
    return mods


def is_keep_outside(name):
    """Whether a modifier or vertex group name is one of ``add_keep_outside_bands``'s."""
    head, _, tail = name.partition(f"{KEEP_OUTSIDE_MODIFIER} ")
    return name == KEEP_OUTSIDE_MODIFIER or (not head and tail.isdigit())


def remove_keep_outside(obj):
    """The Keep Outside Body modifiers and their vertex groups taken off ``obj``."""
    for mod in [m for m in obj.modifiers if m.type == 'SHRINKWRAP' and is_keep_outside(m.name)]:
        obj.modifiers.remove(mod)
    for group in [g for g in obj.vertex_groups if is_keep_outside(g.name)]:
        obj.vertex_groups.remove(group)


def write_share_group(obj, name, share):
    """A vertex group ``name`` of ``obj`` (made, or replaced) with the per-vertex values ``share`` (p,) where
    they are above 0."""
    group = obj.vertex_groups.get(name)
    if group is not None:
        obj.vertex_groups.remove(group)
    group = obj.vertex_groups.new(name=name)
    share = np.round(np.asarray(share, dtype=np.float64), 4)
    for value in np.unique(share[share > 0]):
        group.add(np.flatnonzero(share == value).tolist(), float(value), 'REPLACE')
    return group


def add_surface_ride(context, obj, body, share=None):
    """A Surface Deform on the body, after the Armature modifier, bound as the body is now (the caller puts it at
    rest) and limited to the vertices that ride the skin (``share``, a vertex group): those follow the skinned
    surface itself, at their distance from it, the others the bones; without ``share``, every vertex follows the
    body's surface."""
    mod = obj.modifiers.new(name=RIDE_MODIFIER, type='SURFACE_DEFORM')
    mod.target = body
    if share is not None:
        write_share_group(obj, RIDE_GROUP, share)
        mod.vertex_group = RIDE_GROUP
    # Bound only where the group weighs (a sparse bind binds nothing without a group).
    mod.use_sparse_bind = share is not None
    with context.temp_override(object=obj, active_object=obj):
        bpy.ops.object.surfacedeform_bind(modifier=mod.name)
    context.view_layer.update()
    obj.evaluated_get(context.evaluated_depsgraph_get())
    return mod


def rig_to_body(context, obj, body, *, max_influences=8, ride_surface=False, outside=KEEP_OUTSIDE_SHARE,
                hanging=True):
    """Give ``obj`` (a garment on ``body``, as modelled: the armature at rest) the body's bones as vertex
    groups, weighted by the core's ``inpainted_weights``, an Armature modifier and the live correction: with
    ``ride_surface``, a Surface Deform that carries the cloth lying on the skin with the skinned body's surface
    (``riding_share``), and Shrinkwraps (Outside) in bands up to ``outside`` times the transfer's cloth offset (0:
    none), each holding the vertices the cloth at rest holds that far; with ``hanging``, the cloth that hangs free
    (``riding_share`` 0) also in bands beyond it (``HANGING_BANDS``, times ``outside``). A body played by a cache
    modifier instead of an armature: ``follow_surface`` (armature None).

    Returns
    -------
    armature : bpy.types.Object
    info : dict
        The weight transfer's figures (``matched``, ``inpainted``, ``unweighted``, ``riding``, ``hanging``: the
        vertices kept out beyond the cloth offset, ``warnings``).

    Raises
    ------
    RigError
        The body's weights give none of the garment's vertices a weight (nothing is changed).
    """
    from ..garment_transfer import RigError, inpainted_weights, riding_share

    armature = body_armature(body)
    if armature is None:
        if body_caches(body):
            return None, follow_surface(context, obj, body, outside=outside, hanging=hanging)
        raise RigError(body.name, "has no Armature modifier with an armature to take bones from, nor a Mesh Cache or "
                                  "Mesh Sequence Cache modifier whose surface the cloth could follow")
    bones = deform_bones(armature)
    body_weights = vertex_group_weights(body, bones)
    if not body_weights.influences().any():
        raise RigError(body.name, f"has no vertex groups named as the bones of {armature.name}")
    with at_rest(body):
        depsgraph = context.evaluated_depsgraph_get()
        body_mesh = convert.core_mesh_from_object(body, depsgraph, False, "body")
        cloth = convert.core_mesh_from_object(obj, depsgraph, False, "garment")
        # The surface the Shrinkwraps keep the cloth outside of, at rest (a Subdivision Surface's, where the body
        # has one).
        surface = evaluated_shrinkwrap_surface(body, depsgraph)
    weights, info = inpainted_weights(body_mesh.V, body_mesh.F, body_weights, cloth.V, cloth.F,
                                      max_influences=max_influences, name=obj.name)
    if info["unweighted"] == len(cloth.V):
        # Weights that move nothing: refused before the garment is changed.
        raise RigError(body.name, info["warnings"][-1])
    write_vertex_groups(obj, weights)
    remove_keep_outside(obj)
    for mod in [m for m in obj.modifiers if m.type == 'ARMATURE' or m.name == RIDE_MODIFIER]:
        obj.modifiers.remove(mod)
    add_armature_modifier(obj, armature)
    info["riding"] = info["hanging"] = 0
    needed = ride_surface or (outside > 0 and hanging)
    share = riding_share(body_mesh.V, body_mesh.F, cloth.V, cloth.F) if needed else None
    if ride_surface:
        info["riding"] = int((share > 0).sum())
        if info["riding"]:
            with at_rest(body):
                mod = add_surface_ride(context, obj, body, share)
            if not mod.is_bound:
                raise RigError(obj.name, f"could not be bound to the surface of {body.name} (Surface Deform)")
    elif RIDE_GROUP in obj.vertex_groups:
        obj.vertex_groups.remove(obj.vertex_groups[RIDE_GROUP])
    info["hanging"] = keep_outside(obj, body, body_mesh, cloth, surface, share, outside, hanging)
    obj.data.update()
    return armature, info


def keep_outside(obj, body, body_mesh, cloth, surface, share, outside, hanging):
    """The Shrinkwraps (Outside) that keep the cloth outside the moving body (none when ``outside`` is 0): per
    vertex, in bands up to ``outside`` times the cloth offset, as far as the cloth at rest is held, so that they
    move nothing at rest (the crossing pass leaves some vertices nearer than the offset); with ``hanging``, the
    cloth that hangs free (``share`` 0) also in bands beyond it. Returns the number of vertices kept out beyond the
    cloth offset."""
    from ..garment_transfer import (HANGING_BANDS, KEEP_OUTSIDE_BANDS, OFFSET_SHARE, body_scale, hanging_bands,
                                    held_bands)

    if outside <= 0:
        return 0
    offset = OFFSET_SHARE * body_scale(body_mesh.V)
    bands = held_bands([(surface, cloth.V)], offset, [outside * b for b in KEEP_OUTSIDE_BANDS])
    kept = 0
    if hanging:
        # Beyond the cloth offset, only the cloth that hangs free: a skirt is pushed by the leg swung into it.
        free = hanging_bands(surface, cloth.V, offset, share <= 0, [outside * b for b in HANGING_BANDS])
        # The bands are nested: the first holds every vertex the others hold.
        kept = int(free[0][1].sum()) if free else 0
        bands += free
    add_keep_outside_bands(obj, body, bands)
    return kept


def follow_surface(context, obj, body, *, outside=KEEP_OUTSIDE_SHARE, hanging=True):
    """For a body whose animation plays from a file (``body_caches``: no bones to weight the cloth with): a Surface
    Deform on the body, bound with it at rest, that carries the whole garment with the body's surface as it plays,
    and the Shrinkwraps of ``keep_outside``; any Armature modifier and earlier correction of ``obj`` removed.

    Returns
    -------
    info : dict
        ``riding`` (every vertex), ``hanging``, and ``matched``, ``inpainted``, ``unweighted`` 0 (no weights),
        ``warnings`` (empty).

    Raises
    ------
    RigError
        Blender could not bind the Surface Deform (nothing is left of it)."""
    from ..garment_transfer import RigError, riding_share

    with at_rest(body):
        depsgraph = context.evaluated_depsgraph_get()
        body_mesh = convert.core_mesh_from_object(body, depsgraph, False, "body")
        cloth = convert.core_mesh_from_object(obj, depsgraph, False, "garment")
        surface = evaluated_shrinkwrap_surface(body, depsgraph)
        remove_keep_outside(obj)
        for mod in [m for m in obj.modifiers if m.type == 'ARMATURE' or m.name == RIDE_MODIFIER]:
            obj.modifiers.remove(mod)
        if RIDE_GROUP in obj.vertex_groups:
            obj.vertex_groups.remove(obj.vertex_groups[RIDE_GROUP])
        mod = add_surface_ride(context, obj, body)
        if not mod.is_bound:
            obj.modifiers.remove(mod)
            raise RigError(obj.name, f"could not be bound to the surface of {body.name} (Surface Deform)")
    share = riding_share(body_mesh.V, body_mesh.F, cloth.V, cloth.F) if outside > 0 and hanging else None
    info = {"matched": 0, "inpainted": 0, "unweighted": 0, "riding": cloth.n_vertices, "warnings": []}
    info["hanging"] = keep_outside(obj, body, body_mesh, cloth, surface, share, outside, hanging)
    obj.data.update()
    return info


def rest_and_posed(context, obj, body):
    """The garment's and the body's rest meshes and the body's posed positions at the current frame (world): at rest,
    the body's armature in its rest position and its cache modifiers hidden (``at_rest``)."""
    depsgraph = context.evaluated_depsgraph_get()
    posed = convert.core_mesh_from_object(body, depsgraph, True, "body")
    with at_rest(body):
        depsgraph = context.evaluated_depsgraph_get()
        rest = convert.core_mesh_from_object(body, depsgraph, True, "body")
    cloth = convert.core_mesh_from_object(obj, depsgraph, False, "garment")
    return rest, posed, cloth


def fitted_name(obj, frame):
    return f"{obj.name}_fitted_{frame}"


def fit_current_pose(context, obj, body, untangle=False):
    """The garment fitted to the body's pose at the current frame: a new object (the inputs unchanged); ``untangle``:
    where the fit made the cloth cross itself, undone (the core's ``untangle_fit``).

    Returns
    -------
    result : bpy.types.Object
    outcome : TransferResult
    """
    from ..garment_transfer import fit_to_pose, require_same_topology

    require_motion(body, "pose to fit to")
    rest, posed, cloth = rest_and_posed(context, obj, body)
    require_same_topology(rest, posed)
    frame = context.scene.frame_current
    outcome = fit_to_pose(rest, posed.V, cloth, name=f"frame {frame}", untangle=untangle)
    result = convert.new_result_object(obj, outcome.V, fitted_name(obj, frame), context.evaluated_depsgraph_get(),
                                       False, scene=context.scene, view_layer=context.view_layer)
    try:
        for mod in [m for m in result.modifiers if m.type in ('ARMATURE', 'SHRINKWRAP')]:
            result.modifiers.remove(mod)
        counts = measured_pose_counts(context, result, cloth, rest, posed, outcome, result.name)
    except BaseException:
        convert.remove_results([result])
        raise
    outcome.info.update(counts)
    result[FIGURES] = {k: v for k, v in counts.items() if k != "warnings"}
    return result, outcome


#: The custom property of a fitted or baked object that holds its figures, measured on it as Blender has it.
FIGURES = "garment_transfer_figures"


def measured_pose_counts(context, result, cloth, rest, posed, outcome, name):
    """The pose fit's figures (``posed_counts``) of the new object as Blender has it at the current frame
    (evaluated, in world space, its 32-bit coordinates), against the body as posed there; a refining modifier
    kept on it (Subdivision) is measured before it."""
    return _posed_counts(rest, cloth, outcome, name, posed, written_positions(context, result, cloth))


def written_positions(context, result, cloth):
    """The result object's vertices as Blender has it at the current frame (evaluated, world space); before a
    refining modifier (Subdivision) where it has one."""
    context.view_layer.update()
    depsgraph = context.evaluated_depsgraph_get()
    written = convert.core_mesh_from_object(result, depsgraph, True, "result")
    if written.n_vertices != cloth.n_vertices:
        written = convert.core_mesh_from_object(result, depsgraph, False, "result")
    return written.V


def _posed_counts(rest, cloth, outcome, name, posed, V):
    from ..garment_transfer import posed_counts

    # The posed body as the fit read it: the rest body's polygons (the same mesh) at the posed positions.
    return posed_counts(V, cloth, rest.with_vertices(posed.V, name=posed.name), float(outcome.info["offset"]),
                        rest_V=rest.V, name=name, contact=outcome.contact, free=outcome.obstacle,
                        surface=outcome.surface)


def bake_steps(context, obj, body, start, end, untangle=False):
    """Fit the garment to every frame from ``start`` to ``end``: a generator of fractions done; its value
    (``StopIteration.value``) is ``(frames, positions, fits, seconds)``, ``fits`` what ``measure_baked`` needs:
    the rest body, the garment, and per frame the posed body and the fit. The scene's frame is put back.

    Blender sets each frame and reads the posed body here, in this thread; the fits run a few frames at once in
    threads beside it (the core's ``fit_poses``). Closing the generator (a cancel) waits for the frames being
    fitted and drops the others."""
    from ..garment_transfer import MeshError, fit_poses, prepare_garment

    require_motion(body, "motion to bake")
    if end < start:
        raise MeshError(obj.name, f"the frame range {start} to {end} is empty")
    scene = context.scene
    frame_before = scene.frame_current
    frames = list(range(start, end + 1))
    t = time.perf_counter()
    posed_bodies = {}

    def posed_frames():
        for frame in frames:
            scene.frame_set(frame)
            posed = convert.core_mesh_from_object(body, context.evaluated_depsgraph_get(), True, "body")
            posed_bodies[frame] = posed
            yield frame, posed.V

    try:
        rest, _, cloth = rest_and_posed(context, obj, body)
        prepared = prepare_garment(rest, cloth)
        positions, fits = [], {"rest": rest, "garment": cloth, "frames": []}
        fitting = fit_poses(rest, posed_frames(), cloth, prepared=prepared, untangle=untangle)
        try:
            for i, (frame, outcome) in enumerate(fitting):
                positions.append(outcome.V)
                fits["frames"].append((posed_bodies.pop(frame), outcome))
                yield (i + 1) / len(frames)
        finally:
            fitting.close()
    finally:
        scene.frame_set(frame_before)
    return frames, positions, fits, time.perf_counter() - t


def measure_baked(context, baked, frames, fits):
    """The pose fit's figures of the baked object as Blender plays it back, frame by frame (evaluated, in world
    space), against the body posed at that frame: ``{"frames": [counts per frame], "warnings": [...]}``; also
    kept on the object (``FIGURES``). The scene's frame is put back. Blender plays each frame here; the counts
    run a few frames at once in threads (the core's ``in_threads``)."""
    from ..garment_transfer import in_threads

    scene = context.scene
    frame_before = scene.frame_current
    written = []
    try:
        for frame in frames:
            scene.frame_set(frame)
            written.append(written_positions(context, baked, fits["garment"]))
    finally:
        scene.frame_set(frame_before)

    def count(k):
        posed, outcome = fits["frames"][k]
        return _posed_counts(fits["rest"], fits["garment"], outcome, f"{baked.name} at frame {frames[k]}", posed,
                             written[k])

    rows, warnings = [], []
    for frame, counts in zip(frames, in_threads(count, list(range(len(frames))))):
        warnings += counts.pop("warnings")
        rows.append({"frame": frame, **counts})
    baked[FIGURES] = {"frames": len(rows),
                      "frames_with_crossings": sum(1 for r in rows if r["crossings_outside_contact"]),
                      "crossings_outside_contact": sum(r["crossings_outside_contact"] for r in rows),
                      "crossings_at_contact": sum(r["crossings_at_contact"] for r in rows),
                      "penetrating_vertices": sum(r["penetrating_vertices"] for r in rows),
                      "self_intersections_new": sum(r["self_intersections_new"] for r in rows)}
    return {"frames": rows, "warnings": warnings}


#: The Mesh Cache modifier Bake Pose Fit gives the object it makes.
CACHE_MODIFIER = "Pose Fit Cache"


def files_in_use():
    """Files the open .blend file reads: itself, its libraries, images, sounds, clips, fonts, volumes, caches,
    and the point caches of Mesh Cache modifiers other than Bake Pose Fit's own (a character's animation)."""
    paths = [bpy.data.filepath] if bpy.data.filepath else []
    for collection in (bpy.data.libraries, bpy.data.images, bpy.data.sounds, bpy.data.movieclips, bpy.data.fonts,
                       bpy.data.volumes, bpy.data.cache_files):
        for block in collection:
            path = getattr(block, "filepath", "")
            if path and not path.startswith("<"):
                paths.append(bpy.path.abspath(path, library=block.library))
    for obj in bpy.data.objects:
        for mod in obj.modifiers:
            if mod.type == 'MESH_CACHE' and mod.filepath and mod.name != CACHE_MODIFIER:
                paths.append(bpy.path.abspath(mod.filepath, library=obj.library))
    return paths


def bake_cache_path(path):
    """The absolute path of a bake's point cache, checked before the bake: a new file, or a point cache of an
    earlier bake to replace (PC2; MDD where it is named .mdd); never another kind of file, a file the .blend file
    reads (``files_in_use``: a character's point cache included), a folder or a link; its folder must exist and be
    writable."""
    from ..garment_transfer import OutputError, check_output, is_mdd, is_mdd_name, is_pc2

    full = bpy.path.abspath(path)
    if os.path.isfile(full) and not os.path.islink(full) and not (is_mdd(full) if is_mdd_name(full) else is_pc2(full)):
        kind = "an MDD" if is_mdd_name(full) else "a PC2"
        raise OutputError(full, f"is not {kind} point cache; refusing to replace it (choose a new .pc2 or .mdd file)")
    return check_output(full, files_in_use(), "Point Cache")


def baked_object(context, obj, frames, positions, cache=None):
    """A new object ``<garment>_baked``: a shape key per frame, each at 1 on its frame and 0 on the frames
    beside it (constant interpolation between keys is not needed: neighbours blend linearly); or, with ``cache``
    (a path), the frames written there as a PC2 file, or an MDD file where it is named .mdd (its times the frames'
    at the scene's frame rate), in the object's own coordinates, and a Mesh Cache modifier that plays it, its first
    sample at the first frame."""
    from ..garment_transfer import is_mdd_name, write_mdd, write_pc2

    result = convert.new_result_object(obj, positions[0], f"{obj.name}_baked", context.evaluated_depsgraph_get(),
                                       False, scene=context.scene, view_layer=context.view_layer)
    try:
        for mod in [m for m in result.modifiers if m.type in ('ARMATURE', 'SHRINKWRAP')]:
            result.modifiers.remove(mod)
        if cache is not None:
            local = np.stack([convert.local_from_world(V, result.matrix_world, obj.name) for V in positions])
            render = context.scene.render
            if is_mdd_name(cache):
                times = (np.asarray(frames, dtype=np.float64) - frames[0]) * render.fps_base / render.fps
                write_mdd(cache, local, times, inputs=files_in_use(), what="Point Cache")
            else:
                write_pc2(cache, local, start_frame=frames[0], inputs=files_in_use(), what="Point Cache")
            mod = result.modifiers.new(name=CACHE_MODIFIER, type='MESH_CACHE')
            mod.cache_format = 'MDD' if is_mdd_name(cache) else 'PC2'
            mod.filepath = cache
            mod.time_mode = 'FRAME'
            mod.play_mode = 'SCENE'
            mod.frame_start = frames[0]
            mod.interpolation = 'LINEAR'
            # First in the stack: a refining modifier kept on the result (Subdivision) refines the cached cloth.
            result.modifiers.move(len(result.modifiers) - 1, 0)
            result.data.update()
            return result
        result.shape_key_add(name="Basis", from_mix=False)
        for frame, V in zip(frames, positions):
            kb = result.shape_key_add(name=f"frame {frame}", from_mix=False)
            local = convert.local_from_world(V, result.matrix_world, obj.name)
            kb.data.foreach_set("co", local.astype(np.float32).ravel())
            for f, value in ((frame - 1, 0.0), (frame, 1.0), (frame + 1, 0.0)):
                kb.value = value
                kb.keyframe_insert("value", frame=f)
        result.data.update()
        return result
    except BaseException:
        convert.remove_results([result])
        raise


def make_armature(context, name, skeleton, joints_world):
    """An armature object from a core Skeleton placed by joints in world space: a bone per skeleton bone from
    its head joint to its tail joint, rolled so that its Z axis is the skeleton's (the roll plane's,
    ``bone_frames``); linked to the scene, at the world origin.

    Parameters
    ----------
    skeleton : Skeleton
    joints_world : dict of str to (3,) float

    Returns
    -------
    bpy.types.Object
    """
    from ..garment_transfer import bone_frames

    heads, tails = skeleton.rest(joints_world)
    frames = bone_frames(skeleton, joints_world)
    data = bpy.data.armatures.new(name)
    obj = bpy.data.objects.new(name, data)
    context.scene.collection.objects.link(obj)
    previous = context.view_layer.objects.active
    context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode='EDIT')
    try:
        shortest = 1e-4 * max(float(np.ptp(heads, axis=0).max()), 1e-9)
        bones = []
        for b, bone_name in enumerate(skeleton.names):
            bone = data.edit_bones.new(bone_name)
            bone.head = heads[b]
            # Blender drops a bone of no length: such a bone gets a tiny one along its frame.
            tail = tails[b] if np.linalg.norm(tails[b] - heads[b]) > shortest else heads[b] + shortest * frames[b][:, 1]
            bone.tail = tail
            bone.align_roll(frames[b][:, 2])
            if skeleton.parents[b] >= 0:
                bone.parent = bones[skeleton.parents[b]]
            bones.append(bone)
    finally:
        bpy.ops.object.mode_set(mode='OBJECT')
        context.view_layer.objects.active = previous
    return obj


def pose_armature(armature, skeleton, transforms):
    """Pose an armature made by ``make_armature`` (at the world origin) by the core's skinning transforms
    (``pose_transforms``, (b,3,4), world space): each pose bone's basis is ``Rest^-1 T_parent^-1 T Rest``."""
    def full(T):
        out = np.eye(4)
        out[:3, :] = T
        return out

    T = [full(t) for t in np.asarray(transforms, dtype=np.float64)]
    for b, name in enumerate(skeleton.names):
        bone = armature.data.bones[name]
        rest = convert.matrix_array(bone.matrix_local)
        parent = skeleton.parents[b]
        relative = T[b] if parent < 0 else np.linalg.solve(T[parent], T[b])
        basis = np.linalg.solve(rest, relative @ rest)
        armature.pose.bones[name].matrix_basis = Matrix(basis.tolist())


def _poll_rigged(cls, context):
    return poll_objects(cls, context, lambda s: (("the target body", s.target_body), ("a result", s.result)))


class GARMENT_TRANSFER_OT_rig_garment(bpy.types.Operator):
    """Give the result the target body's bones as vertex groups (matched where the cloth lies on the skin,
    filled smoothly elsewhere), an Armature modifier and a Shrinkwrap that keeps it outside: it follows the
    character"""

    bl_idname = "garment_transfer.rig_garment"
    bl_label = "Rig to Body"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        return _poll_rigged(cls, context)

    def execute(self, context):
        settings = context.scene.garment_transfer
        try:
            armature, info = rig_to_body(context, settings.result, settings.target_body,
                                         max_influences=settings.max_influences,
                                         ride_surface=settings.ride_surface)
        except Exception as exc:
            return report_failure(self, exc)
        if armature is None:
            self.report({'INFO'}, f"{settings.result.name}: follows the surface of {settings.target_body.name} as its "
                                  f"cache plays it (Surface Deform; {info['hanging']} hanging free kept as far out "
                                  f"as at rest)")
        else:
            self.report({'INFO'}, f"{settings.result.name}: rigged to {armature.name} ({info['matched']} vertices "
                                  f"matched the body, {info['inpainted']} inpainted, at most "
                                  f"{settings.max_influences} bones each; {info['hanging']} hanging free kept as far "
                                  f"out as at rest)")
        for warning in info["warnings"]:
            self.report({'WARNING'}, warning)
        return {'FINISHED'}


UNTANGLE_TEXT = ("Undo where the fit makes the cloth cross itself (the lap sitting, under the arms) without crossing "
                 "the body more: seconds more a frame where it does")


class GARMENT_TRANSFER_OT_fit_pose(bpy.types.Operator):
    """Fit the result to the target body's pose at the current frame, keeping its folds and the body inside:
    a new object <result>_fitted_<frame>"""

    bl_idname = "garment_transfer.fit_pose"
    bl_label = "Fit to Pose"
    bl_options = {'REGISTER', 'UNDO'}

    untangle: BoolProperty(name="Untangle", default=False, description=UNTANGLE_TEXT)

    @classmethod
    def poll(cls, context):
        return _poll_rigged(cls, context)

    def execute(self, context):
        settings = context.scene.garment_transfer
        start = time.perf_counter()
        try:
            result, outcome = fit_current_pose(context, settings.result, settings.target_body, self.untangle)
        except Exception as exc:
            return report_failure(self, exc)
        info = outcome.info
        untangled = info.get("untangle")
        self.report({'INFO'}, f"{result.name}: {info['crossings_outside_contact']} crossings with the body, "
                              f"{info['crossings_at_contact']} where it crosses itself; the cloth crosses itself "
                              f"at {info['self_intersections_new']} pairs beyond its rest shape's"
                              + (f" (untangled from {untangled['self_intersections_new_before']})"
                                 if untangled and untangled["kept"] else "")
                              + ("" if self.untangle or not info["self_intersections_new"] else
                                 " (Untangle undoes it where it can)")
                              + f"; {time.perf_counter() - start:.2f} s")
        for warning in info["warnings"]:
            self.report({'WARNING'}, warning)
        return {'FINISHED'}


class GARMENT_TRANSFER_OT_bake_pose_fit(ModalSteps, bpy.types.Operator):
    """Fit the result to the target body's pose at every frame of a range: a new object <result>_baked with
    a shape key per frame, keyed to play back exactly, or played from a PC2 point cache by a Mesh Cache modifier"""

    bl_idname = "garment_transfer.bake_pose_fit"
    bl_label = "Bake Pose Fit"
    bl_options = {'REGISTER', 'UNDO'}

    frame_start: IntProperty(name="Start", default=1, description="First frame to bake")
    frame_end: IntProperty(name="End", default=0, description="Last frame to bake (0: the scene's end)")
    cache_file: StringProperty(name="Point Cache", subtype='FILE_PATH', default="",
                               description="PC2 file (or MDD, named .mdd) to bake into (a Mesh Cache modifier "
                                           "plays it); empty: shape keys")
    untangle: BoolProperty(name="Untangle", default=False, description=UNTANGLE_TEXT)

    status_text = "Baking the pose fit"
    cancel_text = "Pose fit bake cancelled; nothing was made"
    timer_seconds = 0.01
    _steps = None

    @classmethod
    def poll(cls, context):
        return _poll_rigged(cls, context)

    def _start(self, context):
        settings = context.scene.garment_transfer
        end = self.frame_end or context.scene.frame_end
        self._cache = bake_cache_path(self.cache_file) if self.cache_file else None
        self._began = time.perf_counter()
        self._steps = bake_steps(context, settings.result, settings.target_body, self.frame_start, end, self.untangle)

    def _finish(self, context, outcome):
        frames, positions, fits, seconds = outcome
        settings = context.scene.garment_transfer
        result = None
        try:
            result = baked_object(context, settings.result, frames, positions, self._cache)
            measured = measure_baked(context, result, frames, fits)
        except Exception as exc:
            if result is not None:
                convert.remove_results([result])
            return report_failure(self, exc)
        figures = result[FIGURES]
        self.report({'INFO'}, f"{result.name}: {len(frames)} frames fitted in {seconds:.1f} s "
                              f"({seconds / len(frames):.2f} s a frame); as played back, "
                              f"{figures['frames_with_crossings']} frames cross the body away from its own contact; "
                              f"the cloth crosses itself at {figures['self_intersections_new']} pairs beyond its rest "
                              f"shape's over the frames"
                              + ("" if self.untangle or not figures["self_intersections_new"] else
                                 " (Untangle undoes it where it can)"))
        if measured["warnings"]:
            self.report({'WARNING'}, f"{len(measured['warnings'])} warnings; the first: {measured['warnings'][0]}")
        return {'FINISHED'}

    def execute(self, context):
        try:
            self._start(context)
            while True:
                try:
                    next(self._steps)
                except StopIteration as stop:
                    outcome = stop.value
                    break
        except Exception as exc:
            return report_failure(self, exc)
        return self._finish(context, outcome)


CLASSES = (GARMENT_TRANSFER_OT_rig_garment, GARMENT_TRANSFER_OT_fit_pose, GARMENT_TRANSFER_OT_bake_pose_fit)
