"""Outfits: several garments worn one over another, transferred together from the body out.

The layers are ``scene.garment_transfer.outfit_layers``, innermost first, as the panel lists them.
The core (``transfer_outfit``) checks the order, separates the layers and transfers them; only when
every layer succeeded is a new object made for each, so a refused outfit adds nothing to the scene.
"""

from __future__ import annotations

import time

import bpy
from bpy.props import EnumProperty

from . import convert
from .reporting import poll_objects, report_failure, window_progress
from .rigging import body_moves, made_at_rest, pose_remedy, rest_pose_rigs, rig_to_body, skeletons_text
from .transfer import chosen_model, fit_text, model_text, result_name


def outfit_garments(settings):
    """The layers' garment objects, innermost first (None where a layer has none chosen)."""
    return [layer.garment for layer in settings.outfit_layers]


def outfit_offsets(settings):
    """Each layer's offset: None for automatic, else its distance."""
    return [None if layer.auto_offset else float(layer.offset) for layer in settings.outfit_layers]


def check_outfit_objects(source_body, target_body, garments):
    """Raise MeshError naming the object when the layers cannot be an outfit on these bodies."""
    from ..garment_transfer import MeshError

    if not garments:
        raise MeshError("outfit", "has no layers; add garments in the Outfit panel")
    for k, obj in enumerate(garments):
        if obj is None:
            raise MeshError(f"outfit layer {k + 1}", "has no garment chosen")
        convert.require_mesh_object(obj, "garment")
        if obj == source_body or obj == target_body:
            raise MeshError(obj.name, "is chosen both as a layer of the outfit and as a body")
    seen = set()
    for obj in garments:
        if obj.name in seen:
            raise MeshError(obj.name, "is given as two layers of the outfit")
        seen.add(obj.name)


def transfer_outfit_objects(context, source_body, target_body, garments, *, offsets=None, method="DIRECT",
                            model_path="", target_label="", field_share=None, evaluated=True, progress=None):
    """Transfer the outfit ``garments`` (innermost first, on ``source_body``) onto ``target_body``.

    Reads every object (world space), runs the core's ``transfer_outfit`` (``outfit_across_rest_poses`` when both
    bodies have an armature with the bones that move the source: a target in another rest pose gets the source
    and every layer posed into it first; a target of another mesh is registered once, for every layer) and only
    then makes one new object ``<garment>_on_<target>`` per layer;
    if making any of them fails, the ones made are removed: the scene is as it was.

    Parameters
    ----------
    offsets : list of (float or None), optional
        Each layer's offset; None: the automatic one (the core's default).

    Returns
    -------
    results : list of bpy.types.Object
        The new objects, innermost first.
    outcome : OutfitResult
        From the core (each layer's positions, seconds, per-layer info); ``outcome.model_text`` says which
        model was used.
    mdc : list of float
        Each layer's design change (MDC) against the garment as given.
    """
    from ..garment_transfer import mdc, outfit_across_rest_poses, target_at_rest, transfer_outfit

    convert.require_mesh_object(source_body, "source body")
    convert.require_mesh_object(target_body, "target body")
    check_outfit_objects(source_body, target_body, garments)
    depsgraph = context.evaluated_depsgraph_get()
    source = convert.core_mesh_from_object(source_body, depsgraph, evaluated, "source body")
    target = convert.core_mesh_from_object(target_body, depsgraph, evaluated, "target body")
    cloths = [convert.core_mesh_from_object(g, depsgraph, evaluated, "garment") for g in garments]
    # A target subdivided by its modifiers: the mesh they subdivide may be the source's (not registered).
    cage = convert.cage_mesh_from_object(target_body, context, "target body", target) if evaluated else None
    depsgraph = context.evaluated_depsgraph_get()
    model, frame = chosen_model(method, model_path, source, field_share)

    def framed(mesh):
        return mesh.with_vertices(mesh.V @ frame.T)

    source_framed = framed(source)
    options = dict(offsets=offsets, method=method.lower(), **(model.transfer_arguments() if model else {}),
                   target=target_label or None, progress=progress)
    # Two bodies rigged alike: a target in another rest pose gets the source and every layer posed into it first.
    rigs, why_not = rest_pose_rigs(source_body, target_body, depsgraph, evaluated, source.n_vertices, frame, model)
    with pose_remedy(why_not):
        if rigs is not None:
            outcome = outfit_across_rest_poses(source_framed, framed(target), [framed(c) for c in cloths], *rigs,
                                               **options)
        else:
            outcome = transfer_outfit(source_framed, framed(target), [framed(c) for c in cloths],
                                      target_cage=None if cage is None else framed(cage), **options)
    outcome.V = [V @ frame for V in outcome.V]
    outcome.source_V = [V @ frame for V in outcome.source_V]
    outcome.model_text = model_text(model)
    design = [mdc(c.V, V, c.F) for c, V in zip(cloths, outcome.V)]
    results = []
    try:
        for g, V in zip(garments, outcome.V):
            results.append(convert.new_result_object(g, V, result_name(g, target_body), depsgraph, evaluated,
                                                     scene=context.scene, view_layer=context.view_layer))
    except BaseException:
        convert.remove_results(results)
        raise
    posed = bool((outcome.rest_pose or {}).get("posed"))
    # The source at rest tells which parts of a posed target its pose pressed together (through the registration on
    # a target of another mesh; in the frame the core ran in: a rotation, which keeps every distance).
    rest = target_at_rest(source_framed, framed(target), outcome.registration) if posed else None
    outcome.checks = layer_checks(context, results, cloths, target,
                                  [i["offset"] for i in outcome.info] if posed else None, rest)
    return results, outcome, design


