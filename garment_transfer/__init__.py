"""Garment Transfer: a garment made and simulated on one body, put onto a body of another shape with its
design kept (Shi et al., "Learning a Shared Deformation Space for Efficient Design-Preserving Garment
Transfer", and beyond).

Plain functions on numpy arrays (and scipy); never imports bpy. Training needs torch; everything else,
transfer included, needs numpy and scipy only. The layers, from the ground up (each imports only those
below it):

- ``errors``, ``files``: the errors the core raises (each names the file or object), and writing files
  whole or not at all, never over an input;
- ``geometry``: meshes, OBJ files, closest points, gradients, the Poisson solve, intersections;
- ``fitting``: the source body registered onto a target body of any mesh;
- ``learning``: the shared deformation model, the garment fit model and its placement, datasets;
- ``rigging``: skeletons, BVH poses, skinning weights and their transfer from a body to a garment;
- ``pipeline``: transfer, any body, outfits, shape keys, poses, metrics, the catalogue batch;
- ``cli``: the command line (``python -m garment_transfer``), not imported here.

What this module exports (``__all__``) is the public API that a pipeline script, the Blender layer and the
lab use. The errors and the file helpers are imported with the package; every other name is imported from its
layer when it is first used, so that ``import garment_transfer`` (and enabling the Blender extension) stays
instant until a transfer is asked for::

    import garment_transfer as gt

    source, target = gt.read_obj("average.obj"), gt.read_obj("pear.obj")
    garment = gt.read_obj("dress.obj")
    result, registration = gt.transfer_to_any_body(source, target, garment)
    gt.write_obj("dress_on_pear.obj", garment, result.V, inputs=["dress.obj"])
"""

import importlib

from .errors import (Cancelled, DatasetError, GarmentTransferError, MeshError, ModelError, NamedError, PoseError,
                     RegistrationError, RigError, SettingError, TopologyMismatchError)
from .files import (OutputError, atomic_path, check_output, check_output_folder, check_outputs, write_atomic,
                    write_json_atomic)
from .version import __version__

#: The public names of each layer, by subpackage (imported on first use).
LAYERS = {
    "geometry": ("Mesh", "read_obj", "write_obj", "obj_text", "read_pc2", "write_pc2", "is_pc2", "read_mdd",
                 "write_mdd", "is_mdd", "is_mdd_name", "mesh_from_polygons", "mesh_from_triangles",
                 "require_same_topology", "same_mesh", "as_same_mesh", "one_mesh", "TriangleSurface", "body_scale",
                 "fix_penetration", "follow_nearest_vertex", "crossings", "self_intersections", "intersection_report",
                 "readings_of", "Readings"),
    "fitting": ("register", "Registration", "shape_basis_from_bodies", "makehuman_shape_basis", "SHAPE_BOUNDS",
                "limb_angles"),
    "learning": ("read_model_file", "ModelFile", "SharedDeformationModel", "GarmentFitModel", "Dataset",
                 "load_dataset", "dataset_inputs", "train_from_dataset", "train_garment_fit_from_dataset",
                 "check_training_settings"),
    "rigging": ("Skeleton", "read_skeleton", "read_joints", "Motion", "read_bvh", "parse_bvh", "axes_between",
                "SkinWeights", "skin_weights", "read_weights", "write_weights", "weights_from_dict", "weights_to_dict",
                "skin", "pose_transforms", "group_transforms", "Rig", "rig_from_bones", "bvh_rotations",
                "matching_rotations", "twist_from_body", "bone_frames", "surface_weights", "nearest_weights",
                "inpainted_weights", "unweighted_vertices", "riding_share", "MAX_INFLUENCES", "Landmarks",
                "landmarks_of", "naming_of", "pose_to_landmarks", "read_target_skeleton", "read_target_frames",
                "bones_from_dict", "bone_key", "NAMINGS"),
    "pipeline": ("prepare_garment", "transfer_garment", "PreparedGarment", "TransferResult", "transfer_to_any_body",
                 "lies_on_cage",
                 "OFFSET_SHARE", "POSE_LIMITS", "pose_check", "check_result", "result_warnings",
                 "transfer_outfit", "OutfitResult", "OutfitError", "fit_shape_keys", "transfer_to_shapes",
                 "shapes_to_files", "ShapeKeyFit", "KEEP_OUTSIDE_SHARE", "KEEP_OUTSIDE_BANDS", "SHAPE_KEY_BANDS",
                 "keep_outside_bands",
                 "held_bands", "HANGING_BANDS", "hanging_bands",
                 "all_pairs", "fit_steps", "mix_excess", "pair_warnings", "self_crossing_pairs",
                 "evaluate", "mdc", "drape_error", "vertex_error", "per_vertex_change", "training_garments",
                 "check_model", "check_after_training", "read_catalogue", "run_batch", "fit_to_pose",
                 "fit_poses", "in_threads", "posed_counts", "poses_to_files", "every_split",
                 "transfer_across_rest_poses", "outfit_across_rest_poses", "pose_difference", "fold_warnings",
                 "untangle_text", "target_at_rest"),
}
_LAYER_OF = {name: layer for layer, names in LAYERS.items() for name in names}

__all__ = [
    "__version__",
    "GarmentTransferError", "NamedError", "MeshError", "TopologyMismatchError", "ModelError", "DatasetError",
    "SettingError", "RegistrationError", "PoseError", "RigError", "OutputError", "Cancelled",
    "check_output", "check_outputs", "check_output_folder", "atomic_path", "write_atomic", "write_json_atomic",
    *_LAYER_OF,
]


def __getattr__(name):
    layer = _LAYER_OF.get(name)
    if layer is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{layer}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
