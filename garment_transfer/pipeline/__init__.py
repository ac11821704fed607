"""The pipeline: a garment on the source body made into the same garment on a target body, and what is
built on that. ``transfer`` (prepare a garment once, transfer it to each target), ``any_body`` (a target of
another mesh: registered first), ``outfit`` (layers, each outside the ones under it), ``shape_keys`` (one garment
fitted to every shape of a body), ``pose_fit`` (a garment fitted to its body posed), ``rest_pose`` (a target in
another rest pose: the source posed into it first), ``metrics`` (MDC, penetration, drape and vertex error,
crossings: ``evaluate``), ``result_check`` (the promise measured on a result as written: no crossing under any
triangulation, against the body given), ``model_check`` (a trained model on held-out garments), ``catalogue``
(garments to transfer to many targets, read and checked) and ``batch`` (a catalogue's run, resumable, on a
process pool or Dask). Built on ``geometry``, ``fitting``, ``learning`` and ``rigging``.
"""

from .any_body import lies_on_cage, transfer_to_any_body
from .batch import BatchSummary, run_batch
from .catalogue import Catalogue, read_catalogue
from .metrics import drape_error, evaluate, mdc, per_vertex_change, vertex_error
from .model_check import check_after_training, check_lines, check_model, training_garments
from .outfit import OutfitError, OutfitResult, transfer_outfit
from .pose_fit import every_split, fit_poses, fit_to_pose, in_threads, posed_counts, poses_to_files, self_contact
from .rest_pose import (fold_warnings, outfit_across_rest_poses, pose_difference, target_at_rest,
                        transfer_across_rest_poses, untangle_text)
from .result_check import check_result, result_warnings
from .shape_keys import (HANGING_BANDS, KEEP_OUTSIDE_BANDS, KEEP_OUTSIDE_SHARE, SHAPE_KEY_BANDS, ShapeKeyFit,
                         all_pairs, fit_shape_keys, fit_steps, hanging_bands, held_bands, keep_outside_bands,
                         mix_excess, pair_warnings, self_crossing_pairs, shapes_to_files, transfer_to_shapes)
from .transfer import (OFFSET_SHARE, POSE_LIMITS, PreparedGarment, TransferResult, pose_check, prepare_garment,
                       transfer_garment)

__all__ = ["OFFSET_SHARE", "PreparedGarment", "TransferResult", "prepare_garment", "transfer_garment", "pose_check",
           "POSE_LIMITS", "check_result", "result_warnings",
           "transfer_to_any_body", "lies_on_cage", "KEEP_OUTSIDE_SHARE", "KEEP_OUTSIDE_BANDS", "SHAPE_KEY_BANDS",
           "keep_outside_bands",
           "held_bands", "HANGING_BANDS", "hanging_bands",
           "OutfitError", "OutfitResult", "transfer_outfit",
           "ShapeKeyFit", "fit_shape_keys", "transfer_to_shapes", "shapes_to_files", "all_pairs", "fit_steps",
           "mix_excess", "pair_warnings", "self_crossing_pairs",
           "evaluate", "mdc",
           "drape_error", "vertex_error", "per_vertex_change", "training_garments", "check_model",
           "check_after_training", "check_lines", "fit_to_pose", "fit_poses", "in_threads", "posed_counts",
           "poses_to_files", "every_split",
           "self_contact",
           "transfer_across_rest_poses", "outfit_across_rest_poses", "pose_difference", "fold_warnings",
           "untangle_text", "target_at_rest", "Catalogue", "read_catalogue", "run_batch", "BatchSummary"]
