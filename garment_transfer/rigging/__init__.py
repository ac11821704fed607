"""Rigging: skeletons, poses and skinning weights, so that a garment moves with a character. ``skeleton``
reads a skeleton (bones between named joints, each rolled by a plane of three joints: MakeHuman's layout) and
places it on a body by that body's joints; ``bvh`` reads motion files; ``skinning`` holds weights (named groups,
sparse, read and written as JSON), their normalisation and limit to a few influences, and linear blend skinning;
``posing`` applies a BVH pose with each body's own joints and finds the rotations that take one body's skeleton
into another's pose (a bone's turn about itself from the other's bone frames, or from its body:
``twist_from_body``); ``weight_transfer`` carries a body's weights to a garment, by the nearest surface point or
matched where the surfaces agree and inpainted smoothly elsewhere; ``naming`` finds the joints a body bends at in
skeletons named otherwise (Mixamo's, Rigify's, Unreal's) and poses one skeleton onto another's by them. Built on
``geometry`` only.
"""

from .bvh import Motion, axes_between, parse_bvh, read_bvh
from .naming import (NAMINGS, Landmarks, bone_key, bones_from_dict, landmarks_of, naming_of, pose_to_landmarks,
                     read_target_frames, read_target_skeleton)
from .posing import Rig, bvh_rotations, matching_rotations, rig_from_bones, twist_from_body
from .skeleton import Skeleton, bone_frames, plane_normals, read_joints, read_skeleton, skeleton_from_dict
from .skinning import (SkinWeights, deforming, group_transforms, pose_transforms, read_weights, skin, skin_weights,
                       weights_from_dict, weights_to_dict, write_weights)
from .weight_transfer import (MATCH_ANGLE, MATCH_DISTANCE_SHARE, MAX_INFLUENCES, cotangent_laplacian, inpaint,
                              inpainted_weights, match, nearest_weights, riding_share, smoothness_matrix,
                              surface_weights, unweighted_vertices)

__all__ = ["Skeleton", "read_skeleton", "read_joints", "skeleton_from_dict", "bone_frames", "plane_normals",
           "Motion", "read_bvh", "parse_bvh", "axes_between", "SkinWeights", "skin_weights", "read_weights",
           "write_weights", "weights_from_dict", "weights_to_dict", "skin", "pose_transforms", "group_transforms",
           "deforming", "Rig", "rig_from_bones", "bvh_rotations", "matching_rotations", "twist_from_body",
           "surface_weights", "unweighted_vertices",
           "nearest_weights", "inpainted_weights", "riding_share", "match", "inpaint", "cotangent_laplacian",
           "smoothness_matrix", "MATCH_ANGLE", "MATCH_DISTANCE_SHARE", "MAX_INFLUENCES", "Landmarks", "landmarks_of",
           "naming_of", "pose_to_landmarks", "read_target_skeleton", "read_target_frames", "bones_from_dict",
           "bone_key", "NAMINGS"]
