"""Measure a transferred garment and paint how far each of its vertices moved."""

from __future__ import annotations

import bpy
import numpy as np

from . import convert
from .reporting import length_text, poll_objects, report_failure
from .transfer import format_metrics

HEATMAP_ATTRIBUTE = "moved_distance"


def heatmap_colors(values, scale):
    """(n,4) RGBA of (n,) non-negative values: blue (0) through green and yellow to red (>= scale)."""
    t = np.clip(np.asarray(values, dtype=np.float64) / max(scale, 1e-12), 0.0, 1.0)
    stops = np.array([[0.05, 0.15, 0.8], [0.1, 0.75, 0.3], [0.95, 0.85, 0.1], [0.85, 0.1, 0.05]])
    x = t * (len(stops) - 1)
    i = np.minimum(x.astype(np.int64), len(stops) - 2)
    w = (x - i)[:, None]
    rgb = stops[i] * (1 - w) + stops[i + 1] * w
    return np.concatenate([rgb, np.ones((rgb.shape[0], 1))], axis=1)


def evaluate_objects(context, result_obj, garment, target_body, reference=None, source_body=None,
                     evaluated=True):
    """Metrics of ``result_obj`` against ``garment`` (its source) on ``target_body``, and how far each
    vertex moved, written on the result as the colour attribute ``moved_distance`` (raw distances in
    ``moved_distance_value``).

    The drape error is measured against ``reference`` (the garment simulated or fitted on the target
    body) when given, else against the garment carried by ``source_body``'s change alone, else not.

    Returns
    -------
    metrics : dict
        The core's ``evaluate`` (MDC, penetration, drape and vertex errors).
    heatmap : dict
        ``written`` (bool), ``scale`` (value shown in full red), ``max``, and ``reason`` why it was
        not written (None when it was).
    """
    from ..garment_transfer import MeshError, evaluate, one_mesh, per_vertex_change

    for role, obj in (("result", result_obj), ("garment", garment), ("target body", target_body)):
        convert.require_mesh_object(obj, role)
    for role, obj in (("reference", reference), ("source body", source_body)):
        if obj is not None:
            convert.require_mesh_object(obj, role)
    if result_obj in (garment, target_body, reference, source_body):
        raise MeshError(result_obj.name, "is an input; choose the transferred result to evaluate "
                                         "(a heatmap is written on it)")
    depsgraph = context.evaluated_depsgraph_get()
    source = convert.core_mesh_from_object(garment, depsgraph, evaluated, "garment")
    result = convert.core_mesh_from_object(result_obj, depsgraph, evaluated, "result")
    body = convert.core_mesh_from_object(target_body, depsgraph, evaluated, "target body")
    ref = (convert.core_mesh_from_object(reference, depsgraph, evaluated, "reference")
           if reference is not None else None)
    src_body = (convert.core_mesh_from_object(source_body, depsgraph, evaluated, "source body")
                if source_body is not None and reference is None else None)
    cage = None
    if src_body is not None and not one_mesh(src_body, body):
        # The body fit needs the target's vertices to be the source's: a target subdivided by its modifiers
        # has them in the mesh it subdivides; a target of another mesh has no body fit to measure against.
        cage = convert.cage_mesh_from_object(target_body, context, "target body", body) if evaluated else None
        if cage is None or not one_mesh(src_body, cage):
            src_body, cage = None, None
    metrics = evaluate(source, result, body, reference=ref, source_body=src_body, target_cage=cage)
    change = np.asarray(per_vertex_change(source.V, result.V), dtype=np.float64)
    scale = float(np.percentile(change, 99)) if change.size else 0.0
    scale = scale if scale > 0 else 1.0
    heatmap = {"written": False, "scale": scale, "max": float(change.max(initial=0.0)),
               "reason": heatmap_refusal(result_obj, change.shape[0])}
    if heatmap["reason"] is None:
        me = result_obj.data
        convert.write_vertex_colors(me, heatmap_colors(change, scale), HEATMAP_ATTRIBUTE)
        convert.write_float_attribute(me, change, HEATMAP_ATTRIBUTE + "_value")
        heatmap["written"] = True
    return metrics, heatmap


def heatmap_refusal(result_obj, n_values):
    """Why the heatmap of ``n_values`` per-vertex values cannot be written on ``result_obj``'s mesh,
    or None when it can."""
    me = result_obj.data
    if me.library is not None:
        # Linked data is read-only (Python could still write it, but the change would not be saved).
        return (f"{result_obj.name}'s mesh is linked from the library {me.library.filepath}, which "
                "cannot be changed (make the result local to paint it)")
    if len(me.vertices) != n_values:
        return ("the result's modifiers change its vertex count (turn off Use Modifiers and Shape "
                "Keys)")
    return None


class GARMENT_TRANSFER_OT_evaluate(bpy.types.Operator):
    """Measure the result against its garment (design change, penetration, fit against the reference
    if one is chosen) and paint how far each vertex moved as the colour attribute moved_distance"""

    bl_idname = "garment_transfer.evaluate"
    bl_label = "Evaluate Result"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        return poll_objects(cls, context, lambda s: (("the result", s.result),
                                                     ("the garment it came from", s.garment),
                                                     ("the target body", s.target_body)))

    def execute(self, context):
        settings = context.scene.garment_transfer
        try:
            metrics, heatmap = evaluate_objects(context, settings.result, settings.garment,
                                                settings.target_body, settings.reference,
                                                settings.source_body, settings.use_evaluated)
        except Exception as exc:
            return report_failure(self, exc)
        settings.last_metrics = format_metrics(metrics)
        text = (f"{settings.result.name}: MDC {metrics['mdc']:.4f}, "
                f"{metrics['penetration_ratio']:.1%} inside "
                f"(deepest {length_text(context, metrics.get('max_penetration_depth') or 0.0)})")
        if metrics.get("drape_error_relative") is not None:
            against = "reference" if metrics.get("drape_reference") == "reference" else "body fit"
            text += (f", drape error against the {against} {metrics['drape_error_relative']:.2f} "
                     "of the untransferred garment's")
        if heatmap["written"]:
            self.report({'INFO'}, text + f"; heatmap '{HEATMAP_ATTRIBUTE}' (red = moved >= "
                                         f"{length_text(context, heatmap['scale'])})")
        else:
            self.report({'WARNING'}, text + f"; no heatmap: {heatmap['reason']}")
        return {'FINISHED'}


CLASSES = (GARMENT_TRANSFER_OT_evaluate,)
