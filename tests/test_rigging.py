"""The rig layer: skeletons, BVH files, linear blend skinning, weights and their transfer, with exact answers."""

import json

import numpy as np
import pytest
import scipy.sparse as sp

from garment_transfer import (MeshError, RigError, Rig, axes_between, body_scale, bvh_rotations, inpainted_weights,
                              matching_rotations, nearest_weights, parse_bvh, pose_transforms, read_bvh,
                              read_joints, read_skeleton, read_weights, riding_share, skin, skin_weights,
                              unweighted_vertices, write_weights)
from garment_transfer.rigging import (bone_frames, cotangent_laplacian, group_transforms, inpaint, match,
                                      skeleton_from_dict, smoothness_matrix, weights_from_dict)
from tests.meshes import grid, icosphere, in_pieces, random_rotation, require_makehuman

TINY_BVH = """HIERARCHY
ROOT hips
{
  OFFSET 0 0 1
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT knee
  {
    OFFSET 0 0 -0.5
    CHANNELS 3 Xrotation Yrotation Zrotation
    End Site
    {
      OFFSET 0 0 -0.5
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.04
0 0 1 0 0 0 0 0 0
0.5 0 1 90 0 0 30 0 0
"""

#: Three bones in the xy plane: hips -> thigh -> shin, the first two rolled by the plane of their joints.
CHAIN = {"bones": {"hips": {"parent": None, "head": "j0", "tail": "j1", "rotation_plane": "p"},
                   "thigh": {"parent": "hips", "head": "j1", "tail": "j2", "rotation_plane": "p"},
                   "shin": {"parent": "thigh", "head": "j2", "tail": "j3", "rotation_plane": None}},
         "planes": {"p": ["j0", "j1", "j2"]}}
CHAIN_JOINTS = {"j0": np.array([0.0, 0, 0]), "j1": np.array([1.0, 0, 0]), "j2": np.array([2.0, 0, 0]),
                "j3": np.array([3.0, 0, 0])}
CHAIN_JOINTS["j2"] = np.array([1.0, 1.0, 0])


