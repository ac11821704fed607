"""Fit the garment to the source body's shape keys: a new garment object whose shape keys follow the
body's sliders through drivers, and which keeps the garment's rigging.

What is read (rest shapes, no modifiers): the body's shape keys as stored (each relative to the basis)
and the garment's base mesh, both through their ``matrix_world``. The inputs are never changed; the
result ``<garment>_fitted`` is made only once every key is transferred.

``invoke`` runs modally: a timer advances a step generator (one transfer per step), the window shows
progress, Esc cancels and nothing is made. ``execute`` drains the same generator.
"""

from __future__ import annotations

import time

import bpy
import numpy as np
from bpy.props import BoolProperty, FloatProperty, StringProperty

from . import convert, rigging
from .reporting import ModalSteps, poll_objects, report_failure

#: Variables of these types read two targets; the others one (CONTEXT_PROP reads none).
TWO_TARGETS = {'LOC_DIFF', 'ROTATION_DIFF'}


def fitted_name(garment):
    return f"{garment.name}_fitted"


def key_coordinates(key_block):
    """(n,3) float64 object-space coordinates of a shape key."""
    co = np.empty(3 * len(key_block.data), dtype=np.float32)
    key_block.data.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def world(V_local, obj):
    M = convert.matrix_array(obj.matrix_world)
    return V_local @ M[:3, :3].T + M[:3, 3]


def body_key_shapes(body, names=None):
    """The body's basis and the chosen shape keys, in world space (checked).

    Parameters
    ----------
    body : bpy.types.Object
    names : list of str, optional
        Keys to use; default every key but the basis.

    Returns
    -------
    basis : (n,3) float64
    shapes : dict of str to (n,3) float64
    """
    from ..garment_transfer import MeshError

    key = body.data.shape_keys
    if key is None or len(key.key_blocks) < 2:
        raise MeshError(body.name, "has no shape keys besides its basis: nothing to fit the garment to "
                                   "(add shape keys to the body, or use Transfer with a target body)")
    if not key.use_relative:
        raise MeshError(body.name, "its shape keys are absolute (Evaluation Time); only relative shape "
                                   "keys are sliders the garment can follow")
    reference = key.reference_key
    blocks = [kb for kb in key.key_blocks if kb != reference]
    if names:
        known = {kb.name: kb for kb in blocks}
        missing = [n for n in names if n not in known]
        if missing:
            raise MeshError(body.name, f"has no shape key {', '.join(map(repr, missing))}; it has "
                                       f"{', '.join(known)}")
        blocks = [known[n] for n in names]
    for kb in blocks:
        if kb.relative_key != reference:
            raise MeshError(body.name, f"its shape key {kb.name!r} is relative to {kb.relative_key.name!r}, "
                                       f"not to the basis {reference.name!r}: set its Relative To to the "
                                       "basis (a key on top of another key cannot be followed alone)")
    basis = world(key_coordinates(reference), body)
    return basis, {kb.name: world(key_coordinates(kb), body) for kb in blocks}


def broken_drivers(obj):
    """Names of the shape keys of ``obj`` whose drivers read an object or data that was deleted."""
    key = obj.data.shape_keys if obj.type == 'MESH' else None
    if key is None or key.animation_data is None:
        return []
    broken = []
    for fc in key.animation_data.drivers:
        for var in fc.driver.variables:
            count = 2 if var.type in TWO_TARGETS else (0 if var.type == 'CONTEXT_PROP' else 1)
            if any(var.targets[i].id is None for i in range(count)):
                broken.append(fc.data_path)
                break
    return broken


def check_garment(garment, body, key_names):
    """Raise MeshError for a garment whose own shape keys cannot be kept; return their names."""
    from ..garment_transfer import MeshError

    key = garment.data.shape_keys
    if key is None:
        return []
    own = [kb.name for kb in key.key_blocks if kb != key.reference_key]
    clash = [n for n in own if n in key_names]
    if clash:
        raise MeshError(garment.name, f"already has shape keys named like {body.name}'s "
                                      f"({', '.join(map(repr, clash))}); rename them or choose other keys")
    broken = broken_drivers(garment)
    if broken:
        raise MeshError(garment.name, f"has drivers whose target was deleted ({', '.join(broken)}); "
                                      "fix or remove them first")
    return own


