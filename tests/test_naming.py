"""Skeletons named otherwise (Mixamo's, Rigify's, Unreal's): found by their bones, posed onto by the joints a body
bends at, and a target of such a skeleton in another rest pose from the command line."""

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_rest_pose import in_pose, rig_options, rigs

from garment_transfer import (NAMINGS, RigError, bvh_rotations, fit_to_pose, landmarks_of, matching_rotations,
                              naming_of, pose_to_landmarks, read_bvh, read_obj, read_target_skeleton,
                              transfer_garment, write_obj)
from lab.rest_pose_study import bones_data, named_bones


def _about(axis, angle):
    return Rotation.from_rotvec(angle * np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)).as_matrix()


def segments_pose(skeleton, rig):
    """Local rotations that turn the trunk and swing four segments at their first bone (no twist, no bend inside a
    segment): what landmarks tell exactly."""
    heads, _ = rig.rest()
    R = np.tile(np.eye(3), (skeleton.n_bones, 1, 1))
    R[skeleton.index("root")] = _about([0, 1, 0], 0.4) @ _about([1, 0, 0], 0.1)
    for bone, end, angle, helper in (("upperarm01.L", "lowerarm01.L", 0.6, [0, 0, 1]),
                                     ("upperarm01.R", "lowerarm01.R", -0.5, [0, 0, 1]),
                                     ("upperleg01.L", "lowerleg01.L", 0.3, [1, 0, 0]),
                                     ("lowerleg01.R", "foot.R", 0.7, [1, 0, 0])):
        d = heads[skeleton.index(end)] - heads[skeleton.index(bone)]
        R[skeleton.index(bone)] = _about(np.cross(d, helper), angle)
    return R


def test_each_naming_is_found_by_its_bones_whatever_the_namespace_and_case():
    _, skeleton, bodies = rigs()
    rig = bodies["female_average"][1]
    assert naming_of(skeleton.names) == "MakeHuman"
    for naming in NAMINGS:
        bones = named_bones(skeleton, rig.joints, naming, spine=3 if naming in ("Mixamo", "Rigify", "Unreal") else 0)
        assert naming_of(bones) == naming
        upper = {f"character1:{b.upper()}": v for b, v in bones.items()}
        assert naming_of(upper) == naming
    # A knee missing: no naming, and the skeleton is named in the error.
    bones = named_bones(skeleton, rig.joints, "Mixamo", prefix="mixamorig:")
    del bones["mixamorig:LeftLeg"]
    assert naming_of(bones) is None
    with pytest.raises(RigError, match="hero_rig: has bones named in none of the ways known"):
        landmarks_of(bones, "hero_rig")


def test_a_bones_file_with_each_bones_roll_gives_the_targets_frames_exactly(tmp_path):
    from garment_transfer import read_target_frames

    root, skeleton, bodies = rigs()
    body, rig = bodies["female_pear"]
    T, _ = in_pose(root, skeleton, body, rig, "run01")
    joints, frames = rig.posed_joints(T), rig.posed_frames(T)
    # The running pear's bones as an armature has them: head, tail and Z axis (lengthened and tilted along the bone:
    # only its direction across the bone counts).
    y = np.array([joints[t] - joints[h] for h, t in zip(skeleton.heads, skeleton.tails)])
    own = {b: {"parent": None if p < 0 else skeleton.names[p], "head": joints[h].tolist(), "tail": joints[t].tolist(),
               "z_axis": (3.0 * frames[i][:, 2] + 0.5 * y[i]).tolist()}
           for i, (b, p, h, t) in enumerate(zip(skeleton.names, skeleton.parents, skeleton.heads, skeleton.tails))}
    (tmp_path / "bones.json").write_text(json.dumps({"bones": own}))
    assert np.abs(read_target_frames(tmp_path / "bones.json", skeleton) - frames).max() < 1e-12
    R_file, _ = matching_rotations(skeleton, rig.joints, read_target_skeleton(tmp_path / "bones.json", skeleton),
                                   read_target_frames(tmp_path / "bones.json", skeleton))
    R_true, _ = matching_rotations(skeleton, rig.joints, joints, frames)
    assert np.abs(R_file - R_true).max() < 1e-9
    # No roll given, or another skeleton's bones: no frames. A roll given for some bones only, or along its bone:
    # refused, naming the file and the bone.
    plain = {b: {k: v for k, v in spec.items() if k != "z_axis"} for b, spec in own.items()}
    (tmp_path / "plain.json").write_text(json.dumps({"bones": plain}))
    assert read_target_frames(tmp_path / "plain.json", skeleton) is None
    assert read_target_frames(root / "rig" / "joints" / "female_pear.json", skeleton) is None
    (tmp_path / "rigify.json").write_text(json.dumps(bones_data(named_bones(skeleton, joints, "Rigify", spine=3))))
    assert read_target_frames(tmp_path / "rigify.json", skeleton) is None
    some = dict(plain, root=own["root"])
    (tmp_path / "some.json").write_text(json.dumps({"bones": some}))
    with pytest.raises(RigError, match=rf"some.json: bone '{skeleton.names[1]}' has no z_axis where others have one"):
        read_target_frames(tmp_path / "some.json", skeleton)
    along = dict(own, root=dict(own["root"], z_axis=y[skeleton.index("root")].tolist()))
    (tmp_path / "along.json").write_text(json.dumps({"bones": along}))
    with pytest.raises(RigError, match=r"along.json: bone 'root': its z_axis lies along the bone"):
        read_target_frames(tmp_path / "along.json", skeleton)


