"""Playback and bake in Blender: garments rigged by the extension, played back on the posed character against the
nearest-surface rig; and the time of a baked pose fit.

Two characters (``../shared/data/makehuman``), each with MakeHuman's skeleton as an armature (the extension's
``make_armature``: bones from the joints, roll from the planes), its weights as vertex groups and an Armature
modifier: the pear body, onto which each MakeHuman suit is transferred from ``female_average`` by the Transfer
operator (which rigs the result), and the average body, dressed with the demo's dresses and skirts as
``lab.motion`` makes them (the product's transfer from the banana mannequin) and rigged by Rig to Body. The live
rigs compared (``LIVE_RIGS``) are Rig to Body's options: the product's weights, an Armature modifier and a live
correction (a Surface Deform carrying the cloth that lies on the skin, Keep Outside Body's Shrinkwraps, or both;
the rig is built by the operator's own ``rig_to_body``, so the study measures what Rig to Body makes). The
baseline is the same garment rigged by the nearest-surface rule (every influence, Armature only: what Blender's
Data Transfer gives). In every pose of ``lab.motion.pose_set`` (the shared poses and those kept back), each rig
is evaluated by Blender on the posed character and its crossings with the evaluated body counted under every
split of both meshes' quads (the core's exact count), in all and away from where the posed body crosses or closes
on itself, with the share of triangles stretched by more than 20%.

Then the bake: the armature keyed from the rest pose (frame 1) to a pose (frame ``--frames``) and the Bake Pose
Fit operator timed over the range, with the time Blender takes to play a frame of the live rig.

    .venv/bin/python -m lab.blender.motion_playback [--garments g1 g2] [--live r1 r2] [--poses p q]
        [--frames 20] [--bake-pose run01]
"""

from __future__ import annotations

import argparse
import importlib
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
from lab.motion import LOOSE, LOOSE_BODY, SUITS, pose_set, principal_stretch, rest_garments  # noqa: E402
from lab.paths import makehuman_folder  # noqa: E402

C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: Blender's world is Z up, MakeHuman's files Y up: the rotations of ``pose_set`` (body axes) turned to it.
Y_TO_Z = C
GARMENTS = ("female_sportsuit01", "female_casualsuit01", "female_casualsuit02", "aline_skirt", "maxi_skirt",
            "formal_dress")
#: The live rigs compared with the nearest-surface rig: name -> Rig to Body's options.
#: The product's rig is "shrinkwrap" (Rig to Body's defaults: Keep Outside Body in bands up to the cloth offset,
#: each band held at rest, and beyond it for the cloth hanging free), "surface+shrinkwrap" with Ride Body Surface
#: on; "shrinkwrap_to_offset" keeps every vertex in bands up to the cloth offset only (the rig before the hanging
#: cloth's bands); "shrinkwrap_half" keeps outside in bands up to half the cloth offset (the first round's distance).
LIVE_RIGS = {"shrinkwrap_to_offset": dict(ride_surface=False, outside=1.0, hanging=False),
             "shrinkwrap_half": dict(ride_surface=False, outside=0.5),
             "surface": dict(ride_surface=True, outside=0.0),
             "surface+shrinkwrap_half": dict(ride_surface=True, outside=0.5),
             "shrinkwrap": dict(ride_surface=False, outside=1.0),
             "surface+shrinkwrap": dict(ride_surface=True, outside=1.0),
             # No bones: the whole garment carried by the body's surface (a Surface Deform bound at rest) and kept
             # outside by the Shrinkwraps, as a body played by a cache is followed (``follow_surface``).
             "body_surface": dict(follow_surface=True)}


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


class Character:
    """A MakeHuman body in the scene with its armature, weights and Armature modifier."""

    def __init__(self, root, rig_module, body_name):
        self.skeleton = gt.read_skeleton(root / "rig" / "skeleton.json")
        joints = {k: to_world(v) for k, v in gt.read_joints(root / "rig" / "joints" / f"{body_name}.json").items()}
        weights = gt.read_weights(root / "rig" / "weights.json", 13380)
        self.rest = gt.read_obj(root / "bodies" / f"{body_name}.obj")
        self.body = import_obj(root / "bodies" / f"{body_name}.obj", body_name)
        self.armature = rig_module.make_armature(bpy.context, f"{body_name}_rig", self.skeleton, joints)
        rig_module.write_vertex_groups(self.body, weights)
        self.body.modifiers.new(name="Armature", type='ARMATURE').object = self.armature
        self.rig = gt.Rig(self.skeleton, joints, weights)
        self.rest_V = to_world(self.rest.V)
        self.F = gt.every_split(self.rest)
        self.offset = gt.OFFSET_SHARE * gt.body_scale(self.rest_V)

    def pose(self, rig_module, R):
        """Pose the armature by local rotations in MakeHuman's axes (``lab.motion.pose_set``)."""
        R_world = np.einsum("ij,bjk,lk->bil", Y_TO_Z, R, Y_TO_Z)
        rig_module.pose_armature(self.armature, self.skeleton, self.rig.transforms(R_world))