def rot_z(degrees):
    a = np.radians(degrees)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def test_bvh_of_a_tiny_file_is_read_exactly():
    m = parse_bvh(TINY_BVH, "tiny.bvh")
    assert m.names == ("hips", "knee") and list(m.parents) == [-1, 0]
    assert np.array_equal(m.offsets, [[0, 0, 1], [0, 0, -0.5]])
    assert m.channels[0][3:] == ("Zrotation", "Xrotation", "Yrotation")
    assert m.n_frames == 2 and m.frame_time == 0.04
    assert np.allclose(m.rotations(0), np.eye(3))
    R = m.rotations(1)
    assert np.allclose(R[0], rot_z(90)) and np.allclose(R[0] @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(R[1] @ [0, 1, 0], [0, np.cos(np.radians(30)), np.sin(np.radians(30))])
    assert np.allclose(m.root_position(1), [0.5, 0, 1])
    with pytest.raises(RigError, match="no frame 2"):
        m.rotations(2)


def test_bvh_rotations_follow_the_channel_order():
    # Zrotation then Xrotation: R = Rz Rx, not Rx Rz.
    text = TINY_BVH.replace("0.5 0 1 90 0 0 30 0 0", "0 0 0 90 90 0 0 0 0")
    R = parse_bvh(text).rotations(1)[0]
    a = np.radians(90)
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    assert np.allclose(R, rot_z(90) @ Rx) and not np.allclose(R, Rx @ rot_z(90))


@pytest.mark.parametrize("text, problem", [
    ("", "not a BVH"),
    (TINY_BVH.replace("MOTION", ""), "MOTION"),
    (TINY_BVH.replace("Frames: 2", "Frames: 3"), "3 frames of 9 channels but has 18"),
    (TINY_BVH.replace("Xrotation Yrotation Zrotation", "Xrotation Yrotation Wrotation"), "unknown channels"),
    (TINY_BVH.replace("0.5 0 1 90", "0.5 0 1 nan"), "not finite"),
    (TINY_BVH.replace("  }\n}\nMOTION", "  }\nMOTION"), "left open"),
])
def test_a_broken_bvh_file_is_refused_by_name(text, problem):
    with pytest.raises(RigError, match=problem) as e:
        parse_bvh(text, "walk.bvh")
    assert "walk.bvh" in str(e.value)


def test_axes_from_z_up_to_y_up():
    M = axes_between("Z", "Y")
    assert np.allclose(M @ [0, 0, 1], [0, 1, 0]) and np.allclose(M @ [0, -1, 0], [0, 0, 1])
    assert np.allclose(axes_between("Y", "Z") @ M, np.eye(3)) and np.allclose(axes_between("Y", "Y"), np.eye(3))


def chain():
    return skeleton_from_dict(CHAIN, "chain")


def test_skeleton_orders_parents_first_and_refuses_loops():
    shuffled = {"bones": dict(reversed(list(CHAIN["bones"].items()))), "planes": CHAIN["planes"]}
    s = skeleton_from_dict(shuffled, "chain")
    assert s.names == ("hips", "thigh", "shin") and list(s.parents) == [-1, 0, 1]
    loop = json.loads(json.dumps(CHAIN))
    loop["bones"]["hips"]["parent"] = "shin"
    with pytest.raises(RigError, match="own ancestors"):
        skeleton_from_dict(loop, "loop.json")
    with pytest.raises(RigError, match="lack 1 joints"):
        s.rest({k: v for k, v in CHAIN_JOINTS.items() if k != "j3"})


def test_bone_frames_are_makehumans_y_along_the_bone_z_across_the_plane():
    F = bone_frames(chain(), CHAIN_JOINTS)
    # The plane j0, j1, j2 is the xy plane; its normal (p3-p2) x (p2-p1) is -Z; Z = normal x Y.
    assert np.allclose(F[0][:, 1], [1, 0, 0]) and np.allclose(F[0][:, 2], np.cross([0, 0, -1], [1, 0, 0]))
    assert np.allclose(F[1][:, 1], [0, 1, 0]) and np.allclose(F[1][:, 2], np.cross([0, 0, -1], [0, 1, 0]))
    assert np.allclose(np.einsum("bij,bik->bjk", F, F), np.eye(3)) and np.allclose(np.linalg.det(F), 1)


def test_lbs_of_a_single_bone_rotation_is_exact():
    s = chain()
    heads, _ = s.rest(CHAIN_JOINTS)
    R = np.tile(np.eye(3), (3, 1, 1))
    R[1] = rot_z(90)                                    # the thigh turns about its head at x = 1
    T = pose_transforms(s, heads, R)
    V = np.array([[0.5, 0, 0], [1.5, 0.2, 0], [2.5, 0, 0.3], [1.5, 0, 0]])
    W = skin_weights(s.names, np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0.5, 0]], float))
    out = skin(V, W, group_transforms(W, s, T))
    assert np.allclose(out[0], V[0])                    # the hips do not move
    assert np.allclose(out[1], [1 - 0.2, 0.5, 0])       # turned 90 degrees about the thigh's head (1, 0, 0)
    assert np.allclose(out[2], [1, 1.5, 0.3])           # the shin is carried by the thigh
    assert np.allclose(out[3], [1, 0.5, 0])             # half a weight, alone: normalised to one


def test_lbs_blends_two_bones_linearly_and_leaves_unweighted_vertices():
    s = chain()
    heads, _ = s.rest(CHAIN_JOINTS)
    R = np.tile(np.eye(3), (3, 1, 1))
    R[1] = rot_z(90)
    T = pose_transforms(s, heads, R)
    V = np.array([[1.5, 0, 0], [7.0, 7.0, 7.0]])
    W = skin_weights(s.names, np.array([[0.3, 0.3, 0], [0, 0, 0]]))
    out = skin(V, W, group_transforms(W, s, T))
    assert np.allclose(out[0], 0.5 * V[0] + 0.5 * np.array([1, 0.5, 0]))
    assert np.array_equal(out[1], V[1])


