"""A target body in another rest pose: the source body and its garment posed into it first, then the shape."""

import numpy as np
import pytest
from meshes import require_makehuman

from garment_transfer import (PoseError, Rig, bone_frames, bvh_rotations, fit_to_pose, matching_rotations, read_bvh,
                              read_joints, read_obj, read_skeleton, read_weights, rig_from_bones, transfer_garment,
                              twist_from_body)
from garment_transfer.geometry.mesh import mesh_from_triangles
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


def in_pose(root, skeleton, body, rig, pose, name=None):
    """The pose's transforms of ``rig`` (a shared pose by name) and ``body`` posed by them."""
    T = rig.transforms(bvh_rotations(read_bvh(root / "poses" / f"{pose}.bvh"), skeleton))
    return T, body.with_vertices(rig.pose(body.V, T), name=name)


def suit_onto_pear_remeshed(pose, triangles, scale=1.0):
    """The sports suit on the average body, its rig, the pear's rig, the pose's transforms of it, and the pear in that
    pose re-meshed to about ``triangles`` triangles (another mesh: registered), its coordinates times ``scale``."""
    from lab.registration import remesh

    root, skeleton, bodies = rigs()
    (source, source_rig), (target, target_rig) = bodies["female_average"], bodies["female_pear"]
    garment = read_obj(root / "garments" / "female_sportsuit01" / "female_average.obj")
    T, posed = in_pose(root, skeleton, target, target_rig, pose)
    U, G = remesh(posed.V, posed.F, triangles)
    return source, source_rig, target_rig, garment, T, mesh_from_triangles(U * scale, G, name="pear re-meshed")


def rig_options(root):
    """The command line's options of the source's skeleton, joints and weights (the shared rig)."""
    return ["--skeleton", root / "rig" / "skeleton.json", "--source-joints",
            root / "rig" / "joints" / "female_average.json", "--source-weights", root / "rig" / "weights.json"]


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
    T, posed = in_pose(root, skeleton, target, target_rig, "fight01", "pear kicking")
    at_rest = garment.with_vertices(transfer_garment(source, target, garment).V)
    expected = fit_to_pose(target, posed.V, at_rest).V
    result, _ = transfer_across_rest_poses(source, posed, garment, source_rig, target_rig.posed_joints(T),
                                           target_rig.posed_frames(T))
    info = result.info["rest_pose"]
    assert info["posed"] and info["largest_turn"] > 45 and info["largest_turn_bone"] in ("upperarm02.R", "lowerleg01.L")
    # A model is trained on the source's pose: refused before any work, naming the target and the turn.
    with pytest.raises(PoseError, match=r"pear kicking: stands in another pose .* turned \d+ degrees.*direct method"):
        transfer_across_rest_poses(source, posed, garment, source_rig, target_rig.posed_joints(T),
                                   target_rig.posed_frames(T), method="model")
    assert result.info["crossings_outside_contact"] == 0
    assert np.linalg.norm(result.V - expected, axis=1).mean() < 0.03      # 3 mm, in decimetres


