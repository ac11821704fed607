"""The add-on's settings: one PropertyGroup on each Scene (``scene.garment_transfer``)."""

from __future__ import annotations

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)


def is_mesh(_self, obj):
    return obj.type == 'MESH'


def refresh_model_info(settings):
    """List the targets of the model file in ``settings`` (or say why it cannot be read)."""
    from ..garment_transfer import GarmentTransferError
    from ..operators.models import load_model_cached

    settings.model_targets.clear()
    settings.model_kind = 'NONE'
    if not settings.model_path:
        settings.model_status = ""
        return
    try:
        model = load_model_cached(settings.model_path)
    except GarmentTransferError as exc:
        settings.model_status = str(exc)
        return
    for label in model.targets:
        settings.model_targets.add().name = str(label)
    kind = ("Shared deformation model" if model.kind == "shared" else
            "Garment fit model" + (" + learned placement" if model.has_placement else ""))
    settings.model_status = f"{kind}, {len(model.targets)} target(s)"
    settings.model_kind = model.kind.upper()
    if settings.target_label not in model.targets and len(model.targets):
        settings.target_label = str(model.targets[0])


def _model_path_changed(self, _context):
    refresh_model_info(self)


def _offer_model(settings, context):
    """Look for the source body's model file again; with the Model method and no file chosen yet, choose it."""
    from ..operators.models import refresh_found_model, use_found_model

    if refresh_found_model(settings, context) and settings.method == 'MODEL' and not settings.model_path:
        use_found_model(settings)


def _source_body_changed(self, context):
    _offer_model(self, context)


def _method_changed(self, context):
    if self.method == 'MODEL' and not self.model_path:
        _offer_model(self, context)


class GarmentTransferTarget(bpy.types.PropertyGroup):
    """A target body label of the loaded model (``name`` is the label)."""


class GarmentTransferLayer(bpy.types.PropertyGroup):
    """One layer of an outfit: a garment and the distance it keeps from what is under it."""

    garment: PointerProperty(
        name="Garment", type=bpy.types.Object, poll=is_mesh,
        description="The garment of this layer as it sits on the source body")
    auto_offset: BoolProperty(
        name="Automatic Offset", default=True,
        description="Keep the distance the single transfer keeps (chosen from the body's scale)")
    offset: FloatProperty(
        name="Offset", subtype='DISTANCE', unit='LENGTH', default=0.002, min=0.0, max=1.0, soft_max=0.05,
        precision=4,
        description="Distance this layer keeps from the body and the layers under it: the thickness "
                    "of the cloth under it")