def test_pose_transforms_carry_children_and_keep_rigid_bones():
    rng = np.random.default_rng(3)
    s = chain()
    heads, tails = s.rest(CHAIN_JOINTS)
    R = np.stack([random_rotation(rng) for _ in range(3)])
    T = pose_transforms(s, heads, R)
    rig = Rig(s, CHAIN_JOINTS, skin_weights(s.names, np.eye(3)))
    posed = rig.posed_joints(T)
    G01 = R[0] @ R[1]
    assert np.allclose(posed["j0"], heads[0])
    assert np.allclose(posed["j2"], heads[0] + R[0] @ [1, 0, 0] + G01 @ [0, 1, 0])
    assert np.allclose(posed["j3"], posed["j2"] + G01 @ R[2] @ [2, -1, 0])
    # Each bone's transform is rigid: distances between posed points of one bone are kept.
    assert np.allclose(np.einsum("bij,bkj->bik", T[:, :, :3], T[:, :, :3]), np.eye(3))


def test_matching_rotations_find_a_pose_from_the_posed_joints():
    rng = np.random.default_rng(5)
    s = chain()
    heads, _ = s.rest(CHAIN_JOINTS)
    rig = Rig(s, CHAIN_JOINTS, skin_weights(s.names, np.eye(3)))
    # Any pose: every joint where the pose put it (the directions of the bones).
    R = np.stack([random_rotation(rng) for _ in range(3)])
    posed = rig.posed_joints(pose_transforms(s, heads, R))
    found, angles = matching_rotations(s, CHAIN_JOINTS, posed)
    again = rig.posed_joints(pose_transforms(s, heads, found))
    for joint in ("j0", "j1", "j2", "j3"):
        assert np.allclose(again[joint], posed[joint])
    assert angles.shape == (3,) and (angles >= 0).all()
    # The whole skeleton turned: the planes turn with it and fix the roll, so the rotations are found exactly.
    R = np.tile(np.eye(3), (3, 1, 1))
    R[0] = random_rotation(rng)
    found, angles = matching_rotations(s, CHAIN_JOINTS, rig.posed_joints(pose_transforms(s, heads, R)))
    assert np.allclose(found[:2], R[:2]) and np.isclose(angles[0], angles[1])
    same, none = matching_rotations(s, CHAIN_JOINTS, CHAIN_JOINTS)
    assert np.allclose(same, np.eye(3)) and np.allclose(none, 0, atol=1e-6)


def test_weights_normalised_and_limited_to_k_influences():
    rng = np.random.default_rng(0)
    dense = rng.random((50, 12)) * (rng.random((50, 12)) < 0.6)
    dense[7] = 0
    w = skin_weights([f"b{i}" for i in range(12)], dense)
    for k in (1, 4, 8):
        lim = w.limited(k)
        assert lim.influences().max() <= k
        s = lim.sums()
        assert np.allclose(s[dense.sum(axis=1) > 0], 1) and s[7] == 0
        row = lim.W[3].toarray().ravel()
        largest = np.argsort(-dense[3])[:min(k, (dense[3] > 0).sum())]
        assert set(np.flatnonzero(row)) == set(largest)
        assert np.allclose(row[largest], dense[3][largest] / dense[3][largest].sum())
    with pytest.raises(ValueError):
        w.limited(0)


def test_weights_files_round_trip_and_bad_ones_are_refused(tmp_path):
    dense = np.array([[0.25, 0.75], [1.0, 0.0], [0.0, 0.0]])
    w = skin_weights(["arm", "hand"], dense, "sleeve")
    path = tmp_path / "w.json"
    write_weights(path, w)
    back = read_weights(path, 3)
    assert back.groups == ("arm", "hand") and np.allclose(back.dense(), dense)
    assert json.loads(path.read_text())["weights"]["arm"] == [[0, 0.25], [1, 1.0]]
    assert np.allclose(weights_from_dict({"arm": [[0, 0.25], [1, 1]], "hand": [[0, 0.75]]}, 3).dense(), dense)
    with pytest.raises(RigError, match="refers to vertex 1, but the mesh has 1"):
        read_weights(path, 1)
    for bad, problem in ((b"{", "not a JSON"), (b'{"arm": [[0.5, 1]]}', "whole number"),
                         (b'{"arm": [[0, -1]]}', "negative"), (b"[1, 2]", "not a mapping")):
        path.write_bytes(bad)
        with pytest.raises(RigError, match=problem):
            read_weights(path)