def body_weights(body):
    """The body's vertex groups as an (n,k) array and their names."""
    names = [g.name for g in body.vertex_groups]
    W = np.zeros((len(body.data.vertices), len(names)))
    for v in body.data.vertices:
        for g in v.groups:
            if g.group < len(names):
                W[v.index, g.group] = g.weight
    return W, names


def add_driver(key_block, body_key, variables, expression=None):
    """Drive ``key_block.value`` from the values of ``body_key``'s key blocks ``variables``: their average, or
    ``expression`` of them named a, b, ... (an expression Blender evaluates without Python)."""
    fc = key_block.driver_add("value")
    drv = fc.driver
    drv.type = 'SCRIPTED' if expression else 'AVERAGE'
    for i, name in enumerate(variables):
        var = drv.variables.new()
        var.name = "ab"[i] if expression else ("value" if len(variables) == 1 else f"k{i}")
        var.type = 'SINGLE_PROP'
        var.targets[0].id_type = 'KEY'
        var.targets[0].id = body_key
        var.targets[0].data_path = f'key_blocks["{bpy.utils.escape_identifier(name)}"].value'
    if expression:
        drv.expression = expression
    # The curve Blender adds maps 0..1 and holds its ends; without points or modifiers the key takes
    # the driver's value as it is, over the whole slider range.
    for mod in list(fc.modifiers):
        fc.modifiers.remove(mod)
    while len(fc.keyframe_points):
        fc.keyframe_points.remove(fc.keyframe_points[0], fast=True)
    return fc


#: The key that lifts a mix of sliders adding up to more than 1 (``shape_keys.mix_lift``).
MIX_LIFT_KEY = "Mix Lift"


def mix_lift_name(body_keys):
    """``MIX_LIFT_KEY``, numbered when the body has a key of that name."""
    name, i = MIX_LIFT_KEY, 1
    while name in body_keys:
        name, i = f"{MIX_LIFT_KEY} {i}", i + 1
    return name


def add_lift_driver(key_block, body_key, variables):
    """Drive the lift key ``key_block`` by ``shape_keys.mix_excess`` of ``body_key``'s sliders ``variables``: their
    sum (a Sum driver, evaluated without Python and for any number of keys), less 1 (a Generator modifier), held at 0
    below by the key's slider range."""
    fc = add_driver(key_block, body_key, variables)
    fc.driver.type = 'SUM'
    generator = fc.modifiers.new('GENERATOR')
    generator.mode = 'POLYNOMIAL'
    generator.poly_order = 1
    generator.coefficients = (-1.0, 1.0)
    key_block.slider_min = 0.0
    return fc


def write_key(me, key_block, V_local):
    key_block.data.foreach_set("co", np.ascontiguousarray(V_local, dtype=np.float32).reshape(-1))


