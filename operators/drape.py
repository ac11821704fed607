"""Re-drape the garment on the target body with Blender's cloth solver (the simulation baseline)."""

from __future__ import annotations

import bpy

from . import convert
from .reporting import missing_choice_message, report_failure, window_progress


def draped_name(garment, target_body):
    return f"{garment.name}_draped_on_{target_body.name}"


def drape_objects(context, source_body, target_body, garment, *, frames=40, evaluated=True,
                  progress=None):
    """Simulate ``garment`` while ``source_body`` morphs into ``target_body``; make the result object.

    Returns
    -------
    bpy.types.Object
        ``<garment>_draped_on_<target>``, linked next to the garment.
    """
    from ..garment_transfer.errors import MeshError
    from ..garment_transfer.mesh import require_same_topology
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
    shapes = drape_garment(cloth.V, cloth.polygons(), source.V, source.F,
                           target_body_Vs=[target.V], frames=frames, progress=progress)
    return convert.new_result_object(garment, shapes[-1], draped_name(garment, target_body),
                                     depsgraph, evaluated, scene=context.scene)


class GARMENT_TRANSFER_OT_drape(bpy.types.Operator):
    """Simulate the garment with Blender's cloth solver while the source body morphs into the target
    body: makes a new object <garment>_draped_on_<target> (slow; for comparison with Transfer)"""

    bl_idname = "garment_transfer.drape"
    bl_label = "Drape with Cloth Simulation"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        settings = getattr(context.scene, "garment_transfer", None)
        if settings is None:
            return False
        message = missing_choice_message((("the source body", settings.source_body),
                                                  ("the target body", settings.target_body),
                                                  ("the garment", settings.garment)))
        if message:
            cls.poll_message_set(message)
            return False
        if context.mode != 'OBJECT':
            cls.poll_message_set("Switch to Object Mode first")
            return False
        return True

    def execute(self, context):
        settings = context.scene.garment_transfer
        try:
            with window_progress(context) as progress:
                result = drape_objects(context, settings.source_body, settings.target_body,
                                       settings.garment, frames=settings.drape_frames,
                                       evaluated=settings.use_evaluated, progress=progress)
        except Exception as exc:
            return report_failure(self, exc)
        settings.result = result
        self.report({'INFO'}, f"{result.name}: draped over {settings.drape_frames} frames")
        return {'FINISHED'}


CLASSES = (GARMENT_TRANSFER_OT_drape,)