def test_untangling_undoes_where_the_pose_folds_the_cloth_through_itself_and_crosses_the_body_no_more():
    from garment_transfer import check_result, mdc

    root, skeleton, bodies = rigs()
    (source, source_rig), (target, target_rig) = bodies["female_average"], bodies["female_pear"]
    garment = read_obj(root / "garments" / "female_sportsuit01" / "female_average.obj")
    T, posed = in_pose(root, skeleton, target, target_rig, "standing01", "pear standing")
    result, _ = transfer_across_rest_poses(source, posed, garment, source_rig, target_rig.posed_joints(T),
                                           target_rig.posed_frames(T), untangle=True)
    info = result.info["rest_pose"]["untangle"]
    # Both steps measured (the suit over the pear standing, measured: 69 -> 65 pairs on the posed source, then 93 on
    # the target, all undone): what each undid is what its figures say, and the result crosses itself nowhere its
    # source does not, crossing the body no more than the fit.
    fit = info["fit"]
    assert fit["kept"] and fit["self_intersections_new_after"] < fit["self_intersections_new_before"]
    assert info["target"]["kept"] and info["target"]["self_intersections_new_before"] > 0
    assert info["target"]["self_intersections_new_after"] == 0
    # The fit as it was is carried to the target too (its untangling was kept), and its result, crossing itself
    # where the source does not, is not kept.
    assert fit["carried"] and info["compared"]["untangled_fit"]["self_intersections_new"] == 0
    # Said in words by both steps (the command line's line, Blender's Evaluation line); a step not kept is said so.
    from garment_transfer import untangle_text

    assert untangle_text(info) == (f"the fit to the posed source {fit['self_intersections_new_before']} -> "
                                   f"{fit['self_intersections_new_after']}, the result on the target "
                                   f"{info['target']['self_intersections_new_before']} -> 0")
    assert untangle_text({"fit": dict(fit, kept=False)}).endswith(" (not kept)") and untangle_text(None) == ""
    check = check_result(garment, result.V, posed)
    assert check["self_intersections_new"] == 0
    assert result.info["crossings_outside_contact"] == 0 and result.penetrating_vertices == check["inside_vertices"]
    # Against the same transfer not untangled (measured: 95 pairs the source lacks, MDC 0.0539 against 0.0517): the
    # cloth given back its own shape keeps the design at least as well, and is no more inside the body.
    plain, _ = transfer_across_rest_poses(source, posed, garment, source_rig, target_rig.posed_joints(T),
                                          target_rig.posed_frames(T))
    assert "untangle" not in plain.info["rest_pose"]
    before = check_result(garment, plain.V, posed)
    assert before["self_intersections_new"] > 0
    assert mdc(garment.V, result.V, garment.F) <= mdc(garment.V, plain.V, garment.F)
    assert check["inside_vertices"] <= before["inside_vertices"]


def test_untangling_keeps_the_fit_as_it_was_where_its_result_on_the_target_crosses_itself_less():
    from garment_transfer import check_result, untangle_text

    root, skeleton, bodies = rigs()
    (source, source_rig), (target, target_rig) = bodies["female_average"], bodies["female_pear"]
    garment = read_obj(root / "garments" / "female_sportsuit01" / "female_average.obj")
    T, posed = in_pose(root, skeleton, target, target_rig, "run01", "pear running")
    joints, frames = target_rig.posed_joints(T), target_rig.posed_frames(T)
    result, _ = transfer_across_rest_poses(source, posed, garment, source_rig, joints, frames, untangle=True)
    info = result.info["rest_pose"]["untangle"]
    # Running, the untangled fit leaves the target's pass more to fold (measured: 37 pairs the source lacks against
    # 29 from the fit as it was, both untangled on the target): the fit as it was is carried and its result kept.
    untangled, kept = info["compared"]["untangled_fit"], info["compared"]["fit"]
    assert info["fit"]["kept"] and info["fit"]["carried"] is False
    assert kept["self_intersections_new"] < untangled["self_intersections_new"]
    assert info["target"]["self_intersections_new_after"] == kept["self_intersections_new"]
    assert kept == {"self_intersections_new": info["target"]["self_intersections_new_after"],
                    "crossings_outside_contact": result.info["crossings_outside_contact"],
                    "crossings_at_contact": result.info["crossings_at_contact"],
                    "inside_vertices": result.penetrating_vertices}
    assert untangle_text(info).endswith(
        "; the result from the fit as it was kept (pairs, crossings with the body away from its contact and at it, "
        f"vertices inside: {kept['self_intersections_new']}, {kept['crossings_outside_contact']}, "
        f"{kept['crossings_at_contact']}, {kept['inside_vertices']} against the untangled fit's "
        f"{untangled['self_intersections_new']}, {untangled['crossings_outside_contact']}, "
        f"{untangled['crossings_at_contact']}, {untangled['inside_vertices']})")
    # No count of the result is worse than the transfer's not untangled, counted afresh on both (the body's contact as
    # the transfer reads it: the posed pear against its own mesh at rest).
    from garment_transfer.pipeline.pose_fit import posed_counts

    plain, _ = transfer_across_rest_poses(source, posed, garment, source_rig, joints, frames)
    check, before = check_result(garment, result.V, posed), check_result(garment, plain.V, posed)
    assert check["self_intersections_new"] < before["self_intersections_new"]
    assert check["inside_vertices"] <= before["inside_vertices"]
    counts, counts_before = (posed_counts(V, garment, posed, result.info["offset"], rest_V=source.V, own=False)
                             for V in (result.V, plain.V))
    for k in ("crossings_outside_contact", "crossings_at_contact", "penetrating_vertices"):
        assert counts[k] <= counts_before[k]
    assert counts["crossings_at_contact"] == kept["crossings_at_contact"]