def nearest_twin(result, character, rig_module):
    """A copy of the result rigged by the nearest-surface rule (every influence), Armature modifier only."""
    twin = result.copy()
    twin.data = result.data.copy()
    twin.name = f"{result.name}_nearest"
    bpy.context.scene.collection.objects.link(twin)
    for group in list(twin.vertex_groups):
        twin.vertex_groups.remove(group)
    for mod in list(twin.modifiers):
        twin.modifiers.remove(mod)
    rig_module.add_armature_modifier(twin, character.armature)
    rig_module.write_vertex_groups(twin, gt.nearest_weights(character.rest_V, character.rest.F, character.rig.weights,
                                                            world(twin, False)))
    return twin


def live_twin(result, body, rig_module, name, options):
    """A copy of the result rigged by the extension's Rig to Body with ``options``."""
    twin = result.copy()
    twin.data = result.data.copy()
    twin.name = f"{result.name}_{name}"
    bpy.context.scene.collection.objects.link(twin)
    options = dict(options)
    if options.pop("follow_surface", False):
        for group in list(twin.vertex_groups):
            twin.vertex_groups.remove(group)
        rig_module.follow_surface(bpy.context, twin, body, **options)
    else:
        rig_module.rig_to_body(bpy.context, twin, body, **options)
    return twin


def count(V, garment_F, body_V, body_F, free_F):
    c = gt.crossings(V, garment_F, body_V, body_F)
    free = gt.crossings(V, garment_F, body_V, free_F)
    return c["a_edges_through_b"] + c["b_edges_through_a"], free["a_edges_through_b"] + free["b_edges_through_a"]


def dressed(root, names, rig_module, characters, live):
    """Each garment rigged on its character: [(name, character, rigs {rule: object}, every split, F, rest V)]."""
    settings = bpy.context.scene.garment_transfer
    out = []
    rest = rest_garments(root, [n for n in names if n not in SUITS], lambda line: print(line, flush=True))
    for name in names:
        if name in SUITS:
            character = characters[SUITS[name]]
            settings.source_body = characters["source"]
            settings.target_body = character.body
            settings.garment = import_obj(root / "garments" / name / "female_average.obj", name)
            assert bpy.ops.garment_transfer.transfer() == {'FINISHED'}
            result = settings.result
            garment = gt.read_obj(root / "garments" / name / "female_average.obj")
        else:
            character = characters[LOOSE_BODY]
            garment = rest[name][1]
            path = ROOT / "results" / "motion" / "rest" / f"{name}_on_{LOOSE_BODY}.obj"
            result = import_obj(path, name)
            rig_module.rig_to_body(bpy.context, result, character.body)
        rigs = {"nearest": nearest_twin(result, character, rig_module)}
        for live_name in live:
            rigs[live_name] = live_twin(result, character.body, rig_module, live_name, LIVE_RIGS[live_name])
        out.append((name, character, rigs, gt.every_split(garment), garment.F, world(result, False)))
    return out


