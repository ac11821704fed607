"""The "Garment" tab in the 3D viewport's sidebar."""

from __future__ import annotations

import importlib.util
import json
import sys

import bpy

from ..operators.models import model_file_path

METRIC_LABELS = (
    ("mdc", "Design change (MDC)", "{:.4f}"),
    ("penetration_ratio", "Vertices inside body", "{:.1%}"),
    ("max_penetration_depth", "Deepest", "{:.4g}"),
    ("drape_error", "Drape error", "{:.4g}"),
    ("drape_error_relative", "Drape error (relative)", "{:.3f}"),
    ("vertex_error_mean", "Vertex error (mean)", "{:.4g}"),
    ("vertex_error_max", "Vertex error (max)", "{:.4g}"),
    ("garment_edges_through_body", "Garment edges through body", "{:d}"),
    ("body_edges_through_garment", "Body edges through garment", "{:d}"),
    # A target posed (another rest pose): the crossings apart where its body crosses or closes on itself.
    ("crossings_outside_contact", "Crossings away from body contact", "{:d}"),
    ("crossings_at_contact", "Crossings where body meets itself", "{:d}"),
    ("self_intersections_new", "Self-intersections beyond source", "{:d}"),
    ("min_body_distance", "Smallest distance to body", "{:.4g}"),
)


def torch_available():
    """Whether torch can be imported, without importing it (draw code must stay fast)."""
    if "torch" in sys.modules:
        return sys.modules["torch"] is not None
    try:
        return importlib.util.find_spec("torch") is not None
    except (ImportError, ValueError):
        return False


class GarmentPanel:
    bl_space_type = 'VIEW_3D'
    bl_region_type = 'UI'
    bl_category = "Garment"


class VIEW3D_PT_garment_transfer(GarmentPanel, bpy.types.Panel):
    bl_label = "Garment Transfer"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.garment_transfer
        col = layout.column()
        col.prop(settings, "source_body")
        col.prop(settings, "target_body")
        col.prop(settings, "garment")
        col.prop(settings, "use_evaluated")

        col = layout.column()
        col.prop(settings, "method", expand=True)
        if settings.found_model and (settings.method != 'MODEL'
                                     or model_file_path(settings.model_path) != settings.found_model):
            # The model trained for this source body, offered where the method is chosen.
            row = col.row()
            row.label(text=settings.found_model_text, icon='CHECKMARK')
            row.operator("garment_transfer.find_model", text="Use")
        if settings.method == 'MODEL':
            row = col.row(align=True)
            row.prop(settings, "model_path")
            row.operator("garment_transfer.find_model", text="", icon='VIEWZOOM')
            if settings.model_status:
                col.label(text=settings.model_status,
                          icon='INFO' if settings.model_targets else 'ERROR')
            if settings.model_targets:
                col.prop_search(settings, "target_label", settings, "model_targets")
            if settings.model_kind == 'GARMENT':
                col.prop(settings, "field_share", slider=True)
        col.prop(settings, "fix_penetration")
        sub = col.column()
        sub.enabled = settings.fix_penetration
        sub.prop(settings, "auto_offset")
        row = sub.row()
        row.enabled = not settings.auto_offset
        row.prop(settings, "offset")
        col.prop(settings, "keep_registered_body")
        col.prop(settings, "use_shape_keys")
        col.prop(settings, "body_model_path")
        layout.operator("garment_transfer.transfer", icon='MOD_CLOTH')
        if settings.last_registration:
            layout.label(text=settings.last_registration, icon='MOD_MESHDEFORM')
        if settings.last_model:
            layout.label(text=settings.last_model, icon='INFO')
        layout.operator("garment_transfer.fit_shape_keys", icon='SHAPEKEY_DATA')


class GARMENT_TRANSFER_UL_outfit_layers(bpy.types.UIList):
    """The outfit's layers, from the body out: the first row is worn next to the skin."""

    def draw_item(self, _context, layout, _data, item, _icon, _active_data, _active_prop, index=0, _flt=0):
        row = layout.row(align=True)
        row.label(text=f"{index + 1}.")
        row.prop(item, "garment", text="", emboss=False, icon='MOD_CLOTH')
        if item.auto_offset:
            row.label(text="auto offset")
        else:
            row.prop(item, "offset", text="")


class VIEW3D_PT_garment_transfer_outfit(GarmentPanel, bpy.types.Panel):
    bl_label = "Outfit"
    bl_parent_id = "VIEW3D_PT_garment_transfer"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        settings = context.scene.garment_transfer
        layout.label(text="Layers from the body out (first: next to the skin)")
        row = layout.row()
        row.template_list("GARMENT_TRANSFER_UL_outfit_layers", "", settings, "outfit_layers", settings,
                          "outfit_index", rows=3)
        col = row.column(align=True)
        col.operator("garment_transfer.outfit_add", text="", icon='ADD').source = 'SELECTED'
        col.operator("garment_transfer.outfit_remove", text="", icon='REMOVE')
        col.separator()
        col.operator("garment_transfer.outfit_move", text="", icon='TRIA_UP').direction = 'UP'
        col.operator("garment_transfer.outfit_move", text="", icon='TRIA_DOWN').direction = 'DOWN'
        row = layout.row(align=True)
        row.prop(settings, "outfit_collection", text="")
        row.operator("garment_transfer.outfit_add", text="Add Collection",
                     icon='OUTLINER_COLLECTION').source = 'COLLECTION'
        if 0 <= settings.outfit_index < len(settings.outfit_layers):
            layer = settings.outfit_layers[settings.outfit_index]
            col = layout.column()
            col.use_property_split = True
            col.use_property_decorate = False
            col.prop(layer, "auto_offset")
            sub = col.row()
            sub.enabled = not layer.auto_offset
            sub.prop(layer, "offset")
        layout.operator("garment_transfer.transfer_outfit", icon='MOD_CLOTH')
        if settings.last_outfit:
            layout.label(text=f"Last: {settings.last_outfit}", icon='CHECKMARK')
            if settings.last_outfit_model:
                layout.label(text=settings.last_outfit_model, icon='NETWORK_DRIVE')
            if settings.last_outfit_registration:
                layout.label(text=settings.last_outfit_registration, icon='MOD_MESHDEFORM')