def build_result(context, garment, body, fit, garment_basis_local, weights=None, keep_outside=None):
    """The new object: the garment's copy with the fitted basis, a driven key per body key and per
    corrective pair, the key lifting mixes (``fit.lift``), the garment's own keys moved with the basis, its parent,
    modifiers and groups, and with
    ``keep_outside`` (``shape_keys.keep_outside_bands``) a Shrinkwrap per band last in the stack."""
    key_body = body.data.shape_keys
    me = garment.data.copy()
    obj = None
    try:
        obj = garment.copy()
        obj.data = me
        obj.name = fitted_name(garment)
        me.name = obj.name
        if obj.animation_data is not None:
            obj.animation_data_clear()
        basis_local = convert.local_from_world(fit.basis, garment.matrix_world, garment.name)
        shift = basis_local - garment_basis_local
        if me.shape_keys is not None:
            for kb in me.shape_keys.key_blocks:
                write_key(me, kb, key_coordinates(kb) + shift)
        else:
            obj.shape_key_add(name="Basis", from_mix=False)
        reference = me.shape_keys.reference_key
        write_key(me, reference, basis_local)
        convert.write_positions(me, basis_local)
        for name, V in fit.keys.items():
            kb = obj.shape_key_add(name=name, from_mix=False)
            write_key(me, kb, convert.local_from_world(V, garment.matrix_world, garment.name))
            kb.relative_key = reference
            # A driven key's value is clamped to its slider range: the widest, so that it follows the
            # body's slider whatever range the body's key is given later.
            kb.slider_min, kb.slider_max = -10.0, 10.0
            add_driver(kb, key_body, [name])
        for (a, b), delta in fit.correctives.items():
            kb = obj.shape_key_add(name=f"{a}+{b}", from_mix=False)
            V = convert.local_from_world(fit.basis + delta, garment.matrix_world, garment.name)
            write_key(me, kb, V)
            kb.relative_key = reference
            kb.slider_min, kb.slider_max = -10.0, 10.0
            add_driver(kb, key_body, [a, b], expression="a * b")
        if fit.lift is not None:
            kb = obj.shape_key_add(name=mix_lift_name(fit.keys), from_mix=False)
            write_key(me, kb, convert.local_from_world(fit.basis + fit.lift, garment.matrix_world, garment.name))
            kb.relative_key = reference
            kb.slider_min, kb.slider_max = 0.0, 10.0
            add_lift_driver(kb, key_body, list(fit.keys))
        if weights is not None:
            W, names = weights
            for j, name in enumerate(names):
                group = obj.vertex_groups.get(name) or obj.vertex_groups.new(name=name)
                for i in np.flatnonzero(W[:, j] > 1e-4):
                    group.add([int(i)], float(W[i, j]), 'REPLACE')
            if not any(m.type == 'ARMATURE' for m in obj.modifiers):
                for m in body.modifiers:
                    if m.type == 'ARMATURE' and m.object is not None:
                        new = obj.modifiers.new(name=m.name, type='ARMATURE')
                        new.object = m.object
                        new.use_vertex_groups = True
                        new.use_deform_preserve_volume = m.use_deform_preserve_volume
                        break
        if keep_outside:
            rigging.add_keep_outside_bands(obj, body, keep_outside)
        me.update()
        for coll in convert.result_collections(garment, context.scene, context.view_layer):
            coll.objects.link(obj)
        return obj
    except BaseException:
        if obj is not None:
            bpy.data.objects.remove(obj)
        bpy.data.meshes.remove(me)
        raise


def bone_weights(context, body, body_mesh, cloth):
    """With an armature on the body: the garment's weights of its deforming bones (matched where the cloth lies
    on the skin, inpainted elsewhere, ``rigging.rig_to_body``'s rule), as ((g,k) array, names, warnings: the weight
    transfer's, such as cloth left with no weight); else None."""
    from ..garment_transfer import inpainted_weights

    armature = rigging.body_armature(body)
    if armature is None:
        return None
    body_weights = rigging.vertex_group_weights(body, rigging.deform_bones(armature))
    if not body_weights.influences().any():
        return None
    weights, info = inpainted_weights(body_mesh.V, body_mesh.F, body_weights, cloth.V, cloth.F,
                                      max_influences=context.scene.garment_transfer.max_influences, name=cloth.name)
    used = weights.influences() > 0
    keep = [j for j in range(len(weights.groups)) if weights.W[:, j].nnz] if used.any() else []
    return weights.dense()[:, keep], [weights.groups[j] for j in keep], info["warnings"]


