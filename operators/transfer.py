"""Transfer a garment from the source body to a target body: a new object on the target."""

from __future__ import annotations

import os
import time

import bpy
import numpy as np

from . import convert
from .models import load_model_cached
from .reporting import length_text, poll_objects, report_failure, window_progress
from .rigging import body_moves, made_at_rest, pose_remedy, rest_pose_rigs, rig_to_body, skeletons_text

# Blender's OBJ importer, with its default axes, turns a Y-up file Z-up: world = OBJ_Y_UP_TO_WORLD @ file.
OBJ_Y_UP_TO_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def model_frame(model):
    """(3,3) rotation from Blender world space to the frame a model was trained in.

    A model's deformation gradients are directions in its training data's frame, so the bodies and
    the garment must be expressed in that frame. The dataset's up axis (model metadata) tells which:
    a Y-up dataset (the OBJ convention, also assumed when unstated) is taken to be imported with the
    importer's default axes; a Z-up one is used as it is.
    """
    from ..garment_transfer import ModelError

    up = str((model.metadata.get("dataset") or {}).get("up_axis") or "Y").upper()
    if up == "Z":
        return np.eye(3)
    if up == "Y":
        return OBJ_Y_UP_TO_WORLD.T
    raise ModelError(model.name, f"was trained on data whose up axis is {up!r}; Y or Z is needed")


def chosen_model(method, model_path, source, field_share=None):
    """The model file of the ``MODEL`` method (``model_files.ModelFile``, checked against the source body,
    a core Mesh) and the (3,3) rotation into its frame; (None, identity) for the other methods.
    ``field_share`` applies to a garment fit model only (the panel shows it for that kind alone)."""
    from ..garment_transfer import ModelError

    if method != "MODEL":
        return None, np.eye(3)
    if not model_path:
        raise ModelError("model file", "none chosen; choose one, or use the Direct method")
    model = load_model_cached(model_path)
    if model.kind == "garment" and field_share is not None:
        model = model.with_field_share(field_share)
    model.check_source_body(source)
    return model, model_frame(model)


def result_name(garment, target_body):
    return f"{garment.name}_on_{target_body.name}"


def registered_name(source_body, target_body):
    return f"{source_body.name}_fitted_to_{target_body.name}"


def shape_key_basis(body, evaluated=True):
    """A body's relative shape keys as a shape basis: world-space deltas from its basis key.

    Keys relative to another key, muted keys and keys limited to a vertex group are left out (their
    change is not a plain delta of the basis).

    Returns
    -------
    deltas : (k,n,3) float64 or None
        None when the body has no such key.
    bounds : (k,2) float64 or None
        Each weight's range from the key's slider (Min, Max), less its value when the body is read
        evaluated (the keys are then already applied at their values).
    names : list of str
    """
    from .shape_keys import key_coordinates

    key = body.data.shape_keys
    if key is None or not key.use_relative:
        return None, None, []
    reference = key.reference_key
    blocks = [kb for kb in key.key_blocks if kb != reference and kb.relative_key == reference
              and not kb.mute and not kb.vertex_group]
    if not blocks:
        return None, None, []
    M = convert.matrix_array(body.matrix_world)[:3, :3]
    base = key_coordinates(reference)
    deltas = np.stack([(key_coordinates(kb) - base) @ M.T for kb in blocks])
    values = np.array([kb.value if evaluated else 0.0 for kb in blocks])
    bounds = np.array([[kb.slider_min, kb.slider_max] for kb in blocks]) - values[:, None]
    return deltas, bounds, [kb.name for kb in blocks]