def test_a_target_of_another_mesh_is_taken_to_the_source_at_rest_through_its_registration():
    from meshes import icosphere

    from garment_transfer.fitting.alignment import Similarity
    from garment_transfer.fitting.registration import Registration
    from garment_transfer.pipeline.rest_pose import target_at_rest

    rest = mesh_from_triangles(*icosphere(2), name="source")
    # The source posed (stretched and bent), registered onto a target of another mesh: the posed surface's
    # vertices and its triangles' centroids, in a frame half the source's size (the alignment's scale 2).
    posed = rest.V * [1.0, 1.5, 0.7] + 0.3 * rest.V[:, [1]] ** 2
    c = rest.n_vertices + np.arange(rest.F.shape[0])
    a, b, d = rest.F.T
    target = mesh_from_triangles(np.vstack([posed, posed[rest.F].mean(axis=1)]) / 2.0,
                                 np.vstack([np.c_[a, b, c], np.c_[b, d, c], np.c_[d, a, c]]), name="other")
    registration = Registration(posed / 2.0, posed, Similarity(2.0, np.eye(3), np.zeros(3)), {})
    expected = np.vstack([rest.V, rest.V[rest.F].mean(axis=1)]) / 2.0
    assert np.abs(target_at_rest(rest, target, registration) - expected).max() < 1e-12
    # A target of the source's mesh is the source at rest; another mesh without a registration has no rest.
    assert target_at_rest(rest, rest.with_vertices(posed), None) is rest.V
    assert target_at_rest(rest, target, None) is None


def test_a_target_of_another_mesh_in_another_rest_pose_is_clear_away_from_where_its_parts_press_together():
    from garment_transfer import check_result
    from garment_transfer.pipeline.pose_fit import posed_counts
    from garment_transfer.pipeline.rest_pose import target_at_rest

    # The pear in standing03 re-meshed (another mesh, registered): its arms pressed to its sides are found through
    # the registration, as on the pear's own mesh (measured: 15 garment-body crossings there, away from the body's
    # contact as it was found without the source at rest, which no pass clears).
    source, source_rig, target_rig, garment, T, other = suit_onto_pear_remeshed("standing03", 50000)
    result, registration = transfer_across_rest_poses(source, other, garment, source_rig, target_rig.posed_joints(T),
                                                      target_rig.posed_frames(T), cache=False)
    assert registration is not None and result.info["rest_pose"]["posed"]
    rest = target_at_rest(source, other, registration)
    assert rest.shape == other.V.shape
    counts = posed_counts(result.V, garment, other, result.info["offset"], rest_V=rest, own=False)
    assert counts["crossings_outside_contact"] == 0 == result.info["crossings_outside_contact"]
    assert counts["crossings_at_contact"] == result.info["crossings_at_contact"]
    assert counts["penetrating_vertices"] == check_result(garment, result.V, other)["inside_vertices"]


def test_an_offset_given_onto_a_target_of_another_mesh_in_other_units_is_the_targets_on_the_fit_too():
    # The running pear as another mesh, in centimetres (the source in decimetres), its joints so too.
    source, source_rig, target_rig, garment, T, other = suit_onto_pear_remeshed("run01", 30000, 10.0)
    joints = {k: 10.0 * np.asarray(v) for k, v in target_rig.posed_joints(T).items()}
    frames = target_rig.posed_frames(T)
    default, registration = transfer_across_rest_poses(source, other, garment, source_rig, joints, frames, cache=False)
    assert registration.alignment.scale == pytest.approx(0.1, rel=0.05)
    # The default offset given as a number (the target's units, as one garment's --offset): the fit to the posed
    # source keeps it in the source's units, so the result is the default's (measured: 0.37 mm apart on average;
    # taken as the source's units, the fit stood ten offsets out and the result 44 mm away).
    given, _ = transfer_across_rest_poses(source, other, garment, source_rig, joints, frames, cache=False,
                                          offset=default.info["offset"], registration=registration)
    assert given.info["offset"] == default.info["offset"]
    assert np.linalg.norm(given.V - default.V, axis=1).mean() < 0.2       # 2 mm, in centimetres