def layer_checks(context, results, cloths, target, posed_offsets=None, rest_V=None):
    """``check_result`` of each new object as Blender evaluates it (world space) against the target as read and
    the layers under it as evaluated, under every triangulation (a refining modifier kept: the mesh it
    refines). ``posed_offsets``: the layers' offsets, for a target in a pose: each check adds the pose fit's
    counts (``posed_counts``, the target's mesh at rest ``rest_V``): ``crossings_outside_contact``,
    ``crossings_at_contact`` and ``pose_warnings``."""
    from ..garment_transfer import check_result, posed_counts, readings_of

    context.view_layer.update()
    depsgraph = context.evaluated_depsgraph_get()
    checks, below = [], []
    for k, (obj, cloth) in enumerate(zip(results, cloths)):
        V = convert.core_mesh_from_object(obj, depsgraph, True, "result").V
        if V.shape != cloth.V.shape:
            V = convert.core_mesh_from_object(obj, depsgraph, False, "result").V
        checks.append(check_result(cloth, V, target, layers_below=below))
        below.append((V, readings_of(cloth)))
        if posed_offsets is not None:
            counts = posed_counts(V, cloth, target, posed_offsets[k], rest_V=rest_V, name=f"{target.name} ({obj.name})",
                                  own=False)
            checks[-1].update(crossings_outside_contact=counts["crossings_outside_contact"],
                              crossings_at_contact=counts["crossings_at_contact"], pose_warnings=counts["warnings"])
    return checks


def outfit_message(results, outcome, design, elapsed, fitted=""):
    layers = ", ".join(f"{r.name} (MDC {m:.4f})" for r, m in zip(results, design))
    crossing = sum(c["garment_edge_body_pairs"] + c["body_edge_garment_pairs"] + c["layer_crossings"]
                   for c in outcome.checks)
    said = ("no crossings between the layers or with the body" if not crossing else
            f"{crossing} edge-triangle pairs cross between the layers or with the body")
    pose = outcome.rest_pose or {}
    posed = (f"; posed into the target's rest pose first ({pose['largest_turn_bone']} turned "
             f"{pose['largest_turn']:.0f} degrees{skeletons_text(pose)})") if pose.get("posed") else ""
    registered = f"; {fitted}" if fitted else ""
    return (f"Outfit of {len(results)} layers, from the body out: {layers}; {said} (as evaluated, any "
            f"triangulation){posed}{registered}; {outcome.seconds['total']:.2f} s transfer, {elapsed:.2f} s in all")


class GARMENT_TRANSFER_OT_transfer_outfit(bpy.types.Operator):
    """Put every garment of the outfit on the target body, from the body out, each outside the ones
    under it: makes a new object <garment>_on_<target> per layer and leaves the inputs unchanged"""

    bl_idname = "garment_transfer.transfer_outfit"
    bl_label = "Transfer Outfit"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        if not poll_objects(cls, context, lambda s: (("the source body", s.source_body),
                                                     ("the target body", s.target_body))):
            return False
        settings = context.scene.garment_transfer
        if len(settings.outfit_layers) < 1 or any(g is None for g in outfit_garments(settings)):
            cls.poll_message_set("Add the outfit's garments in the Outfit panel, from the body out")
            return False
        if settings.method == 'MODEL' and not settings.model_path:
            cls.poll_message_set("Choose a model file, or use the Direct method")
            return False
        return True

    def execute(self, context):
        settings = context.scene.garment_transfer
        start = time.perf_counter()
        follows = settings.rig_result and body_moves(settings.target_body)
        try:
            # Layers that follow the body's motion are made on the body at rest (``made_at_rest``).
            with window_progress(context) as progress, made_at_rest(settings.target_body, settings.rig_result):
                results, outcome, design = transfer_outfit_objects(
                    context, settings.source_body, settings.target_body, outfit_garments(settings),
                    offsets=outfit_offsets(settings), method=settings.method, model_path=settings.model_path,
                    target_label=settings.target_label, field_share=settings.field_share,
                    evaluated=settings.use_evaluated, progress=progress)
            rig_warnings = []
            if follows:
                try:
                    for result in results:
                        rig_warnings += rig_to_body(context, result, settings.target_body,
                                                    max_influences=settings.max_influences,
                                                    ride_surface=settings.ride_surface)[1]["warnings"]
                except BaseException:
                    convert.remove_results(results)
                    raise
        except Exception as exc:
            return report_failure(self, exc)
        elapsed = time.perf_counter() - start
        settings.result = results[-1]
        for obj in context.view_layer.objects:
            obj.select_set(obj in results)
        context.view_layer.objects.active = results[-1]
        settings.last_outfit = " / ".join(r.name for r in results)
        settings.last_outfit_model = outcome.model_text
        settings.last_outfit_registration = ("" if outcome.registration is None else
                                             fit_text(context, outcome.registration.summary()))
        self.report({'INFO'}, outfit_message(results, outcome, design, elapsed, settings.last_outfit_registration))
        from ..garment_transfer import result_warnings

        for warning in (outcome.rest_pose or {}).get("warnings", []):
            self.report({'WARNING'}, warning)
        if settings.untangle and (outcome.rest_pose or {}).get("posed"):
            self.report({'WARNING'}, "Untangle is for one garment (Transfer Garment): an outfit's layers posed into "
                                     "the target's rest pose are not untangled")
        for obj, check in zip(results, outcome.checks):
            for warning in result_warnings(check, obj.name) + check.get("pose_warnings", []):
                self.report({'WARNING'}, warning)
        for warning in rig_warnings:
            self.report({'WARNING'}, warning)
        return {'FINISHED'}