@pytest.mark.parametrize("naming", list(NAMINGS))
def test_a_pose_of_whole_segments_is_found_exactly_through_every_naming(naming):
    _, skeleton, bodies = rigs()
    body, rig = bodies["female_average"]
    T = rig.transforms(segments_pose(skeleton, rig))
    truth = rig.posed_joints(T)
    bones = named_bones(skeleton, truth, naming, spine=3 if naming in ("Mixamo", "Rigify", "Unreal") else 0)
    joints, segments = pose_to_landmarks(rig, landmarks_of(bones))
    # Every joint where the pose put it (the pelvis on the target's), the segments both have posed.
    assert max(np.abs(joints[j] - truth[j]).max() for j in truth) < 1e-12
    assert len(segments) == (26 if naming == "Unreal" else 27)       # Unreal's head has no landmark at its top
    # So the rotations found from them are those found from the pose's own joints.
    R_named, _ = matching_rotations(skeleton, rig.joints, joints)
    R_true, _ = matching_rotations(skeleton, rig.joints, truth)
    assert np.abs(R_named - R_true).max() < 1e-9


def test_bones_files_are_read_or_refused_naming_the_file(tmp_path):
    root, skeleton, bodies = rigs()
    rig = bodies["female_pear"][1]
    bones = named_bones(skeleton, rig.joints, "Rigify", spine=3)
    data = bones_data(bones)
    (tmp_path / "rigify.json").write_text(json.dumps(data))
    landmarks = read_target_skeleton(tmp_path / "rigify.json", skeleton)
    assert landmarks.naming == "Rigify" and len(landmarks.chains[("pelvis", "neck")]) == 5
    # The skeleton's own joints file is read as joints; so is a bones file of its own bones (matched by name).
    joints = read_target_skeleton(root / "rig" / "joints" / "female_pear.json", skeleton)
    assert set(skeleton.joint_names()) <= set(joints)
    own = {f"character1:{b}": {"parent": None if p < 0 else f"character1:{skeleton.names[p]}",
                                "head": joints[h].tolist(), "tail": joints[t].tolist()}
           for b, p, h, t in zip(skeleton.names, skeleton.parents, skeleton.heads, skeleton.tails)}
    (tmp_path / "own.json").write_text(json.dumps({"bones": own}))
    again = read_target_skeleton(tmp_path / "own.json", skeleton)
    assert isinstance(again, dict) and all(np.array_equal(again[j], joints[j]) for j in skeleton.joint_names())
    data["bones"]["DEF-shin.L"]["head"] = [0, "x", 0]
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(RigError, match=r"bad.json: bone 'DEF-shin.L': its head is not three finite numbers"):
        read_target_skeleton(tmp_path / "bad.json", skeleton)
    # A joints file with a coordinate that is no number is refused the same way.
    (tmp_path / "joints.json").write_text(json.dumps({"root____head": [0, "x", 0]}))
    with pytest.raises(RigError, match=r"joints.json: joint 'root____head' is not three finite numbers"):
        read_target_skeleton(tmp_path / "joints.json", skeleton)
    data = {"bones": {f"bone{k}": {"parent": None, "head": [0, k, 0], "tail": [0, k + 1, 0]} for k in range(5)}}
    (tmp_path / "unknown.json").write_text(json.dumps(data))
    with pytest.raises(RigError, match="unknown.json: has bones named in none of the ways known"):
        read_target_skeleton(tmp_path / "unknown.json", skeleton)