def test_a_rig_from_an_armatures_bones_poses_and_matches_as_the_skeleton_file_does():
    root, skeleton, bodies = rigs()
    (source, source_rig), (_, target_rig) = bodies["female_average"], bodies["female_pear"]
    T = target_rig.transforms(bvh_rotations(read_bvh(root / "poses" / "run01.bvh"), skeleton))
    target_joints, target_frames = target_rig.posed_joints(T), target_rig.posed_frames(T)
    # The bones as an armature has them: heads, tails and rolled frames.
    heads, tails = source_rig.rest()
    frames = bone_frames(skeleton, source_rig.joints)
    bones = {b: (skeleton.names[p] if p >= 0 else None, heads[i], tails[i], frames[i])
             for i, (b, p) in enumerate(zip(skeleton.names, skeleton.parents))}
    armature = rig_from_bones(bones, source_rig.weights, "average_rig")
    assert armature.skeleton.names == skeleton.names
    assert armature.skeleton.heads[0] == f"{skeleton.names[0]} head"
    # Given children first, the bones are put parents first.
    backwards = rig_from_bones(dict(reversed(bones.items())), source_rig.weights, "average_rig").skeleton
    assert all(p < i for i, p in enumerate(backwards.parents))
    assert {(b, backwards.names[p] if p >= 0 else None) for b, p in zip(backwards.names, backwards.parents)} == \
        {(b, skeleton.names[p] if p >= 0 else None) for b, p in zip(skeleton.names, skeleton.parents)}
    b_heads, b_tails = target_rig.skeleton.rest(target_joints)
    target_bones = {f"{b} {end}": p for b, h, t in zip(skeleton.names, b_heads, b_tails)
                    for end, p in (("head", h), ("tail", t))}
    R, turns = pose_difference(source_rig, target_joints, target_frames)
    R_b, turns_b = pose_difference(armature, target_bones, target_frames)
    assert np.array_equal(R, R_b) and turns == turns_b and max(turns.values()) > 45
    assert np.array_equal(armature.pose(source.V, armature.transforms(R_b)),
                          source_rig.pose(source.V, source_rig.transforms(R)))
    # Without frames, the armature's bones are matched by their joints alone (its bones carry no roll planes).
    plain = Rig(armature.skeleton, armature.joints, armature.weights)
    assert not np.array_equal(plain.rest_frames(), frames)
    assert np.allclose(armature.rest_frames(), frames)


def test_a_bones_turn_about_itself_is_measured_on_a_target_of_the_same_mesh():
    # The average body running, by its own rig: its joints say where each bone points, not how far a forearm, a
    # shin or a spine bone turned about itself; the running body itself says it.
    root, skeleton, bodies = rigs()
    source, rig = bodies["female_average"]
    T = rig.transforms(bvh_rotations(read_bvh(root / "poses" / "run01.bvh"), skeleton))
    running, joints = rig.pose(source.V, T), rig.posed_joints(T)
    R, _ = matching_rotations(skeleton, rig.joints, joints)
    R_twist, turns = twist_from_body(rig, R, source.V, joints, running)

    def off(R):
        return np.linalg.norm(rig.pose(source.V, rig.transforms(R)) - running, axis=1)

    # Decimetres: from the joints alone 4.8 mm on average (up to 83 mm), with the twists 0.1 mm, measured.
    assert off(R).mean() > 0.03 and off(R).max() > 0.5
    assert off(R_twist).mean() < 0.005 and np.percentile(off(R_twist), 95) < 0.02
    assert turns.shape == (skeleton.n_bones,) and turns.max() > 90
    with pytest.raises(ValueError, match="the target must be the body's own mesh"):
        twist_from_body(rig, R, source.V, joints, running[:-1])