def transfer_objects(context, source_body, target_body, garment, *, method="DIRECT", model_path="",
                     target_label="", field_share=None, offset=None, fix_penetration=True, evaluated=True,
                     progress=None, keep_registered=False, use_shape_keys=False, body_model_path="",
                     untangle=False):
    """Transfer ``garment`` (on ``source_body``) onto ``target_body`` and make the result object.

    Reads the three objects (world space; see convert for which state), runs the core, and only
    then creates ``<garment>_on_<target>``: a failure leaves the scene as it was. A target body of
    another mesh is registered first (the core's registration); with ``keep_registered`` the
    fitted body is kept as ``<source>_fitted_to_<target>`` (``outcome.registered_body``). With
    ``use_shape_keys`` the source body's shape keys are the registration's shape basis
    (``shape_key_basis``; their names in ``outcome.shape_keys``); with ``body_model_path`` (MakeHuman's
    ``targets.npz``) MakeHuman's sliders are, in place of the shape keys (``outcome.body_model`` True).
    ``field_share``: for a garment fit model file (None: the core's default); its learned placement is
    used when the file holds one. When both bodies have an armature with the bones that move the source
    (``rigging.rest_pose_rigs``), a target in another rest pose gets the source and the garment posed into it
    first (the core's ``transfer_across_rest_poses``; ``outcome.info["rest_pose"]``; ``untangle``: where that folds the
    cloth through itself, undone); ``outcome.model_text`` says
    which model was used, ``outcome.method_text`` which method made the result and what it gains
    (``method_text``).

    Returns
    -------
    result : bpy.types.Object
        The new object, linked next to the garment.
    outcome : TransferResult
        From the core (positions, per-stage seconds, penetrating vertices).
    metrics : dict
        ``evaluate`` of the result as Blender has it (``result_metrics``) against the target body.
    """
    from ..garment_transfer import (SHAPE_BOUNDS, MeshError, target_at_rest, transfer_across_rest_poses,
                                    transfer_to_any_body)

    roles = (("source body", source_body), ("target body", target_body), ("garment", garment))
    for role, obj in roles:
        convert.require_mesh_object(obj, role)
    if garment == source_body or garment == target_body:
        raise MeshError(garment.name, "is chosen both as the garment and as a body")

    depsgraph = context.evaluated_depsgraph_get()
    source = convert.core_mesh_from_object(source_body, depsgraph, evaluated, "source body")
    target = convert.core_mesh_from_object(target_body, depsgraph, evaluated, "target body")
    cloth = convert.core_mesh_from_object(garment, depsgraph, evaluated, "garment")
    # A target subdivided by its modifiers: the mesh they subdivide may be the source's (not registered).
    cage = convert.cage_mesh_from_object(target_body, context, "target body", target) if evaluated else None
    depsgraph = context.evaluated_depsgraph_get()

    model, frame = chosen_model(method, model_path, source, field_share)

    def framed(mesh):
        return mesh.with_vertices(mesh.V @ frame.T)

    body_model = bool(body_model_path)
    if body_model:
        from ..garment_transfer import makehuman_shape_basis

        basis = makehuman_shape_basis(source, bpy.path.abspath(body_model_path))
        deltas, bounds, key_names = basis.basis, basis.bounds, basis.names
    elif use_shape_keys:
        deltas, bounds, key_names = shape_key_basis(source_body, evaluated)
    else:
        deltas, bounds, key_names = None, None, []
    if deltas is not None and deltas.shape[1] != source.n_vertices:
        raise MeshError(source_body.name, f"its shape keys have {deltas.shape[1]} vertices but the mesh read "
                                          f"has {source.n_vertices} (a modifier changes the vertex count): "
                                          "turn off Fit With Shape Keys or Use Evaluated")
    options = dict(method=method.lower(), **(model.transfer_arguments() if model else {}),
                   target=target_label or None, offset=offset, fix_penetration=fix_penetration, progress=progress,
                   shape_basis=None if deltas is None else deltas @ frame.T,
                   shape_bounds=SHAPE_BOUNDS if bounds is None else bounds, body_model=body_model)
    # Two bodies rigged alike: a target in another rest pose gets the source and its garment posed into it first.
    rigs, why_not = rest_pose_rigs(source_body, target_body, depsgraph, evaluated, source.n_vertices, frame, model)
    with pose_remedy(why_not):
        if rigs is not None:
            outcome, registration = transfer_across_rest_poses(framed(source), framed(target), framed(cloth), *rigs,
                                                               untangle=untangle, **options)
        else:
            outcome, registration = transfer_to_any_body(framed(source), framed(target), framed(cloth),
                                                         target_cage=None if cage is None else framed(cage), **options)
    outcome.shape_keys = key_names
    outcome.body_model = body_model
    outcome.model_text = model_text(model)
    outcome.method_text = method_text(method, model)
    outcome.V = outcome.V @ frame
    result = convert.new_result_object(garment, outcome.V, result_name(garment, target_body),
                                       depsgraph, evaluated, scene=context.scene,
                                       view_layer=context.view_layer)
    pose = outcome.info.get("rest_pose") or {}
    # Posed into the target's rest pose: its crossings are counted apart where the target's body crosses or closes
    # on itself (the source at rest tells which parts the pose pressed together, through the registration on a
    # target of another mesh; in the frame the core ran in: a rotation, which keeps every distance).
    posed = ((outcome.info["offset"], target_at_rest(framed(source), framed(target), registration))
             if pose.get("posed") else None)
    metrics = result_metrics(context, result, cloth, target, posed=posed)
    outcome.pose_warnings = metrics.pop("pose_warnings", [])
    outcome.registered_body = None
    if registration is not None and keep_registered:
        outcome.registered_body = convert.new_result_object(
            source_body, registration.V @ frame, registered_name(source_body, target_body), depsgraph,
            evaluated, scene=context.scene, view_layer=context.view_layer)
    return result, outcome, metrics


