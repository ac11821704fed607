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
- ``pipeline``: transfer, any body, outfits, shape keys, weights, metrics, the catalogue batch;
- ``cli``: the command line (``python -m garment_transfer``), not imported here.

What this module exports (``__all__``) is the public API that a pipeline script, the Blender layer and the
lab use::

    import garment_transfer as gt

    source, target = gt.read_obj("average.obj"), gt.read_obj("pear.obj")
    garment = gt.read_obj("dress.obj")
    result, registration = gt.transfer_to_any_body(source, target, garment)
    gt.write_obj("dress_on_pear.obj", garment, result.V, inputs=["dress.obj"])
"""

from .errors import (
                     Cancelled,
                     DatasetError,
                     GarmentTransferError,
                     MeshError,
                     ModelError,
                     NamedError,
                     RegistrationError,
                     SettingError,
                     TopologyMismatchError,
)
from .files import OutputError, atomic_path, check_output, check_output_folder, write_atomic, write_json_atomic
from .fitting import SHAPE_BOUNDS, Registration, makehuman_shape_basis, register, shape_basis_from_bodies
from .geometry import (
                     Mesh,
                     TriangleSurface,
                     body_scale,
                     crossings,
                     fix_penetration,
                     follow_nearest_vertex,
                     intersection_report,
                     mesh_from_polygons,
                     mesh_from_triangles,
                     obj_text,
                     read_obj,
                     require_same_topology,
                     same_mesh,
                     self_intersections,
                     write_obj,
)
from .learning import (
                     Dataset,
                     GarmentFitModel,
                     ModelFile,
                     SharedDeformationModel,
                     check_training_settings,
                     load_dataset,
                     read_model_file,
                     train_from_dataset,
                     train_garment_fit_from_dataset,
)
from .pipeline import (
                     OFFSET_SHARE,
                     OutfitError,
                     OutfitResult,
                     PreparedGarment,
                     ShapeKeyFit,
                     TransferResult,
                     all_pairs,
                     check_after_training,
                     check_model,
                     crossings_left,
                     drape_error,
                     evaluate,
                     fit_shape_keys,
                     fit_steps,
                     mdc,
                     per_vertex_change,
                     prepare_garment,
                     read_catalogue,
                     run_batch,
                     shapes_to_files,
                     surface_weights,
                     training_garments,
                     transfer_garment,
                     transfer_outfit,
                     transfer_to_any_body,
                     transfer_to_shapes,
                     vertex_error,
)
from .version import __version__

__all__ = [
    "__version__",
    # errors
    "GarmentTransferError", "NamedError", "MeshError", "TopologyMismatchError", "ModelError", "DatasetError",
    "SettingError", "RegistrationError", "OutputError", "Cancelled",
    # meshes and files
    "Mesh", "read_obj", "write_obj", "obj_text", "mesh_from_polygons", "mesh_from_triangles",
    "require_same_topology", "same_mesh", "check_output", "check_output_folder", "atomic_path", "write_atomic",
    "write_json_atomic",
    # transfer
    "prepare_garment", "transfer_garment", "PreparedGarment", "TransferResult", "transfer_to_any_body",
    "OFFSET_SHARE", "crossings_left",
    # registration
    "register", "Registration", "shape_basis_from_bodies", "makehuman_shape_basis", "SHAPE_BOUNDS",
    # outfits, shape keys, weights
    "transfer_outfit", "OutfitResult", "OutfitError", "fit_shape_keys", "transfer_to_shapes", "shapes_to_files",
    "ShapeKeyFit", "all_pairs", "fit_steps", "surface_weights",
    # quality
    "evaluate", "mdc", "drape_error", "vertex_error", "per_vertex_change", "crossings", "self_intersections",
    "intersection_report",
    # geometry the Blender layer needs
    "TriangleSurface", "body_scale", "fix_penetration", "follow_nearest_vertex",
    # models and datasets
    "read_model_file", "ModelFile", "SharedDeformationModel", "GarmentFitModel", "Dataset", "load_dataset",
    "train_from_dataset", "train_garment_fit_from_dataset", "check_training_settings", "training_garments",
    "check_model", "check_after_training",
    # catalogues
    "read_catalogue", "run_batch",
]