def test_a_target_of_another_mesh_posed_from_its_joints_alone_is_said_to_be():
    # How each bone's turn about itself was found: the target's bone frames, its body (the source's mesh), or
    # nowhere (another mesh without frames), which the user is warned of by name.
    from garment_transfer.pipeline.rest_pose import posed_source

    root, skeleton, bodies = rigs()
    (source, source_rig), (target, target_rig) = bodies["female_average"], bodies["female_pear"]
    T, posed = in_pose(root, skeleton, target, target_rig, "run01", "running.obj")
    joints, frames = target_rig.posed_joints(T), target_rig.posed_frames(T)
    info, _ = posed_source(source, source_rig, joints, frames, posed)
    assert info["posed"] and info["twist"] == "frames" and info["warnings"] == []
    info, _ = posed_source(source, source_rig, joints, None, posed)
    assert info["twist"] == "body" and info["warnings"] == []
    # The same body as triangles is another mesh (a scan's, an export's): no vertex-for-vertex shape to read.
    scan = mesh_from_triangles(posed.V, posed.F, name="scan.obj")
    info, _ = posed_source(source, source_rig, joints, None, scan)
    assert info["posed"] and info["twist"] == "joints"
    assert len(info["warnings"]) == 1 and info["warnings"][0].startswith("scan.obj: posed from its joints alone")
    # A target in the source's own pose needs no twist: nothing to warn of.
    info, _ = posed_source(source, source_rig, source_rig.joints, None, mesh_from_triangles(source.V, source.F))
    assert not info["posed"] and info["warnings"] == []


