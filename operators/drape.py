"""Re-drape the garment on the target body with Blender's cloth solver (the simulation baseline)."""

from __future__ import annotations

import time

import bpy

from . import convert
from .reporting import poll_objects, report_failure, window_progress


def draped_name(garment, target_body):
    return f"{garment.name}_draped_on_{target_body.name}"


def pinned_vertices(garment, group_name, n_vertices):
    """(k,) int64 indices of the garment's vertices in vertex group ``group_name`` with weight >= 0.5."""
    import numpy as np

    from ..garment_transfer import MeshError

    if not group_name:
        return None
    group = garment.vertex_groups.get(group_name)
    if group is None:
        raise MeshError(garment.name, f"has no vertex group {group_name!r} to pin")
    if len(garment.data.vertices) != n_vertices:
        raise MeshError(garment.name, "its modifiers change its vertex count, so the pin group does "
                                      "not apply; turn off Use Modifiers and Shape Keys")
    index = group.index
    pins = [v.index for v in garment.data.vertices
            if any(g.group == index and g.weight >= 0.5 for g in v.groups)]
    return np.asarray(pins, dtype=np.int64)


def drape_objects(context, source_body, target_body, garment, *, frames=40, pin_group="",
                  evaluated=True, progress=None, report=None):
    """Settle ``garment`` on ``source_body`` with Blender's cloth solver, morph the body into
    ``target_body`` under it, and make the result object from where the cloth comes to rest.

    Positions are in world space, as the cloth solver's constants assume metres. The scene's frame
    and everything the simulation creates are put back afterwards (operators/cloth.py).

    Parameters
    ----------
    frames : int
        Frames to settle after the morph; the morph takes as many, settling on the source twice as many.
    pin_group : str
        A vertex group of the garment held in place (waistband, shoulders), or "".
    report : list, optional
        Receives one dict per simulation (see cloth.drape_garment).

    Returns
    -------
    bpy.types.Object
        ``<garment>_draped_on_<target>``, linked next to the garment.
    """
    from ..garment_transfer import MeshError, require_same_topology
    from .cloth import drape_garment

    for role, obj in (("source body", source_body), ("target body", target_body), ("garment", garment)):
        convert.require_mesh_object(obj, role)
    if garment in (source_body, target_body):
        raise MeshError(garment.name, "is chosen both as the garment and as a body")
    depsgraph = context.evaluated_depsgraph_get()
    source = convert.core_mesh_from_object(source_body, depsgraph, evaluated, "source body")
    target = convert.core_mesh_from_object(target_body, depsgraph, evaluated, "target body")
    cloth = convert.core_mesh_from_object(garment, depsgraph, evaluated, "garment")
    require_same_topology(source, target)
    pins = pinned_vertices(garment, pin_group, cloth.n_vertices)
    shapes = drape_garment(cloth.V, cloth.polygons(), source.V, source.F, target_body_Vs=[target.V],
                           pin_group=pins, frames=frames, progress=progress, report=report)
    return convert.new_result_object(garment, shapes[-1], draped_name(garment, target_body),
                                     depsgraph, evaluated, scene=context.scene,
                                     view_layer=context.view_layer)


class GARMENT_TRANSFER_OT_drape(bpy.types.Operator):
    """Simulate the garment with Blender's cloth solver while the source body morphs into the target
    body: makes a new object <garment>_draped_on_<target> (slow; the baseline Transfer is compared to)"""

    bl_idname = "garment_transfer.drape"
    bl_label = "Drape with Cloth Simulation"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        return poll_objects(cls, context, lambda s: (("the source body", s.source_body),
                                                     ("the target body", s.target_body),
                                                     ("the garment", s.garment)))

    def execute(self, context):
        settings = context.scene.garment_transfer
        start = time.perf_counter()
        runs = []
        try:
            with window_progress(context) as progress:
                result = drape_objects(context, settings.source_body, settings.target_body,
                                       settings.garment, frames=settings.drape_frames,
                                       pin_group=settings.drape_pin_group,
                                       evaluated=settings.use_evaluated, progress=progress,
                                       report=runs)
        except Exception as exc:
            return report_failure(self, exc)
        settings.result = result
        inside = runs[-1]["inside_after"] if runs else 0
        self.report({'INFO'}, f"{result.name}: settled and draped in {time.perf_counter() - start:.1f} s; "
                              f"{inside} vertices inside {settings.target_body.name} after the fix")
        return {'FINISHED'}


CLASSES = (GARMENT_TRANSFER_OT_drape,)
