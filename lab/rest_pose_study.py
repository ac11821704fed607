"""A target in another rest pose, from its joints: how the source is posed into it, and the garment as written.

The data: MakeHuman's default skeleton, its CC0 weights and its shared BVH poses (``../shared/data/makehuman``), the
pose taken as the target's rest pose (``female_pear`` posed by it, its posed joints written as a joints file),
``female_sportsuit01`` on ``female_average`` as the garment.

1. **Posing** (the core): the source posed into each pose by its joints alone (``matching_rotations``) and with each
   bone's twist from the target's body (``twist_from_body``), against the source posed by the pose's true bone
   frames: mean, 95th percentile and largest vertex distance, on the source's own body posed and on the pear posed
   (another shape: its shape around a limb can read as twist).
2. **The command line** (``python -m garment_transfer transfer --skeleton ... --target-joints ...``, a fresh process
   each, as a user runs it): the file written against the reference (the core's transfer to the pear at rest, then
   ``fit_to_pose`` to the pose), its crossings away from where the posed body crosses or closes on itself (the
   JSON's ``rest_pose.written``), how the twists were found (``rest_pose.twist``) and the command's transfer seconds.
   With ``--remeshed``, also onto the posed pear re-meshed to 50K triangles (registered; posed from the joints
   alone, with the JSON's warning).
3. **A skeleton named otherwise** (``--named``): the target's skeleton given as Mixamo's bones where the pose puts
   them (``named_bones``: Mixamo's joints at MakeHuman's, its three spine joints along MakeHuman's spine), in a
   bones file: the source posed onto its landmarks (``pose_to_landmarks``) against the pose itself, and the
   command line's file against the reference, as in 2 (with ``--remeshed``, also onto the re-meshed body: the case
   of a character from another tool, another mesh and another skeleton).

4. **Rolls and untangling** (options of 2): ``--rolls`` gives the command line the target's bones with each bone's
   roll (``own_bones``) in place of its joints (the twists then come from the frames, also onto the re-meshed body);
   ``--untangle`` runs it with ``--untangle`` (the table's column of pairs the file crosses itself at beyond its
   source says what it undid); ``--garment`` picks another MakeHuman garment.

    python -m lab.rest_pose_study [--poses standing01 run01 ...] [--remeshed] [--named] [--rolls] [--untangle]
                                  [--garment NAME] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

import garment_transfer as gt
from garment_transfer.rigging.naming import FINGERS, PHALANX, SEGMENTS, skeleton_bones

from .paths import ROOT, makehuman_folder
from .registration import remesh

POSES = ("standing01", "standing02", "standing03", "sit01", "run01", "fight01")
SOURCE, TARGET, GARMENT = "female_average", "female_pear", "female_sportsuit01"
MM_PER_UNIT = 100.0                 # MakeHuman's bodies are in decimetres


def pose_rotations(root, skeleton, rig, pose):
    """The local rotations of a shared pose (its BVH file), or of ``"tpose"``: the T-pose a character from another
    tool often stands in, each upper arm swung from the rig's rest to straight out sideways (the arm kept as it
    bends at the elbow)."""
    if pose != "tpose":
        return gt.bvh_rotations(gt.read_bvh(root / "poses" / f"{pose}.bvh"), skeleton)
    heads, _ = rig.rest()
    R = np.tile(np.eye(3), (skeleton.n_bones, 1, 1))
    for side, out in (("L", 1.0), ("R", -1.0)):
        b = skeleton.index(f"upperarm01.{side}")
        d = heads[skeleton.index(f"lowerarm01.{side}")] - heads[b]
        d /= np.linalg.norm(d)
        axis = np.cross(d, [out, 0.0, 0.0])
        angle = np.arctan2(np.linalg.norm(axis), d @ [out, 0.0, 0.0])
        # The bones above the upper arm do not turn: its local rotation is its turn in the body.
        R[b] = Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix()
    return R


def _spread(a, b):
    d = np.linalg.norm(np.asarray(a) - np.asarray(b), axis=1) * MM_PER_UNIT
    return {"mean": float(d.mean()), "p95": float(np.percentile(d, 95)), "max": float(d.max())}


def posing(root, skeleton, weights, poses, say=print):
    """Rows of table 1: per pose and target body, the source posed by its joints and with the body's twists, against
    the source posed by the true frames (mm)."""
    source = gt.read_obj(root / "bodies" / f"{SOURCE}.obj")
    source_rig = gt.Rig(skeleton, gt.read_joints(root / "rig" / "joints" / f"{SOURCE}.json", skeleton), weights)
    rows = []
    for target_name in (SOURCE, TARGET):
        target = gt.read_obj(root / "bodies" / f"{target_name}.obj")
        rig = gt.Rig(skeleton, gt.read_joints(root / "rig" / "joints" / f"{target_name}.json", skeleton), weights)
        for pose in poses:
            T = rig.transforms(pose_rotations(root, skeleton, rig, pose))
            joints, posed = rig.posed_joints(T), rig.pose(target.V, T)
            R, _ = gt.matching_rotations(skeleton, source_rig.joints, joints)
            t = time.perf_counter()
            R_twist, _ = gt.twist_from_body(source_rig, R, source.V, joints, posed)
            seconds = time.perf_counter() - t
            R_true, _ = gt.matching_rotations(skeleton, source_rig.joints, joints, rig.posed_frames(T),
                                              source_rig.rest_frames())

            def pose_by(rotations):
                return source_rig.pose(source.V, source_rig.transforms(rotations))

            truth = pose_by(R_true)
            row = {"target": target_name, "pose": pose, "joints": _spread(pose_by(R), truth),
                   "twists": _spread(pose_by(R_twist), truth), "twist_seconds": seconds}
            rows.append(row)
            say(f"posing {target_name:15s} {pose:10s} joints {row['joints']['mean']:5.2f} mm, with the twists "
                f"{row['twists']['mean']:5.2f} mm ({seconds:.2f} s)")
    return rows


def _bodies(root, skeleton, weights, garment_name=GARMENT):
    """The source body, the target body at rest, its rig, and the garment transferred to it at rest."""
    source = gt.read_obj(root / "bodies" / f"{SOURCE}.obj")
    target = gt.read_obj(root / "bodies" / f"{TARGET}.obj")
    rig = gt.Rig(skeleton, gt.read_joints(root / "rig" / "joints" / f"{TARGET}.json", skeleton), weights)
    garment = gt.read_obj(root / "garments" / garment_name / f"{SOURCE}.obj")
    return source, target, rig, garment.with_vertices(gt.transfer_garment(source, target, garment).V)


def _targets(target, posed, remeshed):
    """(label, Mesh) of the target body in the pose: its own mesh, and re-meshed to 50K triangles when asked."""
    out = [("same mesh", target.with_vertices(posed, name="posed"))]
    if remeshed:
        U, G = remesh(posed, target.F, 50000)
        out.append(("re-meshed 50K", gt.mesh_from_triangles(U, G, name="posed")))
    return out


def _command(root, target, joints_path, tmp, what, garment_name=GARMENT, extra=()):
    """The command line's transfer of the garment onto ``target`` (a Mesh, written to ``tmp``) standing as the
    target joints (or bones) file says, as a user runs it: (its JSON, the file it wrote read back)."""
    gt.write_obj(tmp / "posed.obj", target)
    cmd = [sys.executable, "-m", "garment_transfer", "transfer", "--source-body",
           str(root / "bodies" / f"{SOURCE}.obj"), "--target-body", str(tmp / "posed.obj"), "--garment",
           str(root / "garments" / garment_name / f"{SOURCE}.obj"), "--out", str(tmp / "out.obj"), "--skeleton",
           str(root / "rig" / "skeleton.json"), "--source-joints", str(root / "rig" / "joints" / f"{SOURCE}.json"),
           "--source-weights", str(root / "rig" / "weights.json"), "--target-joints", str(joints_path), "--json",
           "--no-cache", *extra]
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if p.returncode != 0:
        raise RuntimeError(f"{what}: {p.stderr[-2000:]}")
    return json.loads(p.stdout), gt.read_obj(tmp / "out.obj").V


def own_bones(skeleton, rig, T):
    """A bones file's content of the rig's own bones in the pose ``T``, each with its roll (``"z_axis"``: its frame's Z
    axis, as Blender's bone matrix has it; ``gt.read_target_frames`` reads it)."""
    joints, frames = rig.posed_joints(T), rig.posed_frames(T)
    return {"bones": {b: {"parent": None if p < 0 else skeleton.names[p], "head": [float(x) for x in joints[h]],
                          "tail": [float(x) for x in joints[t]], "z_axis": [float(x) for x in frames[i][:, 2]]}
                      for i, (b, p, h, t) in enumerate(zip(skeleton.names, skeleton.parents, skeleton.heads,
                                                           skeleton.tails))}}


def command_line(root, skeleton, weights, poses, remeshed=False, say=print, rolls=False, untangle=False,
                 garment_name=GARMENT):
    """Rows of table 2: per pose (and target mesh), the command line's file against the reference; ``rolls``: the
    target's joints file is its bones with their rolls (``own_bones``); ``untangle``: the command runs with
    ``--untangle``."""
    _, target, rig, at_rest = _bodies(root, skeleton, weights, garment_name)
    rows = []
    with tempfile.TemporaryDirectory(prefix="rest_pose_study_") as tmp:
        tmp = Path(tmp)
        for pose in poses:
            T = rig.transforms(pose_rotations(root, skeleton, rig, pose))
            posed = rig.pose(target.V, T)
            reference = gt.fit_to_pose(target, posed, at_rest).V
            (tmp / "joints.json").write_text(json.dumps(own_bones(skeleton, rig, T) if rolls else
                                                        {k: [float(x) for x in v]
                                                         for k, v in rig.posed_joints(T).items()}))
            for label, mesh in _targets(target, posed, remeshed):
                out, written = _command(root, mesh, tmp / "joints.json", tmp, f"{pose} ({label})", garment_name,
                                        ["--untangle"] if untangle else [])
                counts = out["rest_pose"]["written"]
                row = {"pose": pose, "target": label, "to_reference": _spread(written, reference),
                       "twist": out["rest_pose"]["twist"], "crossings_outside_contact":
                       counts["crossings_outside_contact"], "crossings_at_contact": counts["crossings_at_contact"],
                       "warnings": len(out["warnings"]), "seconds": out["seconds"]["total"],
                       "self_intersections_new": out["check"]["self_intersections_new"]}
                rows.append(row)
                say(f"command {pose:10s} {label:13s} {row['to_reference']['mean']:5.2f} mm from the reference, "
                    f"twists from {row['twist']}, {row['crossings_outside_contact']} crossings away from contact "
                    f"({row['crossings_at_contact']} at it), {row['seconds']:.2f} s")
    return rows


#: The spine's bones between the pelvis's and the neck's, by naming (``named_bones``).
SPINE_BONES = {"Mixamo": ("Spine", "Spine1", "Spine2"), "Rigify": ("DEF-spine.001", "DEF-spine.002", "DEF-spine.003"),
               "Unreal": ("spine_01", "spine_02", "spine_03")}


def named_bones(skeleton, joints, naming="Mixamo", spine=3, prefix=""):
    """A skeleton named by ``naming`` (a key of ``gt.NAMINGS``) on a body whose MakeHuman joints are ``joints``:
    ``{prefix + bone: (parent, head, tail)}``, each landmark's bone at MakeHuman's landmark and ``spine`` spine bones
    (0 to 3) spread along MakeHuman's spine from the pelvis to the neck, at equal shares of its length, as a rig
    made for that body would put them (the bones of each segment of ``gt.NAMINGS`` chained as the segments are)."""
    own = gt.landmarks_of(skeleton_bones(skeleton, joints))
    at, table = own.points, gt.NAMINGS[naming]
    line = own.chains[("pelvis", "neck")]
    length = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))])
    shares = np.arange(1, spine + 1) / (spine + 1) * length[-1]
    spine_at = np.stack([np.interp(shares, length, line[:, c]) for c in range(3)], axis=1)
    heads = {table["pelvis"][0]: (None, at["pelvis"])}
    below_neck = table["pelvis"][0]
    for k in range(spine):
        heads[SPINE_BONES[naming][k]] = (below_neck, spine_at[k])
        below_neck = SPINE_BONES[naming][k]
    parent_of = {"neck": below_neck, "head": table["neck"][0], "head top": table["head"][0]}
    for s in ("L", "R"):
        parent_of.update({f"clavicle.{s}": below_neck, f"hip.{s}": table["pelvis"][0]})
    for a, b in SEGMENTS[3:]:
        parent_of[b] = table[a][0]
    tails = {}
    for landmark, (bone, end) in table.items():
        if end == "tail":
            tails[bone] = at[landmark]
        elif landmark in parent_of and landmark in at:
            heads[bone] = (parent_of[landmark], at[landmark])
    # Each finger's three phalanges where MakeHuman's are, the last one's tail at its tip.
    for s in ("L", "R"):
        for f in FINGERS:
            up = table[f"wrist.{s}"][0]
            for k in (1, 2, 3):
                mh = skeleton.index(PHALANX["MakeHuman"](f, k, s))
                bone = PHALANX[naming](f, k, s)
                heads[bone] = (up, np.asarray(joints[skeleton.heads[mh]]))
                up = bone
            tails[up] = np.asarray(joints[skeleton.tails[mh]])
    children = {}
    for bone, (up, _) in heads.items():
        children.setdefault(up, []).append(bone)
    out = {}
    for bone, (up, head) in heads.items():
        tail = tails.get(bone, heads[children[bone][0]][1] if bone in children else
                         head + (head - heads[up][1]) * 0.3)
        out[prefix + bone] = (None if up is None else prefix + up, head, tail)
    return out