def result_metrics(context, result, garment, target, posed=None):
    """``evaluate`` of the new object as Blender has it (evaluated, in world space, its 32-bit coordinates),
    against the target body as read (``garment``, ``target``: the core meshes read): the panel's and the
    report's figures, crossings under every triangulation of the faces included. A result that keeps a refining
    modifier (Use Evaluated off) is measured before it. ``posed``: (offset, rest positions of the target's mesh or
    None) for a target in a pose: the pose fit's counts are added (``posed_counts``: crossings away from where the
    body crosses or closes on itself and at it; its warnings as ``pose_warnings``)."""
    from ..garment_transfer import evaluate, posed_counts

    context.view_layer.update()
    depsgraph = context.evaluated_depsgraph_get()
    written = convert.core_mesh_from_object(result, depsgraph, True, "result")
    if written.n_vertices != garment.n_vertices:
        # A refining modifier kept on the result (Subdivision, with Use Evaluated off): the mesh it refines.
        written = convert.core_mesh_from_object(result, depsgraph, False, "result")
    metrics = evaluate(garment, garment.with_vertices(written.V), target)
    if posed is not None:
        counts = posed_counts(written.V, garment, target, posed[0], rest_V=posed[1], name=target.name, own=False)
        metrics.update(crossings_outside_contact=counts["crossings_outside_contact"],
                       crossings_at_contact=counts["crossings_at_contact"], pose_warnings=counts["warnings"])
    return metrics


#: The panel's registration line names at most this many sliders (the largest weights first).
SHOWN_SLIDERS = 5


def model_text(model):
    """One line for the panel: which model was used ("" without one)."""
    return "" if model is None else "Model: " + model.describe()


#: What each method gains, in a few words: measured on the demo's test garments, which no model saw, against
#: Blender's cloth simulation of each on the pear-shaped body (``bash tools/run.sh demo``'s report;
#: docs/garment-model.md, "What it gains").
GAINS = {
    "garment": "0.62x Direct's distance to a cloth simulation, design kept",
    "garment_alone": "0.83x Direct's distance to a cloth simulation",
    "shared": "0.86x Direct's distance to a cloth simulation, more design change",
    "DIRECT": "the body's own deformation, no model; a garment fit model comes closer to a simulation",
    "SURFACE": "follows the body's surface alone, folds not rebuilt (a baseline)",
}


def method_text(method, model):
    """One line for the panel: which method made the result, and what it gains."""
    if model is None:
        return f"{method.capitalize()}: {GAINS[method]}"
    name = os.path.basename(model.path)
    if model.kind == "shared":
        return f"Shared deformation model ({name}): {GAINS['shared']}"
    if model.placement is not None:
        return f"Garment fit + placement ({name}, field share {model.field_share:g}): {GAINS['garment']}"
    return f"Garment fit model ({name}, field share {model.field_share:g}, no placement): {GAINS['garment_alone']}"


def fit_text(context, summary):
    """How closely the source was fitted onto the target (``Registration.summary()``), for the panels."""
    q = summary["quality"]
    return (f"Registered{' (cached)' if summary.get('cached') else ''}: 95% of the distance within "
            f"{length_text(context, q['to_target_p95'])} to / {length_text(context, q['from_target_p95'])} "
            f"from the target")


def registration_text(context, outcome):
    """One line for the panel: whether the target was registered, and the fit's residual."""
    from ..garment_transfer import untangle_text

    reg = outcome.info.get("registration")
    pose = outcome.info.get("rest_pose") or {}
    untangled = untangle_text(pose.get("untangle"))
    posed = (f"; posed into the target's rest pose first ({pose['largest_turn_bone']} turned "
             f"{pose['largest_turn']:.0f} degrees{skeletons_text(pose)}"
             f"{', untangled: ' + untangled + ' pairs its source does not have' if untangled else ''})"
             if pose.get("posed") else "")
    if not reg:
        faces = " and ".join(w for k, w in (("target_faces_split", "triangulated"), ("target_faces_turned", "turned"))
                             if outcome.info.get(k))
        if outcome.info.get("target_cage"):
            return "Same mesh as the source body under its subdivision: no registration" + posed
        if outcome.info.get("source_faces_split"):
            which = ("both bodies' faces triangulated, differently" if outcome.info.get("target_faces_split")
                     else "the source's faces triangulated")
            return f"Same mesh as the source body ({which}): no registration" + posed
        return f"Same mesh as the source body{f' (its faces {faces})' if faces else ''}: no registration" + posed
    q = reg["quality"]
    text = fit_text(context, reg)
    names = getattr(outcome, "shape_keys", [])
    what = "body model" if getattr(outcome, "body_model", False) else "shape keys"
    if names and "shape_weights" in reg:
        if q.get("shape_used"):
            moved = sorted(((n, w) for n, w in zip(names, reg["shape_weights"]) if abs(w) >= 1e-3),
                           key=lambda nw: -abs(nw[1]))
            shown = ", ".join(f"{n} {w:.2f}" for n, w in moved[:SHOWN_SLIDERS])
            more = f" and {len(moved) - SHOWN_SLIDERS} more" if len(moved) > SHOWN_SLIDERS else ""
            text += f"; {what} {shown}{more}"
        else:
            text += f"; {what} not used (explains {max(q.get('shape_explained', 0.0), 0.0):.0%})"
    return text + posed


