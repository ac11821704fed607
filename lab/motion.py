"""Characters that move: garment weights, playback and the pose fit, per pose, on real poses.

The data: MakeHuman's default skeleton, its CC0 weights and its shared BVH poses (``../shared/data/makehuman``:
``rig/``, ``poses/``), applied with each body's own joints. The garments, clean at rest (the product's own
transfer, with its crossing pass):

- the 8 MakeHuman suits, each transferred from ``female_average`` to a heavier body of its sex (``female_pear``,
  ``male_average``), the target's rig;
- the demo's dresses and skirts (the loose garments), each transferred from the ``banana`` mannequin onto
  ``female_average`` (registered: the product's transfer to any body), that body's rig.

Per garment and pose, skinned with the nearest-surface weights (every influence, as Blender's Data Transfer
gives them) and with the inpainted weights (``rigging.inpainted_weights``, at most 4 influences):

- garment edges through the posed body and body edges through the garment, under every split of both meshes'
  quads (``pipeline.every_split``); vertices inside the posed body and the deepest (mm);
- the share of garment triangles stretched by more than 20% (largest in-plane principal stretch > 1.2) and by
  more than 100% (a tear);
- playback: the inpainted weights and the live correction the Blender rig adds (a Shrinkwrap Outside at half
  the transfer's offset: ``shape_keys.keep_outside``), counted the same way;
- with ``--fit``, the pose fit (``pipeline.fit_to_pose``): crossings away from where the posed body crosses or
  closes on itself and at those places, MDC against the rest garment for the fit and the skinned garment, and
  seconds per pose after the first (the garment prepared once).

    python -m lab.motion [--fit] [--garments a b ...] [--poses p q ...] [--json OUT.json]
    python -m lab.motion --speed      # the pose fit's seconds per pose after the first, beside the baseline
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

import garment_transfer as gt
from garment_transfer.pipeline.pose_fit import CONTACT_GAP, CONTACT_RINGS, self_contact
from garment_transfer.pipeline.shape_keys import keep_outside

from .paths import DEMO_DATA, MAKEHUMAN_SOURCE, makehuman_folder

SUITS = {"female_casualsuit01": "female_pear", "female_casualsuit02": "female_pear",
         "female_sportsuit01": "female_pear", "male_casualsuit01": "male_average",
         "male_casualsuit02": "male_average", "male_casualsuit03": "male_average",
         "male_casualsuit04": "male_average", "male_casualsuit06": "male_average"}
LOOSE = ("aline_skirt", "circle_skirt", "flounce_skirt", "gathered_skirt", "maxi_skirt", "mini_skirt",
         "pleated_skirt", "straight_skirt", "tiered_skirt", "formal_dress", "shift_dress", "slip_dress",
         "tube_dress", "wrap_dress")
LOOSE_BODY = "female_average"
POSES = ("standing01", "standing02", "standing03", "sit01", "run01", "fight01")
MM_PER_DM = 100.0


def principal_stretch(V0, V1, F):
    """(m,) the largest in-plane principal stretch of each triangle from ``V0`` to ``V1`` (1: unstretched)."""
    e1, e2 = V0[F[:, 1]] - V0[F[:, 0]], V0[F[:, 2]] - V0[F[:, 0]]
    u = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    n = np.cross(e1, e2)
    v = np.cross(n, u)
    v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)
    X = np.stack([np.stack([np.einsum("ij,ij->i", e, u), np.einsum("ij,ij->i", e, v)], 1) for e in (e1, e2)], 2)
    Y = np.stack([V1[F[:, 1]] - V1[F[:, 0]], V1[F[:, 2]] - V1[F[:, 0]]], 2)
    ok = np.abs(np.linalg.det(X)) > 1e-14
    s = np.ones(F.shape[0])
    s[ok] = np.linalg.svd(np.einsum("mij,mjk->mik", Y[ok], np.linalg.inv(X[ok])), compute_uv=False)[:, 0]
    return s


def crossing_figures(V, garment_F, body_V, body_F, body_surface, free_F):
    """Crossings both ways (and those away from the body's own contact, ``free_F``), vertices inside, deepest."""
    c = gt.crossings(V, garment_F, body_V, body_F)
    free = gt.crossings(V, garment_F, body_V, free_F)
    sd = body_surface.signed_distance(V)[0]
    return {"garment_edges_through_body": c["a_edges_through_b"], "body_edges_through_garment": c["b_edges_through_a"],
            "away_from_contact": free["a_edges_through_b"] + free["b_edges_through_a"],
            "inside": int((sd < 0).sum()), "deepest_mm": float(MM_PER_DM * max(0.0, -sd.min()))}


def rig_of(root, body_name, skeleton, weights):
    return gt.Rig(skeleton, gt.read_joints(root / "rig" / "joints" / f"{body_name}.json"), weights)


def rest_garments(root, names, say):
    """Each garment clean at rest on its study body: {name: (body name, Mesh)}."""
    out = {}
    source = gt.read_obj(root / "bodies" / f"{MAKEHUMAN_SOURCE}.obj")
    for name in names:
        if name in SUITS:
            garment = gt.read_obj(root / "garments" / name / f"{MAKEHUMAN_SOURCE}.obj")
            body = gt.read_obj(root / "bodies" / f"{SUITS[name]}.obj")
            V = gt.transfer_garment(source, body, garment).V
            out[name] = (SUITS[name], garment.with_vertices(V))
        else:
            banana = gt.read_obj(DEMO_DATA / "bodies" / "banana.obj")
            garment = gt.read_obj(DEMO_DATA / "garments" / name / "banana.obj")
            body = gt.read_obj(root / "bodies" / f"{LOOSE_BODY}.obj")
            result, _ = gt.transfer_to_any_body(banana, body, garment)
            out[name] = (LOOSE_BODY, garment.with_vertices(result.V))
        say(f"{name}: clean at rest on {out[name][0]}")
    return out


def study_garment(name, body, garment, rig, poses, motions, fit, say):
    """Every figure of one garment in every pose (see the module docstring)."""
    offset = gt.OFFSET_SHARE * gt.body_scale(body.V)
    rules = {"nearest": gt.nearest_weights(body.V, body.F, rig.weights, garment.V),
             "inpainted": gt.inpainted_weights(body.V, body.F, rig.weights, garment.V, garment.F)[0]}
    gF, bF = gt.every_split(garment), gt.every_split(body)
    prepared = gt.prepare_garment(body, garment) if fit else None
    rows = []
    for i, pose in enumerate(poses):
        T = rig.transforms(gt.bvh_rotations(motions[pose], rig.skeleton))
        posed = rig.pose(body.V, T)
        surface = gt.TriangleSurface(posed, body.F)
        contact, _ = self_contact(posed, body.F, CONTACT_RINGS, body.V, CONTACT_GAP * offset)
        free_F = bF[~contact[bF].any(axis=1)]
        row = {"garment": name, "pose": pose, "loose": name not in SUITS}
        for rule, weights in rules.items():
            V = rig.pose(garment.V, T, weights)
            s = principal_stretch(garment.V, V, garment.F)
            row[rule] = dict(crossing_figures(V, gF, posed, bF, surface, free_F), stretched_20=float((s > 1.2).mean()),
                             stretched_100=float((s > 2.0).mean()), mdc=float(gt.mdc(garment.V, V, garment.F)))
            if rule == "inpainted":
                live = keep_outside(V, surface, 0.5 * offset)
                row["playback"] = crossing_figures(live, gF, posed, bF, surface, free_F)
        if fit:
            t = time.perf_counter()
            result = gt.fit_to_pose(body, posed, garment, prepared=prepared, name=pose)
            info = result.info
            row["fit"] = {"crossings_outside_contact": info["crossings_outside_contact"],
                          "crossings_at_contact": info["crossings_at_contact"],
                          "body_self_crossings": info["body_self_crossings"],
                          "mdc": float(gt.mdc(garment.V, result.V, garment.F)),
                          "seconds": time.perf_counter() - t, "first": i == 0}
        rows.append(row)
        say(summary_line(row))
    return rows


def summary_line(row):
    n, w = row["nearest"], row["inpainted"]
    text = (f"{row['garment']:>19} {row['pose']:>10}: crossings nearest {n['garment_edges_through_body']}+"
            f"{n['body_edges_through_garment']}, inpainted {w['garment_edges_through_body']}+"
            f"{w['body_edges_through_garment']}, playback {row['playback']['garment_edges_through_body']}+"
            f"{row['playback']['body_edges_through_garment']}; away from contact {n['away_from_contact']} / "
            f"{w['away_from_contact']} / {row['playback']['away_from_contact']}; stretched >20% "
            f"{n['stretched_20']:.3f} / {w['stretched_20']:.3f}")
    if "fit" in row:
        f = row["fit"]
        text += (f"; fit {f['crossings_outside_contact']} ({f['crossings_at_contact']} at contact), MDC "
                 f"{f['mdc']:.4f} vs skinned {w['mdc']:.4f}, {f['seconds']:.2f} s")
    return text


def per_pose_table(rows, loose):
    """Markdown lines: per pose, summed over the garments of one kind."""
    lines = ["| pose | nearest: garment / body edges | inpainted | playback (inpainted + Shrinkwrap) | "
             "away from the body's contact: nearest / inpainted / playback | inside (nearest / inpainted) | "
             "deepest mm | stretched >20% | stretched >100% | pose fit: crossings (at body contact) | "
             "MDC fit / skinned |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for pose in dict.fromkeys(r["pose"] for r in rows):
        sel = [r for r in rows if r["pose"] == pose and r["loose"] == loose]
        if not sel:
            continue

        def total(rule, key):
            return sum(r[rule][key] for r in sel)

        def mean(rule, key):
            return float(np.mean([r[rule][key] for r in sel]))

        fit = ""
        if all("fit" in r for r in sel):
            fit = (f"{sum(r['fit']['crossings_outside_contact'] for r in sel)} "
                   f"({sum(r['fit']['crossings_at_contact'] for r in sel)}) | "
                   f"{np.mean([r['fit']['mdc'] for r in sel]):.4f} / {mean('inpainted', 'mdc'):.4f}")
        else:
            fit = "- | -"
        lines.append(
            f"| {pose} | {total('nearest', 'garment_edges_through_body')} / "
            f"{total('nearest', 'body_edges_through_garment')} | {total('inpainted', 'garment_edges_through_body')} / "
            f"{total('inpainted', 'body_edges_through_garment')} | {total('playback', 'garment_edges_through_body')} / "
            f"{total('playback', 'body_edges_through_garment')} | {total('nearest', 'away_from_contact')} / "
            f"{total('inpainted', 'away_from_contact')} / {total('playback', 'away_from_contact')} | "
            f"{total('nearest', 'inside')} / "
            f"{total('inpainted', 'inside')} | {max(r['nearest']['deepest_mm'] for r in sel):.1f} / "
            f"{max(r['inpainted']['deepest_mm'] for r in sel):.1f} | {mean('nearest', 'stretched_20'):.3f} / "
            f"{mean('inpainted', 'stretched_20'):.3f} | {mean('nearest', 'stretched_100'):.4f} / "
            f"{mean('inpainted', 'stretched_100'):.4f} | {fit} |")
    return lines


def run(garments=None, poses=POSES, fit=False, say=print):
    root = makehuman_folder()
    if root is None:
        raise SystemExit("the MakeHuman fixtures are not there (../shared/data/makehuman)")
    garments = list(garments or (*SUITS, *LOOSE))
    skeleton = gt.read_skeleton(root / "rig" / "skeleton.json")
    weights = gt.read_weights(root / "rig" / "weights.json", 13380)
    motions = {p: gt.read_bvh(root / "poses" / f"{p}.bvh") for p in poses}
    rows = []
    for name, (body_name, garment) in rest_garments(root, garments, say).items():
        body = gt.read_obj(root / "bodies" / f"{body_name}.obj")
        rows += study_garment(name, body, garment, rig_of(root, body_name, skeleton, weights), poses, motions,
                              fit, say)
    return rows


def speed(name="female_casualsuit01", poses=POSES, say=print):
    """Seconds per pose of the pose fit after the first (the garment prepared once), by stage, beside the
    baseline: ``transfer_garment`` to each posed body as ``shapes`` runs it (prepared once, the crossing pass as
    for any target)."""
    root = makehuman_folder()
    skeleton = gt.read_skeleton(root / "rig" / "skeleton.json")
    weights = gt.read_weights(root / "rig" / "weights.json", 13380)
    body_name, garment = rest_garments(root, [name], lambda _: None)[name]
    body = gt.read_obj(root / "bodies" / f"{body_name}.obj")
    rig = rig_of(root, body_name, skeleton, weights)
    t = time.perf_counter()
    prepared = gt.prepare_garment(body, garment)
    say(f"{name} ({garment.n_vertices} vertices) on {body_name}: prepared once in {time.perf_counter() - t:.2f} s")
    rows = []
    for pose in poses:
        posed = rig.pose(body.V, rig.transforms(gt.bvh_rotations(gt.read_bvh(root / "poses" / f"{pose}.bvh"),
                                                                 skeleton)))
        t = time.perf_counter()
        result = gt.fit_to_pose(body, posed, garment, prepared=prepared, name=pose)
        fit = time.perf_counter() - t
        t = time.perf_counter()
        gt.transfer_garment(body, body.with_vertices(posed), garment, prepared=prepared)
        base = time.perf_counter() - t
        s = result.seconds
        rows.append((pose, fit, base))
        say(f"{pose:>10}: pose fit {fit:.2f} s (transfer {s['total'] - s['crossings']:.2f}, contact and crossings "
            f"{s['crossings']:.2f}; passes {len(result.info.get('crossing_pass', []))}), baseline {base:.2f} s, "
            f"ratio {fit / base:.2f}; goal 0.3 s: {fit / 0.3:.1f}x")
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.motion", description=__doc__.split("\n\n")[0])
    p.add_argument("--garments", nargs="+", help="garments (default: the 8 suits and the 14 dresses and skirts)")
    p.add_argument("--poses", nargs="+", default=list(POSES))
    p.add_argument("--fit", action="store_true", help="also the pose fit (slower)")
    p.add_argument("--json", help="write every row to this JSON file")
    p.add_argument("--speed", action="store_true", help="only the pose fit's seconds per pose, beside the baseline")
    args = p.parse_args(argv)
    if args.speed:
        speed(poses=args.poses)
        return
    rows = run(args.garments, args.poses, args.fit, say=lambda line: print(line, file=sys.stderr, flush=True))
    for loose, title in ((False, "MakeHuman suits"), (True, "the demo's dresses and skirts")):
        if any(r["loose"] == loose for r in rows):
            print(f"\n{title} (summed over the garments; stretch and MDC: means)\n")
            print("\n".join(per_pose_table(rows, loose)))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
