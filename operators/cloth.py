"""Drape a garment with Blender's cloth solver: on the source body, then while the body morphs
into each target body. Pure functions on arrays; the objects they need live only during the call.
"""

from __future__ import annotations

import logging
import time

import bpy
import numpy as np

from ..garment_transfer import Cancelled, MeshError

log = logging.getLogger(__name__)

# Cloth thickness kept between garment and body in the result, and the solver's collision distance.
THICKNESS = 0.004
COLLISION_DISTANCE = 0.006
# A garment must start at least this far outside the body (the solver cannot untangle one inside).
START_CLEARANCE = 0.010
PIN_GROUP = "gt_pin"
# Cloth settings: a light, slightly stretchy fabric, damped by the air so that it settles in a few
# dozen frames, and sliding over the body (low friction) instead of bunching up as the body grows.
CLOTH_SETTINGS = {"mass": 0.25, "air_damping": 3.0, "tension_stiffness": 6.0, "compression_stiffness": 6.0,
                  "shear_stiffness": 4.0, "bending_stiffness": 0.2, "pin_stiffness": 2.0}
COLLISION_QUALITY = 2
BODY_FRICTION = 1.0


def drape_garment(garment_V, garment_polys, body_V, body_F, target_body_Vs=(), pin_group=None,
                  frames=30, morph_frames=None, source_frames=None, progress=None, report=None, quality=5,
                  cloth_settings=None, continuous=False):
    """Settle a garment on the source body, then follow the body into each target shape.

    Parameters
    ----------
    garment_V : (n,3) float
        Garment vertices (world space, metres).
    garment_polys : (p,k) int array or list of index sequences
        Garment polygons.
    body_V : (b,3) float
        Source body vertices.
    body_F : (f,3) int
        Body triangles (closed mesh).
    target_body_Vs : sequence of (b,3) float
        Target bodies of the source body's topology.
    pin_group : (k,) int or None
        Garment vertices held in place (waistband, shoulders); pinned vertices follow the body as it
        morphs. None: nothing pinned.
    frames : int
        Frames to settle after each morph.
    morph_frames : int or None
        Frames over which the body morphs into a target (default: ``frames``).
    source_frames : int or None
        Frames to settle on the source body (default: twice ``frames``: the garment starts in its
        unsettled, made-up shape).
    progress : callable or None
        ``progress(fraction) -> bool``; returning True cancels (raises Cancelled).
    report : list or None
        If given, one dict per simulation is appended: ``body`` (index, -1 for the source),
        ``seconds``, ``inside_before`` and ``inside_after`` the penetration fix, ``max_depth``.
    quality : int
        Solver steps per frame.
    cloth_settings : dict or None
        Overrides of ``CLOTH_SETTINGS`` (attributes of Blender's ClothSettings).
    continuous : bool
        False: each target run starts from the garment settled on the source body (the source settling
        is simulated once). Restarting a settled garment moves it even where the body does not change
        (its hanging parts sag further; 1.8 mm on average for a MakeHuman suit, its legs 3-3.5 mm), so a
        target's result differs from the source's by more than the body's change. True: each target run
        is one simulation from the start: ``source_frames`` on the source body, then the morph and the
        settling, with no restart between; the source result is that run's state before the morph (the
        same simulation), so the two differ only by what the morph did. Costs ``source_frames`` more
        frames per target.

    Returns
    -------
    list of (n,3) float64
        The garment settled on the source body, then on each target body (same vertex order).
    """
    from ..garment_transfer import TriangleSurface, fix_penetration

    gV = _array(garment_V, "garment vertices")
    bV = _array(body_V, "body vertices")
    bF = np.asarray(body_F, dtype=np.int64)
    targets = [_array(t, f"target body {i}") for i, t in enumerate(target_body_Vs)]
    for i, t in enumerate(targets):
        if t.shape != bV.shape:
            raise MeshError(f"target body {i}",
                            f"has {t.shape[0]} vertices; the source body has {bV.shape[0]}")
    polys = [list(map(int, p)) for p in garment_polys]
    pins = np.zeros(0, np.int64) if pin_group is None else np.unique(np.asarray(pin_group, np.int64))
    if pins.size and (pins.min() < 0 or pins.max() >= gV.shape[0]):
        raise MeshError("pin group", f"refers to vertices outside 0..{gV.shape[0] - 1}")
    morph_frames = frames if morph_frames is None else morph_frames
    source_frames = 2 * frames if source_frames is None else source_frames
    settings = dict(CLOTH_SETTINGS, **(cloth_settings or {}))
    tri = _triangles(polys)
    runs = 1 + len(targets)

    def step_progress(run):
        if progress is None:
            return None
        return lambda f: progress((run + f) / runs)

    scene = bpy.context.scene
    saved = _SceneState(scene)
    try:
        source_surface = TriangleSurface(bV, bF)
        start, _ = fix_penetration(gV, tri, source_surface, START_CLEARANCE)
        settled = _simulate(scene, start, polys, pins, bV, bF, None, source_frames, 0, quality,
                            settings, step_progress(0), start)
        results = [_finish(settled, tri, source_surface, -1, report)]
        for i, tV in enumerate(targets):
            if continuous:
                # From the start again: the source settling, then the morph, in one run.
                out = _simulate(scene, start, polys, pins, bV, bF, tV, frames, morph_frames, quality,
                                settings, step_progress(1 + i), _pins_following_body(start, pins, bV, tV),
                                rest=start, hold=source_frames)
            else:
                follow = _pins_following_body(results[0], pins, bV, tV)
                out = _simulate(scene, results[0], polys, pins, bV, bF, tV, frames, morph_frames, quality,
                                settings, step_progress(1 + i), follow, rest=start)
            results.append(_finish(out, tri, TriangleSurface(tV, bF), i, report))
        return results
    finally:
        saved.restore()