def test_the_command_line_poses_the_source_onto_a_target_skeleton_named_otherwise(tmp_path):
    root, skeleton, bodies = rigs()
    (source, _), (target, target_rig) = bodies["female_average"], bodies["female_pear"]
    T, posed = in_pose(root, skeleton, target, target_rig, "standing01")
    write_obj(tmp_path / "standing.obj", posed)
    # The character's skeleton is Mixamo's (its joints where a rig made for the body puts them), as it stands.
    bones = named_bones(skeleton, target_rig.posed_joints(T), "Mixamo", prefix="mixamorig:")
    (tmp_path / "mixamo.json").write_text(json.dumps(bones_data(bones)))
    garment = root / "garments" / "female_sportsuit01" / "female_average.obj"
    p = subprocess.run([sys.executable, "-m", "garment_transfer", *map(str, [
        "transfer", "--source-body", root / "bodies" / "female_average.obj", "--target-body", tmp_path / "standing.obj",
        "--garment", garment, "--out", tmp_path / "out.obj", "--json", *rig_options(root), "--target-joints",
        tmp_path / "mixamo.json"])], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    pose = out["rest_pose"]
    assert pose["posed"] and pose["twist"] == "body"
    assert pose["skeletons"] == {"by": "landmarks", "target": "Mixamo", "source": "MakeHuman", "segments": 27}
    # Said in the JSON's warnings, naming the target: what landmarks do not carry.
    said = [w for w in out["warnings"] if "its Mixamo skeleton was matched to the source's MakeHuman one" in w]
    assert said and said[0].startswith(f"{tmp_path / 'standing.obj'}: ") and said == pose["warnings"]
    assert pose["written"]["crossings_outside_contact"] == 0
    # As if transferred at rest and then fitted to the pose: 1.2 mm on average, measured (1.1 mm with MakeHuman's
    # own skeleton; the source posed by the landmarks alone is 6.7 mm from the pose, 3.0 mm with the twists).
    cloth = read_obj(garment)
    expected = fit_to_pose(target, posed.V, cloth.with_vertices(transfer_garment(source, target, cloth).V)).V
    assert np.linalg.norm(read_obj(tmp_path / "out.obj").V - expected, axis=1).mean() < 0.03      # 3 mm


def test_the_command_line_takes_the_rolls_of_a_bones_file_onto_a_target_of_another_mesh(tmp_path):
    from garment_transfer.geometry.mesh import mesh_from_triangles

    root, skeleton, bodies = rigs()
    (source, _), (target, target_rig) = bodies["female_average"], bodies["female_pear"]
    T, posed = in_pose(root, skeleton, target, target_rig, "run01")
    # The running pear as a scan or an export has it (its triangles, its vertices in another order: another mesh,
    # registered), and its armature's bones with each bone's roll (its Z axis).
    order = np.random.default_rng(0).permutation(posed.n_vertices)
    place = np.empty_like(order)
    place[order] = np.arange(order.size)
    write_obj(tmp_path / "running.obj", mesh_from_triangles(posed.V[order], place[posed.F], name="running"))
    joints, frames = target_rig.posed_joints(T), target_rig.posed_frames(T)
    bones = {b: {"parent": None if p < 0 else skeleton.names[p], "head": joints[h].tolist(),
                 "tail": joints[t].tolist(), "z_axis": frames[i][:, 2].tolist()}
             for i, (b, p, h, t) in enumerate(zip(skeleton.names, skeleton.parents, skeleton.heads, skeleton.tails))}
    (tmp_path / "bones.json").write_text(json.dumps({"bones": bones}))
    garment = root / "garments" / "female_sportsuit01" / "female_average.obj"
    p = subprocess.run([sys.executable, "-m", "garment_transfer", *map(str, [
        "transfer", "--source-body", root / "bodies" / "female_average.obj", "--target-body",
        tmp_path / "running.obj", "--garment", garment, "--out", tmp_path / "out.obj", "--json", "--no-cache",
        *rig_options(root), "--target-joints", tmp_path / "bones.json"])], capture_output=True, text=True,
        timeout=300)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    # Each bone's turn about itself from the rolls: nothing to warn of.
    assert out["registered"] and out["rest_pose"]["twist"] == "frames" and out["rest_pose"]["warnings"] == []
    assert not any("posed from its joints alone" in w for w in out["warnings"])
    assert out["rest_pose"]["written"]["crossings_outside_contact"] == 0
    cloth = read_obj(garment)
    expected = fit_to_pose(target, posed.V, cloth.with_vertices(transfer_garment(source, target, cloth).V)).V
    # Measured: 4.7 mm on average from the garment transferred at rest and fitted to the run (the registration onto
    # the running body most of it), against 17.4 mm from the joints alone.
    assert np.linalg.norm(read_obj(tmp_path / "out.obj").V - expected, axis=1).mean() < 0.06      # 6 mm


def test_joints_made_from_landmarks_have_every_twist_fitted_on_a_target_of_the_same_mesh():
    from garment_transfer import twist_from_body

    root, skeleton, bodies = rigs()
    body, rig = bodies["female_average"]
    # The kick: the head turned about the neck, which no landmark tells (the head bone's children lie off its line,
    # so the joints made from landmarks would seem to fix its turn).
    T = rig.transforms(bvh_rotations(read_bvh(root / "poses" / "fight01.bvh"), skeleton))
    truth = rig.pose(body.V, T)
    joints, _ = pose_to_landmarks(rig, landmarks_of(named_bones(skeleton, rig.posed_joints(T))))
    R, _ = matching_rotations(skeleton, rig.joints, joints)

    def off(rotations):
        return np.linalg.norm(rig.pose(body.V, rig.transforms(rotations)) - truth, axis=1).mean() * 100    # mm

    lines, _ = twist_from_body(rig, R, body.V, joints, truth)
    every, _ = twist_from_body(rig, R, body.V, joints, truth, free=skeleton.parents >= 0)
    # Measured: 32.2 mm by the landmarks, 28.5 with the twists of the bones on their line, 12.6 with every bone's.
    assert off(every) < 14.0 < 25.0 < off(lines) < off(R)


def test_a_target_of_another_mesh_and_another_naming_is_warned_of_both():
    from garment_transfer.geometry.mesh import mesh_from_triangles
    from garment_transfer.pipeline.rest_pose import posed_source

    root, skeleton, bodies = rigs()
    (source, source_rig), (target, target_rig) = bodies["female_average"], bodies["female_pear"]
    T, posed = in_pose(root, skeleton, target, target_rig, "run01", "running.obj")
    landmarks = landmarks_of(named_bones(skeleton, target_rig.posed_joints(T), "Rigify", spine=3))
    info, _ = posed_source(source, source_rig, landmarks, None, posed)
    assert info["twist"] == "body" and info["skeletons"]["target"] == "Rigify"
    assert len(info["warnings"]) == 1 and "its Rigify skeleton was matched" in info["warnings"][0]
    # As a scan's or an export's triangles: another mesh, whose twists nothing tells; both said, by name.
    info, _ = posed_source(source, source_rig, landmarks, None, mesh_from_triangles(posed.V, posed.F, name="scan"))
    assert info["posed"] and info["twist"] == "joints" and len(info["warnings"]) == 2
    assert all(w.startswith("scan: ") for w in info["warnings"])
    assert "by a Mixamo skeleton's landmarks" in info["warnings"][1] and "armature" not in info["warnings"][1]