class VIEW3D_PT_garment_transfer_motion(GarmentPanel, bpy.types.Panel):
    bl_label = "Motion"
    bl_parent_id = "VIEW3D_PT_garment_transfer"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.garment_transfer
        layout.prop(settings, "rig_result")
        layout.prop(settings, "max_influences")
        layout.prop(settings, "ride_surface")
        layout.prop(settings, "result")
        layout.operator("garment_transfer.rig_garment", icon='ARMATURE_DATA')
        layout.prop(settings, "untangle")
        layout.operator("garment_transfer.fit_pose", icon='POSE_HLT').untangle = settings.untangle
        layout.prop(settings, "bake_cache")
        op = layout.operator("garment_transfer.bake_pose_fit", icon='REC')
        op.frame_start = context.scene.frame_start
        op.frame_end = context.scene.frame_end
        op.cache_file = settings.bake_cache
        op.untangle = settings.untangle


class VIEW3D_PT_garment_transfer_evaluation(GarmentPanel, bpy.types.Panel):
    bl_label = "Evaluation"
    bl_parent_id = "VIEW3D_PT_garment_transfer"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.garment_transfer
        layout.prop(settings, "result")
        layout.prop(settings, "reference")
        layout.operator("garment_transfer.evaluate", icon='COLOR')
        try:
            metrics = json.loads(settings.last_metrics) if settings.last_metrics else {}
        except ValueError:
            metrics = {}
        col = layout.column(align=True)
        for key, label, fmt in METRIC_LABELS:
            value = metrics.get(key)
            if value is not None:
                row = col.row()
                row.label(text=label)
                row.label(text=fmt.format(value))


class VIEW3D_PT_garment_transfer_training(GarmentPanel, bpy.types.Panel):
    bl_label = "Training"
    bl_parent_id = "VIEW3D_PT_garment_transfer"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.garment_transfer
        layout.prop(settings, "dataset_path")
        layout.prop(settings, "dataset_source")
        layout.prop(settings, "dataset_targets")
        layout.prop(settings, "train_output")
        layout.prop(settings, "train_kind")
        if settings.train_kind == 'SHARED':
            # The garment kind trains for its measured passes (the core's defaults).
            layout.prop(settings, "train_epochs")
            layout.prop(settings, "train_latent")
        layout.prop(settings, "train_hold_out")
        if not torch_available():
            box = layout.box()
            box.label(text="Training needs PyTorch (not installed)", icon='ERROR')
            box.label(text="pip install torch==2.13.0")
        layout.operator("garment_transfer.train", icon='PLAY')
        if settings.train_check:
            box = layout.box()
            for line in check_summary_lines(settings.train_check):
                box.label(text=line)


def check_summary_lines(text):
    """The panel's lines for the last check of a trained model on held-out garments (its JSON)."""
    try:
        check = json.loads(text)
        lines = [f"Held out: {', '.join(check['garments'])}"]
        for t in check["targets"]:
            s = check["targets_summary"][t]
            ratio, mdc = s["vertex_ratio"], s["mdc_ratio"]
            lines.append(f"{t}: vertex error {'n/a' if ratio is None else f'{ratio:.2f}x'} direct's, MDC "
                         f"{'n/a' if mdc is None else f'{mdc:.2f}x'}, {s['model']['penetrating_vertices']} inside")
        return lines
    except (ValueError, KeyError, TypeError):
        return ["The last check could not be read"]


class VIEW3D_PT_garment_transfer_drape(GarmentPanel, bpy.types.Panel):
    bl_label = "Cloth Simulation"
    bl_parent_id = "VIEW3D_PT_garment_transfer"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.garment_transfer
        layout.label(text="Re-drape the garment on the target body with Blender's cloth solver "
                          "(for comparison)")
        layout.prop(settings, "drape_frames")
        if settings.garment is not None:
            layout.prop_search(settings, "drape_pin_group", settings.garment, "vertex_groups")
        layout.operator("garment_transfer.drape", icon='PHYSICS')


CLASSES = (
    GARMENT_TRANSFER_UL_outfit_layers,
    VIEW3D_PT_garment_transfer,
    VIEW3D_PT_garment_transfer_outfit,
    VIEW3D_PT_garment_transfer_motion,
    VIEW3D_PT_garment_transfer_evaluation,
    VIEW3D_PT_garment_transfer_training,
    VIEW3D_PT_garment_transfer_drape,
)