def _addable(settings, obj):
    return (obj.type == 'MESH' and obj not in (settings.source_body, settings.target_body)
            and obj not in outfit_garments(settings))


class GARMENT_TRANSFER_OT_outfit_add(bpy.types.Operator):
    """Add garments to the outfit as outer layers: the selected mesh objects, or the mesh objects of
    the chosen collection (by name; the bodies are left out)"""

    bl_idname = "garment_transfer.outfit_add"
    bl_label = "Add Layers"
    bl_options = {'REGISTER', 'UNDO'}

    source: EnumProperty(
        name="From", items=(('SELECTED', "Selected", "The selected mesh objects"),
                            ('COLLECTION', "Collection", "The mesh objects of the chosen collection")),
        default='SELECTED')

    @classmethod
    def poll(cls, context):
        if getattr(context.scene, "garment_transfer", None) is None:
            return False
        if context.mode != 'OBJECT':
            cls.poll_message_set("Switch to Object Mode first")
            return False
        return True

    def execute(self, context):
        settings = context.scene.garment_transfer
        if self.source == 'COLLECTION':
            if settings.outfit_collection is None:
                self.report({'ERROR'}, "Choose a collection of garments first")
                return {'CANCELLED'}
            candidates = settings.outfit_collection.all_objects
        else:
            # The view layer's own selection: a script or a background run has no selection context.
            candidates = [o for o in context.view_layer.objects if o.select_get()]
        new = sorted((o for o in candidates if _addable(settings, o)), key=lambda o: o.name)
        if not new:
            self.report({'WARNING'}, "No mesh object to add: the bodies and the layers already in the outfit "
                                     "are left out")
            return {'CANCELLED'}
        for obj in new:
            settings.outfit_layers.add().garment = obj
        settings.outfit_index = len(settings.outfit_layers) - 1
        self.report({'INFO'}, f"Added {', '.join(o.name for o in new)}; order the layers from the body out")
        return {'FINISHED'}


class GARMENT_TRANSFER_OT_outfit_remove(bpy.types.Operator):
    """Remove the active layer from the outfit (the garment object itself is kept)"""

    bl_idname = "garment_transfer.outfit_remove"
    bl_label = "Remove Layer"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        settings = getattr(context.scene, "garment_transfer", None)
        return settings is not None and 0 <= settings.outfit_index < len(settings.outfit_layers)

    def execute(self, context):
        settings = context.scene.garment_transfer
        settings.outfit_layers.remove(settings.outfit_index)
        settings.outfit_index = max(0, min(settings.outfit_index, len(settings.outfit_layers) - 1))
        return {'FINISHED'}


class GARMENT_TRANSFER_OT_outfit_move(bpy.types.Operator):
    """Move the active layer one place closer to the body (up) or further out (down)"""

    bl_idname = "garment_transfer.outfit_move"
    bl_label = "Move Layer"
    bl_options = {'REGISTER', 'UNDO'}

    direction: EnumProperty(
        name="Direction", items=(('UP', "Up", "One layer closer to the body"),
                                 ('DOWN', "Down", "One layer further from the body")),
        default='UP')

    @classmethod
    def poll(cls, context):
        settings = getattr(context.scene, "garment_transfer", None)
        return settings is not None and 0 <= settings.outfit_index < len(settings.outfit_layers)

    def execute(self, context):
        settings = context.scene.garment_transfer
        i = settings.outfit_index
        j = i - 1 if self.direction == 'UP' else i + 1
        if not 0 <= j < len(settings.outfit_layers):
            return {'CANCELLED'}
        settings.outfit_layers.move(i, j)
        settings.outfit_index = j
        return {'FINISHED'}


CLASSES = (GARMENT_TRANSFER_OT_transfer_outfit, GARMENT_TRANSFER_OT_outfit_add,
           GARMENT_TRANSFER_OT_outfit_remove, GARMENT_TRANSFER_OT_outfit_move)