def test_the_command_line_poses_the_source_into_a_target_standing_otherwise(tmp_path):
    import json
    import subprocess
    import sys

    from garment_transfer import write_obj

    root, skeleton, bodies = rigs()
    (source, _), (target, target_rig) = bodies["female_average"], bodies["female_pear"]
    T, posed = in_pose(root, skeleton, target, target_rig, "run01")
    write_obj(tmp_path / "running.obj", posed)
    (tmp_path / "running_joints.json").write_text(json.dumps({k: [float(x) for x in v]
                                                              for k, v in target_rig.posed_joints(T).items()}))
    garment = root / "garments" / "female_sportsuit01" / "female_average.obj"
    plain = ["transfer", "--source-body", root / "bodies" / "female_average.obj", "--target-body",
             tmp_path / "running.obj", "--garment", garment, "--out", tmp_path / "out.obj", "--json"]
    rig = rig_options(root)

    def run(*args):
        return subprocess.run([sys.executable, "-m", "garment_transfer", *map(str, args)], capture_output=True,
                              text=True, timeout=300)

    # Without the skeleton the pose difference is refused; with part of it, the missing options are named.
    p = run(*plain)
    assert p.returncode == 1 and "running.obj" in p.stderr and "another pose" in p.stderr
    p = run(*plain, *rig[:4])
    assert p.returncode == 1 and "missing --source-weights, --target-joints" in p.stderr
    (tmp_path / "few_joints.json").write_text('{"root____head": [0, 0, 0]}')
    p = run(*plain, *rig, "--target-joints", tmp_path / "few_joints.json")
    assert p.returncode == 1 and "few_joints.json: lacks" in p.stderr and "give --target-joints" in p.stderr
    assert not (tmp_path / "out.obj").exists()
    p = run(*plain, *rig, "--target-joints", tmp_path / "running_joints.json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["rest_pose"]["posed"] and out["rest_pose"]["largest_turn"] > 45
    assert out["rest_pose"]["twist"] == "body" and out["rest_pose"]["warnings"] == []
    # Counted on the file as written, against the running body: nothing through it away from where the run makes
    # the body cross or close on itself; said in the JSON's warnings.
    written = read_obj(tmp_path / "out.obj")
    assert out["rest_pose"]["written"]["crossings_outside_contact"] == 0
    assert out["rest_pose"]["written"]["warnings"] and set(out["rest_pose"]["written"]["warnings"]) <= \
        set(out["warnings"])
    # As if transferred at rest and then fitted to the pose: 1.2 mm on average, measured (3.6 mm from the joints alone,
    # which do not say how far each bone turned about itself; the running body itself does).
    cloth = read_obj(garment)
    at_rest = cloth.with_vertices(transfer_garment(source, target, cloth).V)
    expected = fit_to_pose(target, posed.V, at_rest).V
    assert np.linalg.norm(written.V - expected, axis=1).mean() < 0.03      # 3 mm, in decimetres
    # The run folds the cloth through itself where the source lacks it: said, with the remedy; --untangle undoes
    # part of it (measured: 66 -> 38 pairs), counted on the file as written, crossing the body no more.
    assert out["check"]["self_intersections_new"] > 0
    assert any("--untangle undoes it" in w for w in out["warnings"])
    p = run(*plain, *rig, "--target-joints", tmp_path / "running_joints.json", "--untangle")
    assert p.returncode == 0, p.stderr
    untangled = json.loads(p.stdout)
    assert untangled["rest_pose"]["untangle"]["fit"]["kept"]
    assert untangled["check"]["self_intersections_new"] < out["check"]["self_intersections_new"]
    assert untangled["rest_pose"]["written"]["crossings_outside_contact"] == 0
    assert untangled["check"]["inside_vertices"] <= out["check"]["inside_vertices"]
    assert not any("--untangle undoes it" in w for w in untangled["warnings"])
    # Only for one garment onto a target standing otherwise: refused before anything is read.
    p = run(*plain, "--untangle")
    assert p.returncode == 2 and "--untangle is for one garment onto a target in another rest pose" in p.stderr


def test_an_outfit_onto_a_target_standing_otherwise_is_posed_layer_by_layer(tmp_path):
    import json
    import subprocess
    import sys

    from garment_transfer import transfer_outfit, write_obj
    from lab.makehuman_procedural import MANNEQUIN, fit
    from lab.paths import DEMO_DATA

    root, skeleton, bodies = rigs()
    (source, _), (target, target_rig) = bodies["female_average"], bodies["female_pear"]
    # Two of the catalogue's garments carried onto the MakeHuman source: a T-shirt under a shift dress.
    mannequin = read_obj(DEMO_DATA / "bodies" / f"{MANNEQUIN}.obj")
    inner, _, _, registration = fit("tshirt", mannequin, source)
    outer, _, _, _ = fit("shift_dress", mannequin, source, registration)
    write_obj(tmp_path / "tshirt.obj", inner)
    write_obj(tmp_path / "dress.obj", outer)
    T, posed = in_pose(root, skeleton, target, target_rig, "run01")
    write_obj(tmp_path / "kicking.obj", posed)
    (tmp_path / "joints.json").write_text(json.dumps({k: [float(x) for x in v]
                                                      for k, v in target_rig.posed_joints(T).items()}))
    (tmp_path / "out").mkdir()
    p = subprocess.run([sys.executable, "-m", "garment_transfer", "transfer", "--source-body",
                        root / "bodies" / "female_average.obj", "--target-body", tmp_path / "kicking.obj",
                        "--garment", tmp_path / "tshirt.obj", "--garment", tmp_path / "dress.obj", "--out",
                        tmp_path / "out", *rig_options(root), "--target-joints", tmp_path / "joints.json", "--json"],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["rest_pose"]["posed"] and len(out["rest_pose"]["pose_fit"]) == 2
    # Each layer as written: nothing through the kicking body away from where it crosses itself, nothing through
    # the layer under it, no self-intersection its source lacks.
    for layer in out["layers"]:
        assert layer["rest_pose_written"]["crossings_outside_contact"] == 0
        assert layer["check"]["layer_crossings"] == 0 and layer["check"]["self_intersections_new"] == 0
    # Near the outfit transferred at rest and each layer then fitted to the kick (not a truth for layers: the fits
    # are made alone): 0.8 and 4.3 mm on average, measured.
    at_rest = transfer_outfit(source, target, [inner, outer]).V
    for garment, V, name, most in ((inner, at_rest[0], "tshirt", 0.03), (outer, at_rest[1], "dress", 0.06)):
        expected = fit_to_pose(target, posed.V, garment.with_vertices(V)).V
        written = read_obj(tmp_path / "out" / f"{name}.obj").V
        assert np.linalg.norm(written - expected, axis=1).mean() < most
    # The running pear as another mesh (re-meshed, more vertices than the source's): registered once for both
    # layers, each as written clear of the body away from where it crosses or closes on itself (which parts the
    # pose pressed together read through the registration), and of the layer under it.
    from lab.registration import remesh

    write_obj(tmp_path / "remeshed.obj", mesh_from_triangles(*remesh(posed.V, posed.F, 32000)))
    (tmp_path / "out2").mkdir()
    p = subprocess.run([sys.executable, "-m", "garment_transfer", "transfer", "--source-body",
                        root / "bodies" / "female_average.obj", "--target-body", tmp_path / "remeshed.obj",
                        "--garment", tmp_path / "tshirt.obj", "--garment", tmp_path / "dress.obj", "--out",
                        tmp_path / "out2", *rig_options(root), "--target-joints", tmp_path / "joints.json", "--json",
                        "--no-cache"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["registered"] and out["rest_pose"]["posed"]
    for layer in out["layers"]:
        assert layer["rest_pose_written"]["crossings_outside_contact"] == 0
        assert layer["check"]["layer_crossings"] == 0