def _array(X, name):
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise MeshError(name, f"expected shape (n, 3), got {X.shape}")
    if not np.all(np.isfinite(X)):
        raise MeshError(name, "contain NaN or infinite coordinates")
    return X


def _triangles(polys):
    tris = [(p[0], p[i], p[i + 1]) for p in polys for i in range(1, len(p) - 1)]
    return np.asarray(tris, dtype=np.int64)


def _pins_following_body(G, pins, bV, tV):
    """Pinned garment vertices moved with the body under them (displacement of the nearest body vertex)."""
    from ..garment_transfer import follow_nearest_vertex

    follow = G.copy()
    follow[pins] = follow_nearest_vertex(G[pins], bV, tV)
    return follow


def _finish(V, tri, surface, body_index, report):
    from ..garment_transfer import fix_penetration

    t = time.perf_counter()
    sd = surface.signed_distance(V)[0]
    fixed, info = fix_penetration(V, tri, surface, THICKNESS)
    entry = {"body": body_index, "inside_before": info["inside_before"],
             "inside_after": info["inside_after"],
             "max_depth": float(max(0.0, -sd.min())), "fix_seconds": time.perf_counter() - t}
    log.info("drape on body %d: %d vertices inside before the fix, %d after (deepest %.4f m)",
             body_index, entry["inside_before"], entry["inside_after"], entry["max_depth"])
    if report is not None:
        report.append(entry)
    return fixed


class _SceneState:
    """What the drape changes in the scene, put back afterwards: the frame range and current frame,
    the selection and active object, and every datablock the drape created."""

    def __init__(self, scene):
        self.scene = scene
        self.frame = scene.frame_current
        self.frame_start, self.frame_end = scene.frame_start, scene.frame_end
        self.objects = set(bpy.data.objects)
        self.meshes = set(bpy.data.meshes)
        self.actions = set(bpy.data.actions)
        self.keys = set(bpy.data.shape_keys)

    def restore(self):
        for ob in [o for o in bpy.data.objects if o not in self.objects]:
            bpy.data.objects.remove(ob, do_unlink=True)
        for me in [m for m in bpy.data.meshes if m not in self.meshes]:
            bpy.data.meshes.remove(me, do_unlink=True)
        for ac in [a for a in bpy.data.actions if a not in self.actions]:
            bpy.data.actions.remove(ac, do_unlink=True)
        self.scene.frame_start, self.scene.frame_end = self.frame_start, self.frame_end
        self.scene.frame_set(self.frame)


