"""Playback and bake in Blender: a MakeHuman suit rigged by the extension, played back on the posed character,
against the nearest-surface rig; and the time of a baked pose fit.

The pear body (``../shared/data/makehuman``) gets MakeHuman's skeleton as an armature (the extension's
``make_armature``: bones from the joints, roll from the planes), its weights as vertex groups and an Armature
modifier. Each suit is transferred onto it from ``female_average`` by the Transfer operator, which rigs the
result (inpainted weights, at most 4 bones a vertex, an Armature modifier and a Shrinkwrap Outside: the live
playback). The baseline is the same result rigged by the nearest-surface rule (every influence, Armature only:
what Blender's Data Transfer gives). Per shared pose, both are evaluated by Blender on the posed character and
their crossings with the evaluated body counted under every split of both meshes' quads (the core's exact
count), in all and away from where the posed body crosses or closes on itself.

Then the bake: the armature keyed from the rest pose (frame 1) to a pose (frame ``--frames``) and the Bake Pose
Fit operator timed over the range, with the time Blender takes to play a frame of the live rig.

    .venv/bin/python -m lab.blender.motion_playback [--garments g1 g2] [--frames 20] [--bake-pose run01]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

import garment_transfer as gt  # noqa: E402
from garment_transfer.pipeline.pose_fit import CONTACT_GAP, CONTACT_RINGS, self_contact  # noqa: E402
from lab.paths import makehuman_folder  # noqa: E402

C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
POSES = ("standing01", "standing02", "standing03", "sit01", "run01", "fight01")


def to_world(P):
    return 0.1 * np.asarray(P) @ C.T


def import_obj(path, name):
    before = set(bpy.data.objects)
    bpy.ops.wm.obj_import(filepath=str(path), global_scale=0.1, use_split_objects=False, use_split_groups=False)
    (obj,) = [o for o in bpy.data.objects if o not in before]
    obj.name = obj.data.name = name
    return obj


def world(obj, evaluated):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    ob = obj.evaluated_get(depsgraph) if evaluated else obj
    me = ob.to_mesh() if evaluated else ob.data
    co = np.empty(3 * len(me.vertices), dtype=np.float32)
    me.vertices.foreach_get("co", co)
    if evaluated:
        ob.to_mesh_clear()
    M = np.array(ob.matrix_world)
    return co.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3]


def setup(root, rig_module):
    skeleton = gt.read_skeleton(root / "rig" / "skeleton.json")
    joints = {k: to_world(v) for k, v in gt.read_joints(root / "rig" / "joints" / "female_pear.json").items()}
    weights = gt.read_weights(root / "rig" / "weights.json", 13380)
    body = import_obj(root / "bodies" / "female_pear.obj", "pear")
    source = import_obj(root / "bodies" / "female_average.obj", "average")
    armature = rig_module.make_armature(bpy.context, "pear_rig", skeleton, joints)
    rig_module.write_vertex_groups(body, weights)
    body.modifiers.new(name="Armature", type='ARMATURE').object = armature
    settings = bpy.context.scene.garment_transfer
    settings.source_body, settings.target_body = source, body
    return skeleton, gt.Rig(skeleton, joints, weights), body, armature, settings


def nearest_twin(result, body, rig, rig_module, armature):
    """A copy of the result rigged by the nearest-surface rule (every influence), Armature modifier only."""
    twin = result.copy()
    twin.data = result.data.copy()
    twin.name = f"{result.name}_nearest"
    bpy.context.scene.collection.objects.link(twin)
    for group in list(twin.vertex_groups):
        twin.vertex_groups.remove(group)
    for mod in list(twin.modifiers):
        if mod.type == 'SHRINKWRAP':
            twin.modifiers.remove(mod)
    rest_body = gt.read_obj(makehuman_folder() / "bodies" / "female_pear.obj")
    rig_module.write_vertex_groups(twin, gt.nearest_weights(to_world(rest_body.V), rest_body.F, rig.weights,
                                                            world(twin, False)))
    return twin


def count(V, garment_F, body_V, body_F, free_F):
    c = gt.crossings(V, garment_F, body_V, body_F)
    free = gt.crossings(V, garment_F, body_V, free_F)
    return c["a_edges_through_b"] + c["b_edges_through_a"], free["a_edges_through_b"] + free["b_edges_through_a"]


def playback(root, names, rig_module):
    skeleton, rig, body, armature, settings = setup(root, rig_module)
    rest_body = gt.read_obj(root / "bodies" / "female_pear.obj")
    body_F = gt.every_split(rest_body)
    offset = gt.OFFSET_SHARE * gt.body_scale(to_world(rest_body.V))
    motions = {p: gt.read_bvh(root / "poses" / f"{p}.bvh") for p in POSES}
    totals = {}
    results = []
    for name in names:
        settings.garment = import_obj(root / "garments" / name / "female_average.obj", name)
        assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
        result = settings.result
        twin = nearest_twin(result, body, rig, rig_module, armature)
        garment_F = gt.every_split(gt.read_obj(root / "garments" / name / "female_average.obj"))
        results.append((name, result, twin, garment_F))
    for pose in POSES:
        T = rig.transforms(gt.bvh_rotations(motions[pose], skeleton, file_up="Z", body_up="Z"))
        rig_module.pose_armature(armature, skeleton, T)
        bpy.context.view_layer.update()
        posed = world(body, True)
        contact, _ = self_contact(posed, rest_body.F, CONTACT_RINGS, to_world(rest_body.V), CONTACT_GAP * offset)
        free_F = body_F[~contact[body_F].any(axis=1)]
        for name, result, twin, garment_F in results:
            live = count(world(result, True), garment_F, posed, body_F, free_F)
            near = count(world(twin, True), garment_F, posed, body_F, free_F)
            totals.setdefault(pose, np.zeros(4, dtype=np.int64))
            totals[pose] += [*near, *live]
            print(f"{name:>20} {pose:>10}: nearest rig {near[0]} crossings ({near[1]} away from the body's contact), "
                  f"live rig {live[0]} ({live[1]})", flush=True)
    print("\n| pose | nearest-surface rig: crossings (away from contact) | live rig (ours) | ratio |")
    print("|---|---:|---:|---:|")
    for pose, (n, nf, w, wf) in totals.items():
        print(f"| {pose} | {n} ({nf}) | {w} ({wf}) | {w / max(n, 1):.2f} ({wf / max(nf, 1):.2f}) |")
    all_n, all_w = sum(t[0] for t in totals.values()), sum(t[2] for t in totals.values())
    print(f"\nall poses: nearest {all_n}, live {all_w}: {all_w / max(all_n, 1):.2f} of the nearest rig's")
    return skeleton, rig, armature, results


def bake(skeleton, rig, armature, result, motion, frames):
    T = rig.transforms(gt.bvh_rotations(motion, skeleton, file_up="Z", body_up="Z"))
    for bone in armature.pose.bones:
        bone.matrix_basis.identity()
        bone.keyframe_insert("location", frame=1)
        bone.keyframe_insert("rotation_quaternion", frame=1)
    ext_rigging = sys.modules[bpy.types.GARMENT_TRANSFER_OT_rig_garment.__module__]
    ext_rigging.pose_armature(armature, skeleton, T)
    for bone in armature.pose.bones:
        bone.keyframe_insert("location", frame=frames)
        bone.keyframe_insert("rotation_quaternion", frame=frames)
    bpy.context.scene.garment_transfer.result = result
    t = time.perf_counter()
    for frame in range(1, frames + 1):
        bpy.context.scene.frame_set(frame)
        world(result, True)
    play = (time.perf_counter() - t) / frames
    t = time.perf_counter()
    assert bpy.ops.garment_transfer.bake_pose_fit(frame_start=1, frame_end=frames) == {'FINISHED'}
    seconds = time.perf_counter() - t
    print(f"\nbake of {frames} frames ({result.name}, rest to {motion.name}): {seconds:.1f} s, "
          f"{seconds / frames:.2f} s a frame ({100 * seconds / frames:.0f} s for 100 frames); live playback "
          f"{play * 1000:.0f} ms a frame")


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.blender.motion_playback", description=__doc__.split("\n\n")[0])
    p.add_argument("--garments", nargs="+", default=["female_sportsuit01", "female_casualsuit01",
                                                     "female_casualsuit02"])
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--bake-pose", default="run01")
    args = p.parse_args(argv)
    root = makehuman_folder()
    if root is None:
        raise SystemExit("the MakeHuman fixtures are not there (../shared/data/makehuman)")
    from extension_loader import load_extension

    ext = load_extension()
    ext.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    rig_module = sys.modules[bpy.types.GARMENT_TRANSFER_OT_rig_garment.__module__]
    skeleton, rig, armature, results = playback(root, args.garments, rig_module)
    if args.frames:
        bake(skeleton, rig, armature, results[0][1], gt.read_bvh(root / "poses" / f"{args.bake_pose}.bvh"),
             args.frames)


if __name__ == "__main__":
    main()
