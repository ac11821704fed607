"""The motion study's poses kept back (``lab.motion``): mirrors and blends of the shared poses, checked on the real
skeleton, and its crossing count split by the body's own contact, against counting the two parts apart."""

import numpy as np

import garment_transfer as gt
from lab import motion
from tests.meshes import require_makehuman


def mirrored_joint(name):
    bone, _, end = name.partition("____")
    return f"{motion.mirror_name(bone)}____{end}"


def test_a_mirrored_pose_poses_the_body_as_the_mirror_image_and_blends_go_between():
    root = require_makehuman()
    skeleton = gt.read_skeleton(root / "rig" / "skeleton.json")
    weights = gt.read_weights(root / "rig" / "weights.json", 13380)
    rig = motion.rig_of(root, "female_average", skeleton, weights)
    poses = motion.pose_set(root, skeleton)
    assert set(motion.POSES) < set(poses) and "run01_mirror" in poses and "rest+sit01" in poses
    R, Rm = poses["run01"], poses["run01_mirror"]
    assert np.allclose(motion.mirrored_rotations(Rm, skeleton), R, atol=1e-12)
    # The mirrored pose moves each joint to the mirror image of where the pose moves its mirror joint; the body's
    # joints are symmetric to within a few millimetres, the pose moves them by decimetres.
    joints, mirrored = rig.posed_joints(rig.transforms(R)), rig.posed_joints(rig.transforms(Rm))
    names = [n for n in joints if mirrored_joint(n) in joints]
    a = np.array([mirrored[n] for n in names])
    b = np.array([joints[mirrored_joint(n)] * [-1, 1, 1] for n in names])
    rest = np.array([rig.joints[n] for n in names])
    assert np.abs(a - rest).max() > 3.0                      # decimetres: the run moves the limbs far
    assert np.abs(a - b).max() < 0.1                         # within a centimetre of the mirror image
    # A blend is halfway along each bone's turn: from the rest pose, half the angle of the pose.
    from scipy.spatial.transform import Rotation

    half = Rotation.from_matrix(poses["rest+sit01"]).magnitude()
    full = Rotation.from_matrix(poses["sit01"]).magnitude()
    assert np.allclose(half, full / 2, atol=1e-9) and full.max() > 1.0
    assert np.allclose(motion.blended_rotations(R, Rm, 0.0), R) and np.allclose(motion.blended_rotations(R, Rm, 1.0),
                                                                                Rm)


def test_crossings_away_from_contact_are_those_counted_against_the_body_without_its_contact():
    root = require_makehuman()
    skeleton = gt.read_skeleton(root / "rig" / "skeleton.json")
    weights = gt.read_weights(root / "rig" / "weights.json", 13380)
    body = gt.read_obj(root / "bodies" / "female_pear.obj")
    garment = gt.read_obj(root / "garments" / "female_sportsuit01" / "female_pear.obj")
    rig = motion.rig_of(root, "female_pear", skeleton, weights)
    T = rig.transforms(motion.pose_set(root, skeleton, ["run01"], kept_back=False)["run01"])
    posed = motion.PosedBody(body, rig.pose(body.V, T), gt.OFFSET_SHARE * gt.body_scale(body.V))
    V = rig.pose(garment.V, T, gt.nearest_weights(body.V, body.F, weights, garment.V))
    F = gt.every_split(garment)
    figures = motion.crossing_figures(V, F, posed)
    whole = gt.crossings(V, F, posed.V, posed.F)
    free = gt.crossings(V, F, posed.V, posed.F[posed.free_triangle])
    # The running body crosses itself (an arm, the thighs): crossings at its contact and away from it.
    total = whole["a_edges_through_b"] + whole["b_edges_through_a"]
    assert figures["crossings"] == total > figures["away_from_contact"]
    assert 0 < figures["away_from_contact"] == free["a_edges_through_b"] + free["b_edges_through_a"]
    assert posed.self_crossings > 0 and not posed.free_triangle.all()
