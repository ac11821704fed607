"""A target body in another rest pose: the source body and its garment posed into it first, then the shape."""

import numpy as np
from meshes import require_makehuman

from garment_transfer import (Rig, bvh_rotations, fit_to_pose, read_bvh, read_joints, read_obj, read_skeleton,
                              read_weights, transfer_garment)
from garment_transfer.pipeline.rest_pose import pose_difference, transfer_across_rest_poses


def rigs():
    root = require_makehuman()
    skeleton = read_skeleton(root / "rig" / "skeleton.json")
    weights = read_weights(root / "rig" / "weights.json", 13380)
    out = {}
    for name in ("female_average", "female_pear"):
        out[name] = (read_obj(root / "bodies" / f"{name}.obj"),
                     Rig(skeleton, read_joints(root / "rig" / "joints" / f"{name}.json"), weights))
    return root, skeleton, out


def test_the_same_rest_pose_is_a_plain_transfer():
    root, _, bodies = rigs()
    (source, source_rig), (target, target_rig) = bodies["female_average"], bodies["female_pear"]
    garment = read_obj(root / "garments" / "female_sportsuit01" / "female_average.obj")
    R, turns = pose_difference(source_rig, target_rig.joints)
    assert max(turns.values()) < 25.0
    result, registration = transfer_across_rest_poses(source, target, garment, source_rig, target_rig.joints)
    assert registration is None and result.info["rest_pose"]["posed"] is False
    assert np.array_equal(result.V, transfer_garment(source, target, garment).V)


def test_a_target_in_another_rest_pose_gets_the_garment_as_if_transferred_at_rest_then_fitted_to_the_pose():
    root, skeleton, bodies = rigs()
    (source, source_rig), (target, target_rig) = bodies["female_average"], bodies["female_pear"]
    garment = read_obj(root / "garments" / "female_sportsuit01" / "female_average.obj")
    T = target_rig.transforms(bvh_rotations(read_bvh(root / "poses" / "fight01.bvh"), skeleton))
    posed = target.with_vertices(target_rig.pose(target.V, T), name="pear kicking")
    at_rest = garment.with_vertices(transfer_garment(source, target, garment).V)
    expected = fit_to_pose(target, posed.V, at_rest).V
    result, _ = transfer_across_rest_poses(source, posed, garment, source_rig, target_rig.posed_joints(T),
                                           target_rig.posed_frames(T))
    info = result.info["rest_pose"]
    assert info["posed"] and info["largest_turn"] > 45 and info["largest_turn_bone"] in ("upperarm02.R", "lowerleg01.L")
    assert result.info["crossings_outside_contact"] == 0
    assert np.linalg.norm(result.V - expected, axis=1).mean() < 0.03      # 3 mm, in decimetres