def test_inpainting_reproduces_a_linear_field():
    mesh = grid(12, 10, wave=0.0)
    V, F = mesh.V, mesh.F
    L = cotangent_laplacian(V, F)
    assert abs(L - L.T).max() < 1e-12 and np.allclose(L.sum(axis=1), 0)
    linear = np.stack([2 * V[:, 0] - V[:, 1] + 0.5, V[:, 1]], axis=1)
    # Fixed: two rings at the border (the biharmonic term sees two rings); free: the inside.
    border = (np.minimum.reduce([V[:, 0], V[:, 1], V[:, 0].max() - V[:, 0], V[:, 1].max() - V[:, 1]])
              < 2.5 * (V[1, 0] - V[0, 0]) - 1e-9)
    values = np.where(border[:, None], linear, 0.0)
    X = inpaint(smoothness_matrix(V, F), border, values)
    assert (~border).sum() > 20 and np.allclose(X, linear, atol=1e-10)


def sphere_rig():
    """A body (a sphere of radius 1) with two weight groups that change linearly from bottom to top."""
    V, F = icosphere(3)
    up = 0.5 * (V[:, 2] + 1)
    return V, F, skin_weights(["low", "high"], np.stack([1 - up, up], axis=1), "sphere weights")


def test_inpainted_weights_match_where_close_and_facing_and_fill_the_rest():
    V, F, W = sphere_rig()
    # A garment: a sphere a little larger (matched everywhere but a cap pulled far out).
    G, GF = icosphere(2, radius=1.02)
    far = G[:, 2] > 0.8
    G = G.copy()
    G[far] *= 1.5
    weights, info = inpainted_weights(V, F, W, G, GF, max_influences=4)
    near = nearest_weights(V, F, W, G)
    matched = match(V, F, G, GF)[0]
    assert not matched[far].any() and matched.sum() > 0.8 * (~far).sum()
    assert info["matched"] == matched.sum() and info["inpainted"] == (~matched).sum()
    assert np.allclose(weights.dense()[matched], near.dense()[matched])
    assert np.allclose(weights.sums(), 1) and weights.influences().max() <= 4
    # The cap is filled from the matched rim around it: within the rim's weights.
    rim = matched & (G[:, 2] > 0.5)
    high = weights.dense()[~matched, 1]
    assert high.min() >= weights.dense()[rim, 1].min() - 1e-9 and high.max() <= 1.0
    assert weights.groups == W.groups


def test_inpainted_weights_turn_a_garment_wound_inside_out():
    V, F, W = sphere_rig()
    G, GF = icosphere(2, radius=1.02)
    a, _ = inpainted_weights(V, F, W, G, GF)
    b, info = inpainted_weights(V, F, W, G, GF[:, ::-1])
    assert info["inpainted"] == 0 and np.allclose(a.dense(), b.dense())


def test_a_piece_far_from_the_body_takes_its_nearest_vertex_weights():
    V, F, W = sphere_rig()
    G, GF = icosphere(2, radius=1.02)
    B, BF = icosphere(1, radius=0.05, centre=(0, 0, 1.4))     # a button floating above the top
    garment_V, garment_F = np.vstack([G, B]), np.vstack([GF, BF + len(G)])
    weights, info = inpainted_weights(V, F, W, garment_V, garment_F, max_influences=None)
    button = weights.dense()[len(G):]
    assert np.allclose(button, button[0]) and button[0, 1] > 0.99
    assert info["inpainted"] == len(B) - 1 and len(info["warnings"]) == 1 and "1 pieces" in info["warnings"][0]
    with pytest.raises(MeshError, match="far from the body"):
        inpainted_weights(V, F, W, B + [0, 0, 3], BF, name="lost button")


