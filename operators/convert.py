"""Blender objects to core arrays and back: the only place that moves mesh data in bulk.

Which state of an object is used (the same rule for bodies, garments and results):

- ``evaluated=True`` (the default, "Use Modifiers and Shape Keys" in the panel): the object as the
  viewport shows it at the current frame, modifiers, shape keys and cloth simulation included.
- ``evaluated=False``: the object's own mesh data, without modifiers; with shape keys, the basis
  shape.

Positions always go through the object's ``matrix_world``: the core works in world space. A
transform with a negative determinant (a negative scale on the object or a parent: the usual way to
mirror a character) mirrors the mesh, which turns its faces inside out in world space; their vertex
order is then reversed (``reverse_polygons``) so that world-space faces keep pointing outward.
"""

from __future__ import annotations

import bpy
import numpy as np

from ..garment_transfer import MeshError

# Modifiers that only refine a surface that is already in place. In the base-mesh mode a result keeps
# these (they act on the transferred positions); anything else, and every modifier in the evaluated
# mode (already applied), is dropped so that nothing moves the result again.
REFINING_MODIFIERS = frozenset({
    "SUBSURF", "SOLIDIFY", "WEIGHTED_NORMAL", "EDGE_SPLIT", "BEVEL", "TRIANGULATE",
})


def require_mesh_object(obj, role):
    """Raise MeshError unless ``obj`` is a mesh object; ``role`` names it in the message."""
    if obj is None:
        raise MeshError(role, "no object chosen")
    if obj.type != 'MESH':
        kind = obj.type.lower().replace("_", " ")
        article = "an" if kind[0] in "aeiou" else "a"
        raise MeshError(obj.name, f"is {article} {kind} object; the {role} must be a mesh")


def matrix_array(matrix):
    """(4,4) float64 array of a mathutils.Matrix."""
    return np.array(matrix, dtype=np.float64).reshape(4, 4)


def _read_mesh_data(me):
    n = len(me.vertices)
    co = np.empty(n * 3, dtype=np.float32)
    me.vertices.foreach_get("co", co)
    p = len(me.polygons)
    loop_start = np.empty(p, dtype=np.int32)
    loop_total = np.empty(p, dtype=np.int32)
    me.polygons.foreach_get("loop_start", loop_start)
    me.polygons.foreach_get("loop_total", loop_total)
    corner_vert = np.empty(len(me.loops), dtype=np.int32)
    me.loops.foreach_get("vertex_index", corner_vert)
    face_start = np.zeros(p + 1, dtype=np.int64)
    np.cumsum(loop_total, out=face_start[1:])
    if np.array_equal(face_start[:-1], loop_start):
        face_vertices = corner_vert.astype(np.int64)
    else:
        # Blender stores face corners contiguously, but do not rely on it.
        idx = np.repeat(loop_start - face_start[:-1], loop_total) + np.arange(face_start[-1])
        face_vertices = corner_vert[idx].astype(np.int64)
    return co.reshape(n, 3).astype(np.float64), face_vertices, face_start


def mesh_arrays_from_object(obj, depsgraph, evaluated=True):
    """World-space vertices and polygons of a mesh object.

    Parameters
    ----------
    obj : bpy.types.Object
        A mesh object.
    depsgraph : bpy.types.Depsgraph
        Used when ``evaluated`` is True.
    evaluated : bool
        True: modifiers and shape keys applied; False: the base mesh.

    Returns
    -------
    V : (n,3) float64
        Vertex positions in world space.
    face_vertices : (k,) int64
        Vertex indices of the polygons, concatenated.
    face_start : (p+1,) int64
        Polygon j uses ``face_vertices[face_start[j]:face_start[j+1]]``.
    """
    require_mesh_object(obj, "object")
    if evaluated:
        obj_eval = obj.evaluated_get(depsgraph)
        me = obj_eval.to_mesh()
        try:
            V, fv, fs = _read_mesh_data(me)
        finally:
            obj_eval.to_mesh_clear()
        M = matrix_array(obj_eval.matrix_world)
    else:
        V, fv, fs = _read_mesh_data(obj.data)
        M = matrix_array(obj.matrix_world)
    if np.linalg.det(M[:3, :3]) < 0:
        fv = reverse_polygons(fv, fs)
    with np.errstate(invalid="ignore", over="ignore"):
        # NaN/inf coordinates pass through; core_mesh_from_object reports them.
        return V @ M[:3, :3].T + M[:3, 3], fv, fs