class GarmentTransferSettings(bpy.types.PropertyGroup):
    source_body: PointerProperty(
        name="Source Body", type=bpy.types.Object, poll=is_mesh, update=_source_body_changed,
        description="The body the garment was made (simulated) on")
    target_body: PointerProperty(
        name="Target Body", type=bpy.types.Object, poll=is_mesh,
        description="The body to put the garment on: the source body's mesh in another shape, or any "
                    "body mesh of a person in a similar pose (the source body is fitted onto it first)")
    garment: PointerProperty(
        name="Garment", type=bpy.types.Object, poll=is_mesh,
        description="The garment as it sits on the source body")
    use_evaluated: BoolProperty(
        name="Use Modifiers and Shape Keys", default=True,
        description="Read every object as the viewport shows it (modifiers, shape keys and cloth "
                    "simulation at the current frame). Off: the base meshes")
    method: EnumProperty(
        name="Method",
        items=(
            ('DIRECT', "Direct", "Carry the body's own deformation from the source to the target body "
                                 "onto the garment; needs no model"),
            ('MODEL', "Model", "Use a trained model: the paper's shared deformation model, or the garment "
                               "fit model with its learned placement"),
            ('SURFACE', "Surface", "Baseline: the garment follows the body surface only, like "
                                   "Blender's Surface Deform (folds are not rebuilt)"),
        ),
        default='DIRECT', update=_method_changed)
    model_path: StringProperty(
        name="Model File", subtype='FILE_PATH', update=_model_path_changed,
        description="A model file (.npz) trained on this source body (python -m garment_transfer train; "
                    "--kind garment: the garment fit model and its learned placement in one file)")
    model_targets: CollectionProperty(type=GarmentTransferTarget)
    model_status: StringProperty(name="Model Status")
    model_kind: EnumProperty(
        name="Model Kind", items=(('NONE', "None", "No model file read"),
                                  ('SHARED', "Shared", "The paper's shared deformation model"),
                                  ('GARMENT', "Garment", "The garment fit model")), default='NONE')
    field_share: FloatProperty(
        name="Field Share", default=0.5, min=0.0, max=1.0,
        description="Garment fit model: how much of its predicted field is used, from the body's own (0, as "
                    "Direct) to the model's (1). With the learned placement, half kept the design (MDC) at "
                    "Direct's and its vertex error at 0.63x Direct's on unseen test garments")
    found_model: StringProperty(
        name="Found Model", description="The model file trained for the source body, found where the user keeps "
                                        "one (the last one trained here, or beside the .blend file)")
    found_model_text: StringProperty(name="Found Model Text")
    last_trained_model: StringProperty(name="Last Trained Model", subtype='FILE_PATH',
                                       description="The model file trained last in this scene")
    last_model: StringProperty(
        name="Last Method", description="Which method made the last result, and what it gains")
    last_outfit_model: StringProperty(name="Last Outfit Model")
    last_outfit_registration: StringProperty(name="Last Outfit Registration")
    target_label: StringProperty(
        name="Target", description="Which of the model's target bodies the target body is")
    auto_offset: BoolProperty(
        name="Automatic Offset", default=True,
        description="Choose the distance kept between garment and body from the meshes' scale")
    offset: FloatProperty(
        name="Penetration Offset", subtype='DISTANCE', unit='LENGTH', default=0.002, min=0.0,
        max=1.0, soft_max=0.05, precision=4,
        description="Distance the garment keeps from the target body's surface: the cloth thickness, "
                    "at most 5% of the body's size (checked when transferring, as on the command line)")
    keep_registered_body: BoolProperty(
        name="Keep Fitted Body", default=False,
        description="When the target body is another mesh, keep the source body fitted onto it as a "
                    "new object <source>_fitted_to_<target>, for inspection")
    use_shape_keys: BoolProperty(
        name="Fit With Shape Keys", default=True,
        description="When the target body is another mesh and the source body has shape keys (sliders), "
                    "first fit the source as a blend of them within their slider ranges, then fit the "
                    "surface: the keys carry where each vertex belongs (a blend that explains less than half "
                    "of the difference is not used)")
    body_model_path: StringProperty(
        name="Body Model", subtype='FILE_PATH', default="",
        description="MakeHuman's targets.npz (from the makehuman package): when the target body is another "
                    "mesh and the source is a MakeHuman (hm08) body, fit the source as a blend of "
                    "MakeHuman's sliders first, in place of its shape keys. Empty: none")
    last_registration: StringProperty(name="Last Registration")
    fix_penetration: BoolProperty(
        name="Fix Penetration", default=True,
        description="Push garment vertices out of the target body and spread the fix smoothly")

    outfit_layers: CollectionProperty(
        type=GarmentTransferLayer, name="Outfit Layers",
        description="The garments of an outfit, from the body out: each is worn over the ones above "
                    "it in the list")
    outfit_index: IntProperty(name="Active Layer", default=0, min=0)
    outfit_collection: PointerProperty(
        name="Collection", type=bpy.types.Collection,
        description="A collection of garments to add as layers (its mesh objects, by name)")
    last_outfit: StringProperty(name="Last Outfit")

    result: PointerProperty(
        name="Result", type=bpy.types.Object, poll=is_mesh,
        description="A transferred garment to evaluate (set by Transfer)")
    reference: PointerProperty(
        name="Reference", type=bpy.types.Object, poll=is_mesh,
        description="Optional: the same garment simulated or fitted on the target body")
    last_metrics: StringProperty(name="Last Metrics")

    dataset_path: StringProperty(
        name="Dataset", subtype='DIR_PATH',
        description="A dataset folder: bodies/<body>.obj, garments/<garment>/<body>.obj")
    dataset_source: StringProperty(
        name="Source Body Name", default="",
        description="The dataset's source body, bodies/<name>.obj (empty: the first body the "
                    "dataset lists)")
    dataset_targets: StringProperty(
        name="Target Body Names", default="",
        description="Comma-separated target bodies to train for (empty: every other body)")
    train_output: StringProperty(
        name="Save Model As", subtype='FILE_PATH', default="//garment_model.npz",
        description="Where to write the trained model (.npz)")
    train_kind: EnumProperty(
        name="Model",
        items=[('GARMENT', "Garment Fit + Placement",
                "The garment fit model and its learned placement in one file: a field and a hang of each "
                "garment's own (on unseen garments 0.6x Direct's distance to a cloth simulation, the design "
                "kept; docs/garment-model.md)"),
               ('SHARED', "Shared Deformation", "The paper's shared deformation model: one field per target body")],
        default='GARMENT')
    train_epochs: IntProperty(name="Epochs", default=300, min=1, soft_max=5000)
    train_latent: IntProperty(name="Latent Size", default=30, min=1, soft_max=256,
                              description="Size of the shared deformation space")
    train_progress: FloatProperty(name="Training Progress", subtype='PERCENTAGE', min=0, max=100)
    train_hold_out: StringProperty(
        name="Hold Out", default="",
        description="Comma-separated garments of the dataset to leave out of training: once the model is saved, "
                    "each is transferred with it and with direct transfer and measured against its own drape, "
                    "to see whether the model beats the body alone on garments it has not seen")
    train_check: StringProperty(
        name="Last Check",
        description="The last trained model measured on its held-out garments (JSON; empty: none held out)")

    rig_result: BoolProperty(
        name="Rig Result", default=True,
        description="When the target body has an Armature modifier, transfer on its rest pose and give the "
                    "result the body's bones as vertex groups (matched where the cloth lies on the skin, filled "
                    "smoothly elsewhere), an Armature modifier and a Shrinkwrap that keeps it outside; when a Mesh "
                    "Cache or Mesh Sequence Cache modifier plays it, transfer on its mesh without them and let the "
                    "result follow its surface (Surface Deform) and the Shrinkwrap")
    ride_surface: BoolProperty(
        name="Ride Body Surface", default=False,
        description="Rigging also adds a Surface Deform, bound to the body at rest, that carries the cloth lying "
                    "on the skin with the posed body's surface (the rest follows the bones): closer to the skin at "
                    "the bends; in Blender about as many crossings as without it over the poses measured")
    untangle: BoolProperty(
        name="Untangle", default=False,
        description="Fit to Pose and Bake Pose Fit also undo where the fit makes the cloth cross itself (under the "
                    "arms, the lap sitting) without crossing the body more: seconds more a frame where it does. So "
                    "does Transfer Garment onto a character in another rest pose, where posing the source folds it")
    bake_cache: StringProperty(
        name="Point Cache", subtype='FILE_PATH', default="",
        description="Bake Pose Fit into this PC2 file (or MDD, named .mdd), played by a Mesh Cache modifier on the "
                    "baked object (one file for a long action); empty: a shape key per frame on the object")
    max_influences: IntProperty(
        name="Bones per Vertex", default=8, min=1, max=16,
        description="The most bones that move one garment vertex (game engines take 8, or 4: fewer follow the "
                    "skin less closely)")

    drape_frames: IntProperty(
        name="Frames", default=30, min=1, soft_max=400,
        description="Frames to let the cloth settle after the body has morphed (the morph takes as "
                    "many, settling on the source body twice as many)")
    drape_pin_group: StringProperty(
        name="Pin Group",
        description="Vertex group of the garment held in place while the body morphs (waistband, "
                    "shoulders); without one a close-fitting garment can slide down")


CLASSES = (GarmentTransferTarget, GarmentTransferLayer, GarmentTransferSettings)


def register_settings():
    bpy.types.Scene.garment_transfer = PointerProperty(type=GarmentTransferSettings)


def unregister_settings():
    del bpy.types.Scene.garment_transfer