def test_riding_share_is_one_on_the_skin_none_where_the_cloth_hangs_free_and_a_ramp_between():
    V, F, _ = sphere_rig()
    G, GF = icosphere(2)
    # Each vertex at its own height above the unit sphere: from on the skin (bottom) to 10 cm off (top), facing out.
    lift = 0.05 * (G[:, 2] + 1)
    G = G * (1 + lift)[:, None]
    full, none = 0.01, 0.06
    share = riding_share(V, F, G, GF, full=full, none=none, smoothing=0)
    dist = np.linalg.norm(G, axis=1) - 1                       # the sphere's facets are within 1 mm of r = 1
    assert np.all(share[dist < full - 2e-3] == 1) and np.all(share[dist > none + 2e-3] == 0)
    ramp = (dist > full + 2e-3) & (dist < none - 2e-3)
    assert ramp.sum() > 20 and np.allclose(share[ramp], (none - dist[ramp]) / (none - full), atol=0.05)
    # A patch standing on edge 2-5 cm above the top faces across the skin: it does not ride; laid flat it does.
    a, b = np.meshgrid(np.linspace(-0.05, 0.05, 6), np.linspace(0.02, 0.05, 4))
    PF = np.array([[i * 6 + j, i * 6 + j + 1, (i + 1) * 6 + j] for i in range(3) for j in range(5)]
                  + [[i * 6 + j + 1, (i + 1) * 6 + j + 1, (i + 1) * 6 + j] for i in range(3) for j in range(5)])
    standing = np.stack([a.ravel(), np.zeros(a.size), 1 + b.ravel()], axis=1)
    flat = np.stack([a.ravel(), b.ravel() - 0.035, 1 + b.ravel()], axis=1)
    flat[:, 2] = 1.03
    assert np.all(riding_share(V, F, standing, PF, full=full, none=none, smoothing=0) == 0)
    assert np.all(riding_share(V, F, flat, PF, full=full, none=none, smoothing=0) > 0.4)
    # Smoothing keeps the share within [0, 1] and spreads it: no edge joins a vertex riding fully to a free one.
    smooth = riding_share(V, F, G, GF, full=full, none=none)
    edges = np.vstack([GF[:, [0, 1]], GF[:, [1, 2]], GF[:, [2, 0]]])
    assert smooth.min() >= 0 and smooth.max() <= 1
    assert np.abs(np.diff(smooth[edges], axis=1)).max() < np.abs(np.diff(share[edges], axis=1)).max()
    # Defaults: shares of the body's scale.
    default = riding_share(V, F, G, GF, smoothing=0)
    scale = body_scale(V)
    assert np.all(default[dist < 0.005 * scale - 2e-3] == 1) and np.all(default[dist > 0.02 * scale + 2e-3] == 0)
    with pytest.raises(ValueError, match="riding distances"):
        riding_share(V, F, G, GF, full=0.05, none=0.01)


def test_weight_transfer_refuses_mismatched_weights_and_empty_garments():
    V, F, W = sphere_rig()
    G, GF = icosphere(1, radius=1.02)
    with pytest.raises(RigError, match="sphere weights"):
        inpainted_weights(V[:-1], F[F.max(axis=1) < V.shape[0] - 1], W, G, GF)
    with pytest.raises(MeshError, match="cape"):
        inpainted_weights(V, F, W, G, np.zeros((0, 3), int), name="cape")
    assert sp.issparse(weights_from_dict({"a": []}, 3).W)


def test_makehuman_rig_poses_a_body_and_round_trips_its_pose():
    root = require_makehuman()
    from garment_transfer import read_obj

    skeleton = read_skeleton(root / "rig" / "skeleton.json")
    body = read_obj(root / "bodies" / "female_average.obj")
    joints = read_joints(root / "rig" / "joints" / "female_average.json")
    rig = Rig(skeleton, joints, read_weights(root / "rig" / "weights.json", body.n_vertices))
    assert skeleton.n_bones == 163 and rig.weights.groups[0] in skeleton.names
    rest = rig.transforms(np.tile(np.eye(3), (skeleton.n_bones, 1, 1)))
    assert np.allclose(rig.pose(body.V, rest), body.V)
    motion = read_bvh(root / "poses" / "sit01.bvh")
    T = rig.transforms(bvh_rotations(motion, skeleton))
    joints_posed = rig.posed_joints(T)
    # Sitting on the floor (Y up, +Z forward, decimetres): the right leg stretched out in front, level with the
    # hip; the left knee raised.
    hip, knee, ankle = ([joints_posed[f"{b}.{side}____{e}"] for side in "RL"] for b, e in
                        (("upperleg01", "head"), ("upperleg02", "tail"), ("lowerleg02", "tail")))
    assert abs(knee[0][1] - hip[0][1]) < 0.5 and abs(ankle[0][1] - hip[0][1]) < 0.5 and ankle[0][2] > hip[0][2] + 6
    assert knee[1][1] > hip[1][1] + 2 and knee[1][1] > ankle[1][1] + 2
    R, angles = matching_rotations(skeleton, joints, joints_posed)
    again = rig.posed_joints(rig.transforms(R))
    err = max(np.linalg.norm(again[j] - joints_posed[j]) for j in skeleton.heads)
    assert err < 1e-9 and angles.max() > 45