def _new_object(scene, name, V, polys):
    me = bpy.data.meshes.new(name)
    me.from_pydata(V.tolist(), [], polys)
    me.update()
    ob = bpy.data.objects.new(name, me)
    scene.collection.objects.link(ob)
    return ob


def _animate_key(key_block, frame0, frame1):
    key_block.value = 0.0
    key_block.keyframe_insert("value", frame=frame0)
    key_block.value = 1.0
    key_block.keyframe_insert("value", frame=frame1)


def _simulate(scene, start, polys, pins, bV, bF, tV, frames, morph_frames, quality, settings, progress,
              follow, rest=None, hold=0):
    """One cloth run: the garment starts at ``start``; after ``hold`` frames on bV the body morphs from bV
    to tV (if given) over ``morph_frames`` and holds; pinned vertices move from ``start`` to ``follow``
    meanwhile."""
    t0 = time.perf_counter()
    last = 1 + hold + morph_frames + frames
    body = _new_object(scene, "gt_drape_body", bV, bF.tolist())
    cloth_ob = _new_object(scene, "gt_drape_garment", start if rest is None else rest, polys)
    try:
        if tV is not None:
            body.shape_key_add(name="Basis", from_mix=False)
            kb = body.shape_key_add(name="target", from_mix=False)
            kb.data.foreach_set("co", tV.astype(np.float32).ravel())
            _animate_key(kb, 1 + hold, 1 + hold + morph_frames)
        col = body.modifiers.new("Collision", 'COLLISION')
        del col
        cs = body.collision
        cs.thickness_outer = COLLISION_DISTANCE
        cs.cloth_friction = BODY_FRICTION
        cs.use_culling = True

        if rest is not None:
            # The garment's rest shape stays the unsimulated one; it starts where it settled.
            cloth_ob.shape_key_add(name="Basis", from_mix=False)
            k_start = cloth_ob.shape_key_add(name="start", from_mix=False)
            k_start.data.foreach_set("co", start.astype(np.float32).ravel())
            k_start.value = 1.0
            k_follow = cloth_ob.shape_key_add(name="follow", from_mix=False)
            k_follow.data.foreach_set("co", follow.astype(np.float32).ravel())
            k_follow.relative_key = k_start
            _animate_key(k_follow, 1 + hold, 1 + hold + morph_frames)
        if pins.size:
            vg = cloth_ob.vertex_groups.new(name=PIN_GROUP)
            vg.add(pins.tolist(), 1.0, 'REPLACE')
        mod = cloth_ob.modifiers.new("Cloth", 'CLOTH')
        st = mod.settings
        st.quality = quality
        for key, value in settings.items():
            setattr(st, key, value)
        if pins.size:
            st.vertex_group_mass = PIN_GROUP
        if rest is not None:
            st.rest_shape_key = cloth_ob.data.shape_keys.key_blocks["Basis"]
        cset = mod.collision_settings
        cset.distance_min = COLLISION_DISTANCE
        cset.use_self_collision = False
        cset.collision_quality = COLLISION_QUALITY
        cache = mod.point_cache
        cache.frame_start = 1
        cache.frame_end = last
        scene.frame_start, scene.frame_end = 1, last
        # The cloth cache needs every frame in order from its start.
        for f in range(1, last + 1):
            scene.frame_set(f)
            if progress is not None and progress(f / last):
                raise Cancelled("draping cancelled")
        dg = bpy.context.evaluated_depsgraph_get()
        ev = cloth_ob.evaluated_get(dg)
        me = ev.to_mesh()
        try:
            co = np.empty(len(me.vertices) * 3, np.float64)
            me.vertices.foreach_get("co", co)
        finally:
            ev.to_mesh_clear()
        co = co.reshape(-1, 3)
        M = np.array(cloth_ob.matrix_world)
        co = co @ M[:3, :3].T + M[:3, 3]
        if co.shape[0] != start.shape[0]:
            raise MeshError("garment", "the cloth solver changed the vertex count")
        log.info("cloth run: %d frames in %.1f s", last, time.perf_counter() - t0)
        return co
    finally:
        for ob in (cloth_ob, body):
            me = ob.data
            bpy.data.objects.remove(ob, do_unlink=True)
            bpy.data.meshes.remove(me, do_unlink=True)