class GARMENT_TRANSFER_OT_transfer(bpy.types.Operator):
    """Put the garment on the target body, keeping its folds: makes a new object
    <garment>_on_<target> and leaves the inputs unchanged"""

    bl_idname = "garment_transfer.transfer"
    bl_label = "Transfer Garment"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        if not poll_objects(cls, context, lambda s: (("the source body", s.source_body),
                                                     ("the target body", s.target_body),
                                                     ("the garment", s.garment))):
            return False
        if context.scene.garment_transfer.method == 'MODEL' and not context.scene.garment_transfer.model_path:
            cls.poll_message_set("Choose a model file, or use the Direct method")
            return False
        return True

    def execute(self, context):
        settings = context.scene.garment_transfer
        start = time.perf_counter()
        follows = settings.rig_result and body_moves(settings.target_body)
        rigged = None
        try:
            # A result that follows the body's motion is made on the body at rest: its Armature modifier poses it,
            # Fit to Pose and Bake Pose Fit carry it from there.
            with window_progress(context) as progress, made_at_rest(settings.target_body, settings.rig_result):
                result, outcome, metrics = transfer_objects(
                    context, settings.source_body, settings.target_body, settings.garment,
                    method=settings.method, model_path=settings.model_path,
                    target_label=settings.target_label, field_share=settings.field_share,
                    offset=None if settings.auto_offset else settings.offset,
                    fix_penetration=settings.fix_penetration, evaluated=settings.use_evaluated,
                    progress=progress, keep_registered=settings.keep_registered_body,
                    use_shape_keys=settings.use_shape_keys, body_model_path=settings.body_model_path,
                    untangle=settings.untangle)
            if follows:
                try:
                    rigged = rig_to_body(context, result, settings.target_body,
                                         max_influences=settings.max_influences,
                                         ride_surface=settings.ride_surface)[1]
                except BaseException:
                    convert.remove_results([result])
                    raise
        except Exception as exc:
            return report_failure(self, exc)
        elapsed = time.perf_counter() - start
        settings.result = result
        for obj in context.view_layer.objects:
            obj.select_set(obj == result)
        context.view_layer.objects.active = result
        settings.last_metrics = format_metrics(metrics)
        settings.last_registration = registration_text(context, outcome)
        settings.last_model = outcome.method_text
        self.report({'INFO'}, transfer_message(context, result, settings.target_body, outcome,
                                               metrics, elapsed))
        from ..garment_transfer import fold_warnings, result_warnings

        pose = outcome.info.get("rest_pose") or {}
        for warning in (result_warnings(metrics, result.name) + outcome.pose_warnings + pose.get("warnings", [])
                        + fold_warnings(pose, metrics["self_intersections_new"], result.name,
                                        "Untangle (the Motion panel)")
                        + (rigged or {}).get("warnings", [])):
            self.report({'WARNING'}, warning)
        return {'FINISHED'}


def transfer_message(context, result, target_body, outcome, metrics, elapsed):
    n = len(outcome.V)
    depth = metrics.get("max_penetration_depth") or 0.0
    return (f"{result.name}: MDC {metrics['mdc']:.4f}, {metrics['penetration_ratio']:.1%} of {n} "
            f"vertices inside {target_body.name} (deepest {length_text(context, depth)}), "
            f"{outcome.seconds['total']:.2f} s transfer, {elapsed:.2f} s in all")


def format_metrics(metrics):
    """Metrics as JSON for the panel and scripts (numbers and None only)."""
    import json
    import numbers

    clean = {}
    for key, value in metrics.items():
        if value is None or isinstance(value, bool):
            clean[key] = value
        elif isinstance(value, numbers.Integral):
            clean[key] = int(value)
        elif isinstance(value, numbers.Real):
            clean[key] = float(value)
    return json.dumps(clean)


CLASSES = (GARMENT_TRANSFER_OT_transfer,)