def fit_steps(context, body, garment, *, names=None, correctives=False, margin=0.0,
              weights_from_body=False, keep_outside=False, offset=None, mix_lift=True):
    """Read the objects, transfer one key per step, then make the object: a generator.

    Yields the fraction done; returns ``(result object, ShapeKeyFit, kept garment keys, weight note, warnings)``:
    the weights' warnings (``bone_weights``), then those of each key at 1 as stored (``key_warnings``).
    """
    from ..garment_transfer import MeshError, all_pairs, surface_weights
    from ..garment_transfer import fit_steps as core_steps

    convert.require_mesh_object(body, "source body")
    convert.require_mesh_object(garment, "garment")
    if body == garment:
        raise MeshError(garment.name, "is chosen both as the garment and as the body")
    basis_V, shapes = body_key_shapes(body, names)
    kept = check_garment(garment, body, set(shapes) | {f"{a}+{b}" for a, b in all_pairs(shapes)}
                         | ({mix_lift_name(shapes)} if mix_lift and not correctives else set()))
    depsgraph = context.evaluated_depsgraph_get()
    body_mesh = convert.core_mesh_from_object(body, depsgraph, False, "source body").with_vertices(basis_V)
    cloth = convert.core_mesh_from_object(garment, depsgraph, False, "garment")
    if garment.data.shape_keys is not None:
        garment_basis_local = key_coordinates(garment.data.shape_keys.reference_key)
        cloth = cloth.with_vertices(world(garment_basis_local, garment))
    else:
        garment_basis_local = convert.local_from_world(cloth.V, garment.matrix_world, garment.name)
    weights = None
    note = ""
    weight_warnings = []
    if weights_from_body:
        if len(garment.vertex_groups):
            note = f"kept {garment.name}'s own vertex groups (it has weights)"
        elif not len(body.vertex_groups):
            note = f"{body.name} has no vertex groups to take weights from"
        else:
            found = bone_weights(context, body, body_mesh, cloth)
            if found is None:
                W, group_names = body_weights(body)
                weights = (surface_weights(body_mesh.V, body_mesh.F, W, cloth.V), group_names)
            else:
                weights, weight_warnings = found[:2], found[2]
            note = f"took {len(weights[1])} vertex groups from {body.name}"
    steps = core_steps(body_mesh, shapes, cloth, pairs=all_pairs(shapes) if correctives else (),
                       margin=margin, offset=offset, lift=mix_lift)
    while True:
        try:
            done, total, _name = next(steps)
        except StopIteration as stop:
            fit = stop.value
            break
        yield done / total
    bands = None
    if keep_outside:
        from ..garment_transfer import held_bands

        # Per vertex, as far out as the basis and every key at 1 hold it (in bands, one Shrinkwrap each), measured
        # on the body's faces as Blender splits them (``shape_keys.keep_outside_bands`` on Blender's triangles).
        held = [(rigging.shrinkwrap_surface(body, basis_V), fit.basis)]
        held += [(rigging.shrinkwrap_surface(body, V), fit.keys[name]) for name, V in shapes.items()]
        bands = held_bands(held, fit.info["Basis"]["offset"])
    result = build_result(context, garment, body, fit, garment_basis_local, weights, bands)
    return result, fit, kept, note, weight_warnings + key_warnings(result, fit, cloth, body_mesh, shapes)


def key_warnings(result, fit, cloth, body_mesh, shapes):
    """The warnings to report: the pairs of keys whose body crosses itself (``pair_warnings``), then what each key
    at 1 crosses, as stored in the new object (its 32-bit coordinates, in world space) against the body at that
    key, under every triangulation (``check_result``)."""
    from ..garment_transfer import check_result, pair_warnings, result_warnings

    blocks = result.data.shape_keys.key_blocks
    out = pair_warnings(fit, body_mesh.name)
    for name, V_body in shapes.items():
        V = world(key_coordinates(blocks[name]), result)
        check = check_result(cloth, V, body_mesh.with_vertices(V_body), source_pairs=fit.prepared.source_pairs(),
                             readings=fit.prepared.readings())
        out += result_warnings(check, f"{result.name} with {name} at 1")
    return out