def playback(root, names, rig_module, live=tuple(LIVE_RIGS), poses=None):
    characters = {"female_pear": Character(root, rig_module, "female_pear"),
                  LOOSE_BODY: Character(root, rig_module, LOOSE_BODY)}
    characters["source"] = import_obj(root / "bodies" / "female_average.obj", "average_source")
    results = dressed(root, names, rig_module, characters, live)
    every = pose_set(root, characters["female_pear"].skeleton)
    every = {p: every[p] for p in (poses or every)}
    rigs = ("nearest", *live)
    totals = {}
    for pose, R in every.items():
        contact = {}
        for key, ch in characters.items():
            if key == "source":
                continue
            ch.pose(rig_module, R)
        bpy.context.view_layer.update()
        for name, ch, objects, garment_F, F, rest_V in results:
            if ch not in contact:
                posed = world(ch.body, True)
                c, _ = self_contact(posed, ch.rest.F, CONTACT_RINGS, ch.rest_V, CONTACT_GAP * ch.offset)
                contact[ch] = posed, ch.F[~c[ch.F].any(axis=1)]
            posed, free_F = contact[ch]
            kind = "loose" if name in LOOSE else "suits"
            cells = []
            for r in rigs:
                V = world(objects[r], True)
                all_, free = count(V, garment_F, posed, ch.F, free_F)
                s20 = float((principal_stretch(rest_V, V, F) > 1.2).mean())
                totals.setdefault((kind, pose), {}).setdefault(r, []).append((all_, free, s20))
                cells.append(f"{r} {all_} ({free}) {s20:.3f}")
            print(f"{name:>20} {pose:>18}: " + "; ".join(cells), flush=True)
    for kind in ("suits", "loose"):
        keys = [k for k in totals if k[0] == kind]
        if not keys:
            continue
        print(f"\n{kind}: per pose, summed over the garments: crossings (away from contact), mean share stretched >20%"
              "; ratio to the nearest rig's crossings (away from contact)\n")
        print("| pose | " + " | ".join(rigs) + " |")
        print("|---|" + "---:|" * len(rigs))
        sums = {r: np.zeros(2) for r in rigs}
        for key in keys:
            row = {r: np.array(v) for r, v in totals[key].items()}
            n, nf = row["nearest"][:, 0].sum(), row["nearest"][:, 1].sum()
            cells = []
            for r in rigs:
                a, f, s = row[r][:, 0].sum(), row[r][:, 1].sum(), row[r][:, 2].mean()
                sums[r] += (a, f)
                cells.append(f"{int(a)} ({int(f)}) {s:.3f}" + ("" if r == "nearest" else
                                                               f"; {a / max(n, 1):.2f} ({f / max(nf, 1):.2f})"))
            print(f"| {key[1]} | " + " | ".join(cells) + " |")
        n, nf = sums["nearest"]
        print("| all | " + " | ".join(f"{int(a)} ({int(f)})" + ("" if r == "nearest" else
                                                                   f"; {a / max(n, 1):.2f} ({f / max(nf, 1):.2f})")
                                      for r, (a, f) in sums.items()) + " |")
    return characters, results


def bake(character, rig_module, result, R, pose_name, frames):
    armature = character.armature
    for bone in armature.pose.bones:
        bone.matrix_basis.identity()
        bone.keyframe_insert("location", frame=1)
        bone.keyframe_insert("rotation_quaternion", frame=1)
    character.pose(rig_module, R)
    for bone in armature.pose.bones:
        bone.keyframe_insert("location", frame=frames)
        bone.keyframe_insert("rotation_quaternion", frame=frames)
    bpy.context.scene.garment_transfer.result = result
    t = time.perf_counter()
    for frame in range(1, frames + 1):
        bpy.context.scene.frame_set(frame)
        world(result, True)
    play = (time.perf_counter() - t) / frames
    # The bake as the extension runs it (a few frames fitted at once), beside the same bake one frame at a time.
    core = importlib.import_module(rig_module.__name__.rsplit(".", 2)[0] + ".garment_transfer")
    pose_fit, threads = core.pipeline.pose_fit, core.geometry.threads
    default = pose_fit.POSE_WORKERS
    seconds = {}
    try:
        for workers in (1, default):
            # The poses fitted at once and the frames' counts made at once (``in_threads``).
            pose_fit.POSE_WORKERS = threads.WORKERS = workers
            t = time.perf_counter()
            assert bpy.ops.garment_transfer.bake_pose_fit(frame_start=1, frame_end=frames) == {'FINISHED'}
            seconds[workers] = time.perf_counter() - t
    finally:
        pose_fit.POSE_WORKERS = threads.WORKERS = default
    one, many = seconds[1], seconds[default]
    print(f"\nbake of {frames} frames ({result.name}, rest to {pose_name}): {many:.1f} s, {many / frames:.2f} s a "
          f"frame ({100 * many / frames:.0f} s for 100 frames), {default} frames at once; one frame at a time "
          f"{one:.1f} s ({many / one:.2f}x); live playback {play * 1000:.0f} ms a frame")


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.blender.motion_playback", description=__doc__.split("\n\n")[0])
    p.add_argument("--garments", nargs="+", default=list(GARMENTS))
    p.add_argument("--live", nargs="+", default=list(LIVE_RIGS), choices=list(LIVE_RIGS),
                   help="the live rigs compared with the nearest-surface rig")
    p.add_argument("--poses", nargs="+", help="poses by name (default: the shared poses and those kept back)")
    p.add_argument("--frames", type=int, default=20, help="frames of the timed bake (0: none)")
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
    characters, results = playback(root, args.garments, rig_module, args.live, args.poses)
    if args.frames:
        suits = [r for r in results if r[0] in SUITS]
        if suits:
            name, character, objects, *_ = suits[0]
            bpy.context.scene.garment_transfer.target_body = character.body
            R = pose_set(root, character.skeleton, [args.bake_pose], kept_back=False)[args.bake_pose]
            bake(character, rig_module, objects[args.live[-1]] if args.live else objects["nearest"], R,
                 args.bake_pose, args.frames)


if __name__ == "__main__":
    main()