def test_cloth_left_with_no_weight_is_counted_and_said_and_none_weighted_is_said_so():
    V, F, W = sphere_rig()
    # The body's weights left empty on its top cap (a region not painted).
    bare = V[:, 2] > 0.5
    W = skin_weights(W.groups, W.dense() * ~bare[:, None], "cap-less weights")
    G, GF = icosphere(2, radius=1.02)
    weights, info = inpainted_weights(V, F, W, G, GF, max_influences=None, name="shirt")
    # Every vertex is matched, so each takes the weights at its closest body point: none where that point's
    # triangle has only unweighted corners.
    expected = int((nearest_weights(V, F, W, G).sums() <= 0).sum())
    assert info["inpainted"] == 0 and 0 < expected < len(G)
    assert info["unweighted"] == expected == int((weights.sums() <= 0).sum())
    assert np.allclose(weights.sums()[weights.sums() > 0], 1)
    assert info["warnings"] == [
        f"{expected} of the {len(G)} vertices of shirt have no weight ({int(bare.sum())} of the body's {len(V)} "
        "vertices have none in cap-less weights, where the garment takes its weights from them): they stay where "
        "they are when the bones move; give the body weights there"]
    assert unweighted_vertices(weights, W, "shirt") == (expected, info["warnings"])
    # A cap of cloth over that region only: no vertex has a weight.
    cap = np.flatnonzero(G[:, 2] > 0.75)
    keep = np.isin(GF, cap).all(axis=1)
    local = np.full(len(G), -1)
    local[cap] = np.arange(cap.size)
    weights, info = inpainted_weights(V, F, W, G[cap], local[GF[keep]], name="hat")
    assert info["unweighted"] == cap.size and weights.W.nnz == 0
    assert info["warnings"][-1].startswith(f"none of the {cap.size} vertices of hat has a weight (")
    # Every vertex weighted: nothing said.
    painted, info = inpainted_weights(V, F, sphere_rig()[2], G, GF)
    assert info["unweighted"] == 0 and unweighted_vertices(painted, W, "shirt") == (0, [])


def test_a_garment_whose_pieces_are_not_joined_is_weighted_as_the_joined_one():
    V, F, W = sphere_rig()
    # A garment matched but for a cap pulled far out (inpainted), cut into two pieces at x = 0 (each vertex they
    # share written again for the second piece): the inpainting of each piece alone gives a seam vertex and its
    # twin other weights, which skinning would pull apart.
    G, GF = icosphere(2, radius=1.02)
    G = G.copy()
    G[G[:, 2] > 0.6] *= 1.5
    PV, PF, seam, twin = in_pieces(G, GF)
    pieces, info = inpainted_weights(V, F, W, PV, PF, max_influences=None)
    joined, joined_info = inpainted_weights(V, F, W, G, GF, max_influences=None)
    # Counted per vertex of the file: a twin of an inpainted seam vertex is inpainted too.
    unmatched_seam = int((~match(V, F, G, GF)[0][seam]).sum())
    assert info["inpainted"] > 0 and info["inpainted"] == joined_info["inpainted"] + unmatched_seam
    D = pieces.dense()
    assert np.array_equal(D[:len(G)], joined.dense()) and np.array_equal(D[len(G):], D[seam])
    # So is the share of the cloth that rides the skin (averaged over neighbours: across the seam, as one).
    share = riding_share(V, F, PV, PF)
    assert np.array_equal(share[:len(G)], riding_share(V, F, G, GF)) and np.array_equal(share[len(G):], share[seam])