def bones_data(bones):
    """A bones file's content (``gt.bones_from_dict`` reads it) of ``{bone: (parent, head, tail)}``."""
    return {"bones": {b: {"parent": p, "head": [float(x) for x in h], "tail": [float(x) for x in t]}
                      for b, (p, h, t) in bones.items()}}


def named(root, skeleton, weights, poses, remeshed=False, say=print):
    """Rows of table 3: per pose, the target's skeleton named Mixamo's way (a bones file): the source posed onto its
    landmarks against the pose itself, and the command line's file against the reference."""
    source, target, rig, at_rest = _bodies(root, skeleton, weights)
    source_rig = gt.Rig(skeleton, gt.read_joints(root / "rig" / "joints" / f"{SOURCE}.json", skeleton), weights)
    rows = []
    with tempfile.TemporaryDirectory(prefix="rest_pose_study_") as tmp:
        tmp = Path(tmp)
        for pose in poses:
            R_pose = pose_rotations(root, skeleton, rig, pose)
            # The source posed onto the landmarks of its own pose, against the pose.
            T_own = source_rig.transforms(R_pose)
            truth = source_rig.pose(source.V, T_own)
            own_joints, segments = gt.pose_to_landmarks(source_rig, gt.landmarks_of(named_bones(
                skeleton, source_rig.posed_joints(T_own))))
            R, _ = gt.matching_rotations(skeleton, source_rig.joints, own_joints)
            # Joints made from landmarks fix no twist of the posed segments' bones (as the transfer takes them).
            posed_bones = {b for bones in segments.values() for b in bones}
            R_twist, _ = gt.twist_from_body(source_rig, R, source.V, own_joints, truth,
                                            free=np.array([b in posed_bones for b in skeleton.names]))
            posing_rows = {"landmarks": _spread(source_rig.pose(source.V, source_rig.transforms(R)), truth),
                           "twists": _spread(source_rig.pose(source.V, source_rig.transforms(R_twist)), truth)}
            # The command line onto the pear in the pose, its skeleton as Mixamo's bones.
            T = rig.transforms(R_pose)
            posed = rig.pose(target.V, T)
            reference = gt.fit_to_pose(target, posed, at_rest).V
            bones = named_bones(skeleton, rig.posed_joints(T), prefix="mixamorig:")
            (tmp / "bones.json").write_text(json.dumps(bones_data(bones)))
            for label, mesh in _targets(target, posed, remeshed):
                out, written = _command(root, mesh, tmp / "bones.json", tmp, f"{pose} ({label}, named otherwise)")
                counts = out["rest_pose"]["written"]
                row = {"pose": pose, "target": label, "posing": posing_rows,
                       "to_reference": _spread(written, reference), "skeletons": out["rest_pose"]["skeletons"],
                       "twist": out["rest_pose"]["twist"],
                       "crossings_outside_contact": counts["crossings_outside_contact"],
                       "crossings_at_contact": counts["crossings_at_contact"], "warnings": len(out["warnings"]),
                       "seconds": out["seconds"]["total"]}
                rows.append(row)
                lm, tw = posing_rows["landmarks"]["mean"], posing_rows["twists"]["mean"]
                say(f"named {pose:10s} {label:13s} posing {lm:5.2f} mm ({tw:5.2f} with the twists); command "
                    f"{row['to_reference']['mean']:5.2f} mm from the reference, twists from {row['twist']}, "
                    f"{row['crossings_outside_contact']} crossings away from contact, {row['seconds']:.2f} s")
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.rest_pose_study", description=__doc__.split("\n\n")[0])
    p.add_argument("--poses", nargs="+", default=list(POSES),
                   help="shared poses by name (default: all six), or tpose (the upper arms straight out sideways)")
    p.add_argument("--remeshed", action="store_true", help="also onto the posed body re-meshed to 50K (registered)")
    p.add_argument("--named", action="store_true", help="also the target's skeleton named Mixamo's way (landmarks)")
    p.add_argument("--rolls", action="store_true",
                   help="the command line's target joints file as its bones with each bone's roll (z_axis)")
    p.add_argument("--untangle", action="store_true", help="the command line run with --untangle")
    p.add_argument("--garment", default=GARMENT, help=f"the MakeHuman garment (default {GARMENT})")
    p.add_argument("--json", type=Path, help="write every row to this file")
    args = p.parse_args(argv)
    root = makehuman_folder()
    if root is None:
        raise SystemExit("error: the MakeHuman data (../shared/data/makehuman) is not there")
    skeleton = gt.read_skeleton(root / "rig" / "skeleton.json")
    weights = gt.read_weights(root / "rig" / "weights.json", gt.read_obj(root / "bodies" / f"{SOURCE}.obj").n_vertices)

    def say(line):
        print(line, file=sys.stderr, flush=True)

    rows = {"posing": posing(root, skeleton, weights, args.poses, say),
            "command_line": command_line(root, skeleton, weights, args.poses, args.remeshed, say, args.rolls,
                                         args.untangle, args.garment)}
    print("\nposing: the source against the source posed by the true frames, mm (mean / 95% / max)")
    print(f"{'target':15s} {'pose':10s} | {'joints alone':>20s} | {'with the twists':>20s}")
    for r in rows["posing"]:
        j, t = r["joints"], r["twists"]
        print(f"{r['target']:15s} {r['pose']:10s} | {j['mean']:6.2f} {j['p95']:6.2f} {j['max']:6.1f} | "
              f"{t['mean']:6.2f} {t['p95']:6.2f} {t['max']:6.1f}")
    print("\nthe command line: the file against the reference (transfer at rest, then fit to the pose)")
    print(f"{'pose':10s} {'target':13s} | {'mean mm':>7s} | twists from | away from contact | at it | "
          "crossing itself beyond the source | s")
    for r in rows["command_line"]:
        print(f"{r['pose']:10s} {r['target']:13s} | {r['to_reference']['mean']:7.2f} | {r['twist']:11s} | "
              f"{r['crossings_outside_contact']:17d} | {r['crossings_at_contact']:5d} | "
              f"{r['self_intersections_new']:33d} | {r['seconds']:.2f}")
    if args.named:
        rows["named"] = named(root, skeleton, weights, args.poses, args.remeshed, say)
        print("\nthe target's skeleton named Mixamo's way: the source posed onto its landmarks against the pose, and "
              "the command line's file against the reference (mm, mean / 95% / max)")
        print(f"{'pose':10s} {'target':13s} | {'posing':>20s} | {'with the twists':>20s} | {'the file':>20s} | "
              "away | at | s")
        for r in rows["named"]:
            a, b, c = r["posing"]["landmarks"], r["posing"]["twists"], r["to_reference"]
            print(f"{r['pose']:10s} {r['target']:13s} | {a['mean']:6.2f} {a['p95']:6.2f} {a['max']:6.1f} | "
                  f"{b['mean']:6.2f} {b['p95']:6.2f} {b['max']:6.1f} | "
                  f"{c['mean']:6.2f} {c['p95']:6.2f} {c['max']:6.1f} | {r['crossings_outside_contact']:4d} | "
                  f"{r['crossings_at_contact']:3d} | {r['seconds']:.2f}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