def drain(steps):
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            return stop.value


class GARMENT_TRANSFER_OT_fit_shape_keys(ModalSteps, bpy.types.Operator):
    """Fit the garment to each shape key of the source body: a new object <garment>_fitted with a
    shape key per body key, driven by the body's sliders, keeping the garment's rigging"""

    bl_idname = "garment_transfer.fit_shape_keys"
    bl_label = "Fit to Body Shape Keys"
    bl_options = {'REGISTER', 'UNDO'}

    keys: StringProperty(name="Keys", default="",
                         description="The body's shape keys to follow, comma-separated (empty: all)")
    correctives: BoolProperty(
        name="Corrective Keys", default=False,
        description="Also fit every pair of keys at 1 and add its difference from the linear blend as a "
                    "key driven by the product of the two sliders (exact pairs; more keys)")
    margin: FloatProperty(name="Margin", default=0.0, min=0.0, subtype='DISTANCE',
                          description="Extra distance from the body for every key, room for blends")
    weights_from_body: BoolProperty(
        name="Weights from Body", default=True,
        description="When the garment has no vertex groups, take the body's (nearest surface point, "
                    "interpolated) and its Armature modifier, so that the result follows the rig")

    mix_lift: BoolProperty(
        name="Lift Mixes", default=True,
        description="Add a key, driven by how far the sliders add up beyond 1, that moves the garment out along "
                    "the body's normals where its edges are long, so that a mix of several keys does not cut "
                    "through the body between vertices (nothing at the basis, at any key at 1 or with corrective "
                    "keys)")
    keep_outside: BoolProperty(
        name="Keep Outside Body", default=True,
        description="Add Shrinkwrap modifiers (Outside mode, last in the stack) that move only the vertices "
                    "a mix of sliders or a pose puts inside or too near the body out to the distance each "
                    "key at 1 keeps them (half the offset to twice the offset, in bands)")

    status_text = "Fitting to shape keys"
    cancel_text = "Fitting to shape keys cancelled; nothing was made"
    timer_seconds = 0.05
    _steps = None

    @classmethod
    def poll(cls, context):
        return poll_objects(cls, context, lambda s: (("the source body", s.source_body),
                                                     ("the garment", s.garment)))

    def _start(self, context):
        settings = context.scene.garment_transfer
        names = [n.strip() for n in self.keys.split(",") if n.strip()] or None
        self._began = time.perf_counter()
        self._steps = fit_steps(context, settings.source_body, settings.garment, names=names,
                                correctives=self.correctives, margin=self.margin,
                                weights_from_body=self.weights_from_body,
                                keep_outside=self.keep_outside, mix_lift=self.mix_lift,
                                offset=None if settings.auto_offset else settings.offset)

    def _finish(self, context, outcome):
        result, fit, kept, note, warnings = outcome
        settings = context.scene.garment_transfer
        settings.result = result
        for obj in context.view_layer.objects:
            obj.select_set(obj == result)
        context.view_layer.objects.active = result
        parts = [f"{result.name}: {len(fit.keys)} shape keys driven by {settings.source_body.name}'s"]
        if fit.correctives:
            parts.append(f"{len(fit.correctives)} corrective pair keys")
        if fit.lift is not None:
            parts.append("a key lifting mixes beyond 1")
        if kept:
            parts.append(f"kept the garment's own shape keys {', '.join(kept)} (moved with the basis)")
        if note:
            parts.append(note)
        parts.append(f"{time.perf_counter() - self._began:.2f} s")
        self.report({'INFO'}, "; ".join(parts))
        for warning in warnings:
            self.report({'WARNING'}, warning)
        return {'FINISHED'}

    def execute(self, context):
        try:
            self._start(context)
            outcome = drain(self._steps)
        except Exception as exc:
            return report_failure(self, exc)
        return self._finish(context, outcome)


CLASSES = (GARMENT_TRANSFER_OT_fit_shape_keys,)