def reverse_polygons(face_vertices, face_start):
    """The polygons with their vertex order reversed (first corner kept): ``[a, b, c, d]`` becomes
    ``[a, d, c, b]``.

    Parameters
    ----------
    face_vertices : (k,) int
    face_start : (p+1,) int

    Returns
    -------
    (k,) int64
    """
    fv = np.asarray(face_vertices, dtype=np.int64)
    fs = np.asarray(face_start, dtype=np.int64)
    sizes = np.diff(fs)
    start = np.repeat(fs[:-1], sizes)
    local = np.arange(fs[-1]) - start
    turned = np.where(local == 0, 0, np.repeat(sizes, sizes) - local)
    return fv[start + turned]


def core_mesh_from_object(obj, depsgraph, evaluated=True, role="mesh"):
    """A core Mesh (world space, named after the object) of a mesh object.

    Raises
    ------
    MeshError
        Naming the object: not a mesh, no vertices or faces, NaN/inf coordinates.
    """
    from ..garment_transfer import mesh_from_polygons

    require_mesh_object(obj, role)
    V, fv, fs = mesh_arrays_from_object(obj, depsgraph, evaluated)
    if V.shape[0] == 0 or fs.shape[0] <= 1:
        what = "vertices" if V.shape[0] == 0 else "faces"
        raise MeshError(obj.name, f"the {role} has no {what}")
    sizes = np.diff(fs)
    if np.all(sizes == sizes[0]):
        polygons = fv.reshape(-1, int(sizes[0]))
    else:
        polygons = np.split(fv, fs[1:-1])
    return mesh_from_polygons(V, polygons, name=obj.name)


#: Modifiers that add faces to smooth a surface: an object with them, followed only by those of
#: ``AFTER_SUBDIVIDING``, has a cage, its mesh without them.
SUBDIVIDING_MODIFIERS = frozenset({"SUBSURF", "MULTIRES"})
#: What may follow a subdividing modifier and leave the mesh it subdivides the cage: the refining modifiers (hidden
#: with it) and an Armature (kept: it poses the cage's vertices by the same weights; a Multiresolution is first in
#: the stack of a sculpted character, before its Armature).
AFTER_SUBDIVIDING = REFINING_MODIFIERS | {"ARMATURE"}


def cage_mesh_from_object(obj, context, role="mesh", surface=None):
    """The object as the viewport shows it without its Subdivision Surface and Multiresolution modifiers, where
    nothing but refining modifiers and an Armature follows them (the mesh they subdivide, posed and shaped by
    everything else), or None where its stack is not so. Those modifiers and the refining ones among them are
    hidden while it is read and shown again. A Multiresolution's sculpted detail may take the surface far from the
    mesh it subdivides: with one, the cage is given only where ``surface`` (the object as shown, a core Mesh) lies
    on it (the core's ``lies_on_cage``); else None, another surface (registered)."""
    from ..garment_transfer import lies_on_cage

    hidden = []
    for mod in reversed(obj.modifiers):
        if not mod.show_viewport or mod.type == 'ARMATURE':
            continue
        if mod.type not in AFTER_SUBDIVIDING | SUBDIVIDING_MODIFIERS:
            break
        hidden.append(mod)
    if not any(mod.type in SUBDIVIDING_MODIFIERS for mod in hidden):
        return None
    try:
        for mod in hidden:
            mod.show_viewport = False
        context.view_layer.update()
        cage = core_mesh_from_object(obj, context.evaluated_depsgraph_get(), True, role)
    finally:
        for mod in hidden:
            mod.show_viewport = True
        context.view_layer.update()
    if surface is not None and any(mod.type == 'MULTIRES' for mod in hidden) and not lies_on_cage(surface, cage):
        return None
    return cage


def local_from_world(V_world, matrix_world, name):
    """Object-space positions of world-space ones, for an object with ``matrix_world``."""
    M = matrix_array(matrix_world)
    if abs(np.linalg.det(M[:3, :3])) < 1e-20:
        raise MeshError(name, "its transform has zero scale; apply or fix the scale first")
    Minv = np.linalg.inv(M)
    return np.asarray(V_world, dtype=np.float64) @ Minv[:3, :3].T + Minv[:3, 3]


def write_positions(me, V_local):
    """Write (n,3) object-space positions into mesh data ``me`` (fast path, then update)."""
    V_local = np.asarray(V_local)
    if V_local.shape != (len(me.vertices), 3):
        raise MeshError(me.name, f"cannot write {V_local.shape[0]} positions into a mesh of "
                                 f"{len(me.vertices)} vertices")
    me.vertices.foreach_set("co", np.ascontiguousarray(V_local, dtype=np.float32).reshape(-1))
    me.update()


def _result_mesh_data(garment, depsgraph, evaluated):
    if evaluated:
        obj_eval = garment.evaluated_get(depsgraph)
        return bpy.data.meshes.new_from_object(obj_eval, preserve_all_data_layers=True,
                                               depsgraph=depsgraph)
    return garment.data.copy()


def layer_collections_shown(view_layer):
    """The collections whose objects are in ``view_layer`` (not excluded, nor under an excluded one)."""
    shown = set()
    stack = [view_layer.layer_collection]
    while stack:
        layer = stack.pop()
        if not layer.exclude:
            shown.add(layer.collection)
            stack.extend(layer.children)
    return shown


def result_collections(garment, scene, view_layer=None):
    """Where a result made from ``garment`` goes: the garment's collections that can take a new object
    (neither linked from a library nor a library override) and, given ``view_layer``, are in it; else
    the scene's own collection.

    A garment in a linked collection, an excluded one or another scene's would otherwise give a result
    that cannot be made (linked data is read-only) or that is not in the view layer to be selected.
    """
    shown = layer_collections_shown(view_layer) if view_layer is not None else None
    collections = [c for c in garment.users_collection
                   if c.library is None and c.override_library is None
                   and (shown is None or c in shown)]
    return collections or ([scene.collection] if scene is not None else [])


def new_result_object(garment, V_world, name, depsgraph, evaluated=True, scene=None, view_layer=None):
    """A new object with the garment's faces, UVs, materials, seams, sharp edges and vertex groups
    at new world-space positions, linked into the garment's collections (see result_collections).

    The result keeps the garment's transform (without its parent), and drops what would move it
    again: animation, constraints, shape keys, and modifiers (all of them when ``evaluated``, since
    they are applied; only the non-refining ones otherwise, see REFINING_MODIFIERS).

    Parameters
    ----------
    garment : bpy.types.Object
    V_world : (n,3) float
        New positions, in the vertex order of the garment's state used (see the module docstring).
    name : str
        Name of the new object and its mesh (Blender adds a suffix when taken).
    scene : bpy.types.Scene, optional
        Where to link the result when none of the garment's collections can take it.
    view_layer : bpy.types.ViewLayer, optional
        The result is linked only into collections in this view layer.

    Returns
    -------
    bpy.types.Object
    """
    me = _result_mesh_data(garment, depsgraph, evaluated)
    result = None
    try:
        if len(me.vertices) != len(V_world):
            raise MeshError(garment.name, f"its mesh has {len(me.vertices)} vertices but "
                                          f"{len(V_world)} positions were computed")
        M = (garment.evaluated_get(depsgraph) if evaluated else garment).matrix_world.copy()
        result = garment.copy()
        result.data = me
        result.name = name
        me.name = result.name
        result.animation_data_clear()
        result.parent = None
        result.constraints.clear()
        result.matrix_world = M
        if me.shape_keys is not None:
            result.shape_key_clear()
        for mod in list(result.modifiers):
            if evaluated or mod.type not in REFINING_MODIFIERS:
                result.modifiers.remove(mod)
        write_positions(me, local_from_world(V_world, M, garment.name))
        for coll in result_collections(garment, scene, view_layer):
            coll.objects.link(result)
        return result
    except BaseException:
        if result is not None:
            bpy.data.objects.remove(result)
        bpy.data.meshes.remove(me)
        raise


def remove_results(objects):
    """Remove new result objects and their meshes (what an operator made before it failed)."""
    for obj in objects:
        me = obj.data
        bpy.data.objects.remove(obj)
        bpy.data.meshes.remove(me)


def write_vertex_colors(me, rgba, name):
    """Write (n,4) per-vertex colours as a float colour attribute and make it the active one."""
    rgba = np.ascontiguousarray(rgba, dtype=np.float32)
    if rgba.shape != (len(me.vertices), 4):
        raise MeshError(me.name, f"expected {len(me.vertices)} colours, got {rgba.shape[0]}")
    attr = me.color_attributes.get(name)
    if attr is not None and (attr.domain != 'POINT' or attr.data_type != 'FLOAT_COLOR'):
        me.color_attributes.remove(attr)
        attr = None
    if attr is None:
        attr = me.color_attributes.new(name=name, type='FLOAT_COLOR', domain='POINT')
    attr.data.foreach_set("color", rgba.reshape(-1))
    me.color_attributes.active_color = attr
    me.color_attributes.render_color_index = me.color_attributes.active_color_index
    me.update()


def write_float_attribute(me, values, name):
    """Write (n,) per-vertex floats as a float attribute (the raw numbers behind a heatmap)."""
    values = np.ascontiguousarray(values, dtype=np.float32)
    attr = me.attributes.get(name)
    if attr is not None and (attr.domain != 'POINT' or attr.data_type != 'FLOAT'):
        me.attributes.remove(attr)
        attr = None
    if attr is None:
        attr = me.attributes.new(name=name, type='FLOAT', domain='POINT')
    attr.data.foreach_set("value", values)
