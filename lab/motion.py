"""Characters that move: garment weights, playback and the pose fit, per pose, on real poses and poses kept back.

The data: MakeHuman's default skeleton, its CC0 weights and its shared BVH poses (``../shared/data/makehuman``:
``rig/``, ``poses/``), applied with each body's own joints, and poses kept back from every choice made here
(``pose_set``): each shared pose mirrored left to right, and halfway blends of two poses (or of the rest pose and
one). The garments, clean at rest (the product's own transfer, with its crossing pass):

- the 8 MakeHuman suits, each transferred from ``female_average`` to a heavier body of its sex (``female_pear``,
  ``male_average``), the target's rig;
- the demo's dresses and skirts (the loose garments), each transferred from the ``banana`` mannequin onto
  ``female_average`` (registered: the product's transfer to any body), that body's rig.

Per garment and pose, skinned with each weight rule of ``RULES`` (the nearest-surface rule with every influence,
as Blender's Data Transfer gives them, is the baseline):

- garment edges through the posed body and body edges through the garment, under every split of both meshes'
  quads (``pipeline.every_split``), in all and away from where the posed body crosses or closes on itself;
- the share of garment triangles stretched by more than 20% (largest in-plane principal stretch > 1.2) and by
  more than 100% (a tear);
- playback: the product's weights and each live correction of ``LIVE`` (the core's equivalents of the Blender
  rig's modifiers: a Shrinkwrap Outside at the transfer's offset, ``shape_keys.keep_outside``; the
  vertices that lie on the skin carried on the skinned body's surface, ``riding_share`` and ``carry``, as
  Blender's Surface Deform does), counted the same way; ``lab.blender.motion_playback`` measures the real
  modifiers in Blender;
- with ``--fit``, the pose fit (``pipeline.fit_to_pose``): crossings away from where the posed body crosses or
  closes on itself and at those places, MDC against the rest garment for the fit and the skinned garment, and
  seconds per pose after the first (the garment prepared once).

    python -m lab.motion [--fit] [--garments a b ...] [--poses p q ...] [--shared-only] [--json OUT.json]
    python -m lab.motion --speed      # the pose fit's seconds per pose after the first, beside the baseline,
                                      # then the poses in a row one and two at a time (fit_poses)
    python -m lab.motion --untangle [--garments a b ...]   # each pose fit as it is and untangled, counted afresh
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from scipy.spatial.transform import Rotation

import garment_transfer as gt
from garment_transfer.geometry import bind, carry
from garment_transfer.pipeline.pose_fit import CONTACT_GAP, CONTACT_RINGS, POSE_WORKERS, self_contact
from garment_transfer.pipeline.shape_keys import keep_outside

from .paths import DEMO_DATA, MAKEHUMAN_SOURCE, ROOT, makehuman_folder

SUITS = {"female_casualsuit01": "female_pear", "female_casualsuit02": "female_pear",
         "female_sportsuit01": "female_pear", "male_casualsuit01": "male_average",
         "male_casualsuit02": "male_average", "male_casualsuit03": "male_average",
         "male_casualsuit04": "male_average", "male_casualsuit06": "male_average"}
LOOSE = ("aline_skirt", "circle_skirt", "flounce_skirt", "gathered_skirt", "maxi_skirt", "mini_skirt",
         "pleated_skirt", "straight_skirt", "tiered_skirt", "formal_dress", "shift_dress", "slip_dress",
         "tube_dress", "wrap_dress")
LOOSE_BODY = "female_average"
POSES = ("standing01", "standing02", "standing03", "sit01", "run01", "fight01")
#: Poses kept back: halfway between two shared poses (or the rest pose and one); with the mirror of every shared
#: pose (``<pose>_mirror``).
BLENDS = (("rest", "sit01"), ("run01", "fight01"), ("standing01", "run01"), ("sit01", "fight01"))
MM_PER_DM = 100.0
#: Where the garments clean at rest are kept between runs (the transfer with its crossing pass takes seconds each).
REST_CACHE = ROOT / "results" / "motion" / "rest"


def rules(max_influences=gt.MAX_INFLUENCES):
    """The weight rules compared: name -> ``rule(body, garment, body_weights, surface)`` -> SkinWeights."""
    def nearest(body, garment, weights, surface):
        return gt.nearest_weights(body.V, body.F, weights, garment.V, surface=surface)

    def inpainted(body, garment, weights, surface):
        return gt.inpainted_weights(body.V, body.F, weights, garment.V, garment.F, surface=surface,
                                    max_influences=max_influences)[0]

    def inpainted4(body, garment, weights, surface):
        return gt.inpainted_weights(body.V, body.F, weights, garment.V, garment.F, surface=surface,
                                    max_influences=4)[0]

    out = {"nearest": nearest, "inpainted": inpainted}
    if max_influences != 4:
        out["inpainted, 4 influences"] = inpainted4
    return out


#: The live corrections of playback measured in the core, on the product's weights: name -> (ride the body's
#: surface, keep outside at this share of the cloth offset; 0: not).
LIVE = {"shrinkwrap": (False, 1.0), "surface+shrinkwrap": (True, 1.0)}


def mirror_name(bone):
    """MakeHuman's name of a bone's mirror image (``.L`` and ``.R`` swapped; a middle bone is its own)."""
    if bone.endswith(".L"):
        return bone[:-2] + ".R"
    if bone.endswith(".R"):
        return bone[:-2] + ".L"
    return bone


def mirrored_rotations(R, skeleton, across=0):
    """The pose mirrored across the body's plane normal to axis ``across`` (MakeHuman: x, left to right): each bone
    takes its mirror bone's rotation, reflected (``S R S``).

    Parameters
    ----------
    R : (b,3,3) float
        Local rotations in the body's axes (``bvh_rotations``).
    skeleton : Skeleton

    Returns
    -------
    (b,3,3) float64
    """
    S = np.eye(3)
    S[across, across] = -1.0
    index = {name: i for i, name in enumerate(skeleton.names)}
    return np.array([S @ R[index.get(mirror_name(name), b)] @ S for b, name in enumerate(skeleton.names)])


def blended_rotations(Ra, Rb, t=0.5):
    """Each bone's rotation ``t`` of the way from ``Ra`` to ``Rb`` (b,3,3) along the shortest turn."""
    a, b = Rotation.from_matrix(Ra), Rotation.from_matrix(Rb)
    return (a * Rotation.from_rotvec(t * (a.inv() * b).as_rotvec())).as_matrix()


def pose_set(root, skeleton, names=POSES, kept_back=True):
    """The shared poses by name, then the poses kept back: ``{name: (b,3,3) local rotations}`` in the body's axes."""
    R = {p: gt.bvh_rotations(gt.read_bvh(root / "poses" / f"{p}.bvh"), skeleton) for p in names}
    out = dict(R)
    if kept_back:
        shared = {p: gt.bvh_rotations(gt.read_bvh(root / "poses" / f"{p}.bvh"), skeleton) for p in POSES}
        for p in names:
            out[f"{p}_mirror"] = mirrored_rotations(R[p], skeleton)
        rest = np.tile(np.eye(3), (skeleton.n_bones, 1, 1))
        for a, b in BLENDS:
            out[f"{a}+{b}"] = blended_rotations(rest if a == "rest" else shared[a], shared[b])
    return out


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


class PosedBody:
    """A body in one pose, with what every count against it needs: its surface, the triangles of every split of its
    quads, and which of them lie away from where the posed body crosses or closes on itself.

    Parameters
    ----------
    body : Mesh
        At rest.
    V : (n,3) float
        Posed.
    offset : float
        The cloth offset (contact: parts closer than ``CONTACT_GAP`` offsets).
    """

    def __init__(self, body, V, offset):
        self.V = np.asarray(V, dtype=np.float64)
        self.surface = gt.TriangleSurface(self.V, body.F)
        self.F = gt.every_split(body)
        contact, self.self_crossings = self_contact(self.V, body.F, CONTACT_RINGS, body.V, CONTACT_GAP * offset)
        self.free_triangle = ~contact[self.F].any(axis=1)
        E = np.sort(np.concatenate([self.F[self.free_triangle][:, [a, b]] for a, b in ((0, 1), (1, 2), (2, 0))]),
                    axis=1)
        self.n = self.V.shape[0]
        self.free_edge_keys = np.unique(E[:, 0] * self.n + E[:, 1])


def crossing_figures(V, garment_F, posed: PosedBody):
    """Crossings both ways, those away from the body's own contact, vertices inside and the deepest (mm).

    One exact count against the whole posed body; a crossing is away from contact when its body triangle (a garment
    edge through the body) or its body edge (through the garment) belongs to the body without its contact."""
    c = gt.crossings(V, garment_F, posed.V, posed.F)
    free_g = c["a_pairs"][posed.free_triangle[c["a_triangles"]]]
    keys = c["b_pairs"][:, 0] * posed.n + c["b_pairs"][:, 1]
    away = np.unique(free_g[:, 0] * V.shape[0] + free_g[:, 1]).size + int(np.isin(np.unique(keys),
                                                                                    posed.free_edge_keys).sum())
    sd = posed.surface.signed_distance(V)[0]
    return {"garment_edges_through_body": c["a_edges_through_b"], "body_edges_through_garment": c["b_edges_through_a"],
            "crossings": c["a_edges_through_b"] + c["b_edges_through_a"], "away_from_contact": int(away),
            "inside": int((sd < 0).sum()), "deepest_mm": float(MM_PER_DM * max(0.0, -sd.min()))}


def stretch_figures(rest_V, V, F):
    s = principal_stretch(rest_V, V, F)
    return {"stretched_20": float((s > 1.2).mean()), "stretched_100": float((s > 2.0).mean())}


def rig_of(root, body_name, skeleton, weights):
    return gt.Rig(skeleton, gt.read_joints(root / "rig" / "joints" / f"{body_name}.json"), weights)


def rest_garments(root, names, say, cache=REST_CACHE):
    """Each garment clean at rest on its study body: {name: (body name, Mesh)}; kept in ``cache`` (OBJ files of
    the product's output), made again when missing."""
    out = {}
    source = gt.read_obj(root / "bodies" / f"{MAKEHUMAN_SOURCE}.obj")
    for name in names:
        if name in SUITS:
            body_name, garment = SUITS[name], gt.read_obj(root / "garments" / name / f"{MAKEHUMAN_SOURCE}.obj")
        else:
            body_name, garment = LOOSE_BODY, gt.read_obj(DEMO_DATA / "garments" / name / "banana.obj")
        kept = cache / f"{name}_on_{body_name}.obj" if cache else None
        if kept is not None and kept.is_file():
            out[name] = (body_name, garment.with_vertices(gt.read_obj(kept).V))
            continue
        body = gt.read_obj(root / "bodies" / f"{body_name}.obj")
        if name in SUITS:
            V = gt.transfer_garment(source, body, garment).V
        else:
            V = gt.transfer_to_any_body(gt.read_obj(DEMO_DATA / "bodies" / "banana.obj"), body, garment)[0].V
        out[name] = (body_name, garment.with_vertices(V))
        if kept is not None:
            kept.parent.mkdir(parents=True, exist_ok=True)
            gt.write_obj(kept, garment, V)
        say(f"{name}: clean at rest on {body_name}")
    return out


def study_garment(name, body, garment, rig, poses, fit, say, weight_rules=None, posed_bodies=None):
    """Every figure of one garment in every pose (see the module docstring).

    Parameters
    ----------
    poses : dict
        Pose name -> (b,3,3) local rotations.
    posed_bodies : dict, optional
        Pose name -> PosedBody of this body, shared by the garments on it (filled here when missing).
    """
    offset = gt.OFFSET_SHARE * gt.body_scale(body.V)
    surface = gt.TriangleSurface(body.V, body.F)
    weight_rules = weight_rules or rules()
    weights = {rule: make(body, garment, rig.weights, surface) for rule, make in weight_rules.items()}
    product = weights["inpainted"]
    share = gt.riding_share(body.V, body.F, garment.V, garment.F, surface=surface)[:, None]
    binding = bind(garment.V, body.V, body.F, surface)
    gF = gt.every_split(garment)
    prepared = gt.prepare_garment(body, garment) if fit else None
    posed_bodies = {} if posed_bodies is None else posed_bodies
    rows = []
    for i, (pose, R) in enumerate(poses.items()):
        T = rig.transforms(R)
        if pose not in posed_bodies:
            posed_bodies[pose] = PosedBody(body, rig.pose(body.V, T), offset)
        posed = posed_bodies[pose]
        row = {"garment": name, "pose": pose, "loose": name not in SUITS, "kept_back": pose not in POSES}
        for rule, w in weights.items():
            V = rig.pose(garment.V, T, w)
            row[rule] = dict(crossing_figures(V, gF, posed), **stretch_figures(garment.V, V, garment.F),
                             mdc=float(gt.mdc(garment.V, V, garment.F)))
        skinned = rig.pose(garment.V, T, product)
        for live, (ride, outside) in LIVE.items():
            V = (1.0 - share) * skinned + share * carry(binding, posed.V, body.F) if ride else skinned
            if outside:
                V = keep_outside(V, posed.surface, outside * offset)
            row[f"playback:{live}"] = dict(crossing_figures(V, gF, posed), **stretch_figures(garment.V, V, garment.F))
        if fit:
            t = time.perf_counter()
            result = gt.fit_to_pose(body, posed.V, garment, prepared=prepared, name=pose)
            info = result.info
            row["fit"] = {"crossings_outside_contact": info["crossings_outside_contact"],
                          "crossings_at_contact": info["crossings_at_contact"],
                          "body_self_crossings": info["body_self_crossings"],
                          "mdc": float(gt.mdc(garment.V, result.V, garment.F)),
                          "seconds": time.perf_counter() - t, "first": i == 0}
        rows.append(row)
        say(summary_line(row, weight_rules))
    return rows


def summary_line(row, weight_rules):
    cells = [f"{rule} {row[rule]['crossings']} ({row[rule]['away_from_contact']}) {row[rule]['stretched_20']:.3f}"
             for rule in weight_rules]
    cells += [f"{key} {row[key]['crossings']} ({row[key]['away_from_contact']})" for key in row
              if key.startswith("playback:")]
    text = f"{row['garment']:>19} {row['pose']:>18}: " + "; ".join(cells)
    if "fit" in row:
        f = row["fit"]
        text += (f"; fit {f['crossings_outside_contact']} ({f['crossings_at_contact']} at contact), MDC "
                 f"{f['mdc']:.4f}, {f['seconds']:.2f} s")
    return text


def per_pose_table(rows, loose, methods):
    """Markdown lines, per pose summed over the garments of one kind: for each method (a weight rule or a
    playback) its crossings (ratio to the nearest rule's), away from contact, and the mean share stretched >20%
    (>100%)."""
    lines = ["| pose | " + " | ".join(f"{m}: crossings (x nearest), away from contact, stretched >20% (>100%)"
                                      for m in methods) + " |",
             "|---|" + "---:|" * len(methods)]
    totals = {m: np.zeros(2) for m in methods}
    for pose in dict.fromkeys(r["pose"] for r in rows):
        sel = [r for r in rows if r["pose"] == pose and r["loose"] == loose]
        if not sel:
            continue
        base = sum(r["nearest"]["crossings"] for r in sel)
        cells = []
        for m in methods:
            c, a = sum(r[m]["crossings"] for r in sel), sum(r[m]["away_from_contact"] for r in sel)
            totals[m] += (c, a)
            cells.append(f"{c} ({c / max(base, 1):.2f}), {a}, {np.mean([r[m]['stretched_20'] for r in sel]):.3f} "
                         f"({np.mean([r[m]['stretched_100'] for r in sel]):.4f})")
        lines.append(f"| {pose} | " + " | ".join(cells) + " |")
    base = totals["nearest"]
    lines.append("| all | " + " | ".join(f"{int(t[0])} ({t[0] / max(base[0], 1):.2f}), {int(t[1])} "
                                         f"({t[1] / max(base[1], 1):.2f})" for t in totals.values()) + " |")
    return lines


def fit_table(rows, loose):
    """Markdown lines: the pose fit per pose (crossings away from and at contact, MDC fit / skinned)."""
    lines = ["| pose | pose fit: crossings (at body contact) | MDC fit / skinned |", "|---|---:|---:|"]
    for pose in dict.fromkeys(r["pose"] for r in rows):
        sel = [r for r in rows if r["pose"] == pose and r["loose"] == loose and "fit" in r]
        if sel:
            lines.append(f"| {pose} | {sum(r['fit']['crossings_outside_contact'] for r in sel)} "
                         f"({sum(r['fit']['crossings_at_contact'] for r in sel)}) | "
                         f"{np.mean([r['fit']['mdc'] for r in sel]):.4f} / "
                         f"{np.mean([r['inpainted']['mdc'] for r in sel]):.4f} |")
    return lines


def run(garments=None, poses=None, fit=False, say=print, kept_back=True, max_influences=gt.MAX_INFLUENCES):
    root = makehuman_folder()
    if root is None:
        raise SystemExit("the MakeHuman fixtures are not there (../shared/data/makehuman)")
    garments = list(garments or (*SUITS, *LOOSE))
    skeleton = gt.read_skeleton(root / "rig" / "skeleton.json")
    weights = gt.read_weights(root / "rig" / "weights.json", 13380)
    every = pose_set(root, skeleton, kept_back=kept_back)
    if poses:
        unknown = [p for p in poses if p not in every]
        if unknown:
            raise SystemExit(f"unknown poses {unknown}; there are {sorted(every)}")
        every = {p: every[p] for p in poses}
    rows, posed = [], {}
    weight_rules = rules(max_influences)
    for name, (body_name, garment) in rest_garments(root, garments, say).items():
        body = gt.read_obj(root / "bodies" / f"{body_name}.obj")
        rows += study_garment(name, body, garment, rig_of(root, body_name, skeleton, weights), every, fit, say,
                              weight_rules, posed.setdefault(body_name, {}))
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
    rotations = pose_set(root, skeleton, list(poses), kept_back=False)
    posed_bodies = [(pose, rig.pose(body.V, rig.transforms(rotations[pose]))) for pose in poses]
    rows = []
    for pose, posed in posed_bodies:
        t = time.perf_counter()
        result = gt.fit_to_pose(body, posed, garment, prepared=prepared, name=pose)
        fit = time.perf_counter() - t
        t = time.perf_counter()
        # The pose is the point here (as in the pose fit), not a difference to refuse.
        gt.transfer_garment(body, body.with_vertices(posed), garment, prepared=prepared, check_pose=False)
        base = time.perf_counter() - t
        s = result.seconds
        rows.append((pose, fit, base))
        say(f"{pose:>10}: pose fit {fit:.2f} s (transfer {s['total'] - s['crossings']:.2f}, contact and crossings "
            f"{s['crossings']:.2f}; passes {len(result.info.get('crossing_pass', []))}), baseline {base:.2f} s, "
            f"ratio {fit / base:.2f}; goal 0.3 s: {fit / 0.3:.1f}x")
    runs = {}
    for workers in sorted({1, max(2, POSE_WORKERS)}):
        t = time.perf_counter()
        runs[workers] = dict(gt.fit_poses(body, posed_bodies, garment, prepared=prepared, workers=workers))
        runs[workers] = (time.perf_counter() - t, runs[workers])
    (one, first), (many, second) = runs[1], runs[max(runs)]
    same = all(np.array_equal(first[p].V, second[p].V) for p in first)
    say(f"the {len(poses)} poses in a row (fit_poses): one at a time {one / len(poses):.2f} s a pose; "
        f"{max(runs)} at once {many / len(poses):.2f} s a pose ({many / one:.2f}x; the same results: {same}); "
        f"goal 0.3 s: {many / len(poses) / 0.3:.1f}x")
    return rows


def untangle(names=None, poses=POSES, say=print):
    """Each garment fitted to each pose as it is and untangled (``fit_to_pose(..., untangle=True)``), both counted
    afresh on the result against the pose (``posed_counts``): the garment's own crossings beyond its rest shape's,
    crossings away from the body's contact and at it, vertices inside; MDC against the rest garment beside the
    skinned garment's (the product's weights); the untangling's seconds. Prints a row per pose and the totals."""
    root = makehuman_folder()
    skeleton = gt.read_skeleton(root / "rig" / "skeleton.json")
    weights = gt.read_weights(root / "rig" / "weights.json", 13380)
    rotations = pose_set(root, skeleton, list(poses), kept_back=False)
    say(f"{'garment':20s} {'pose':10s} {'own new':>13s} {'kept':>5s} {'away':>9s} {'at contact':>11s} "
        f"{'inside':>7s} {'MDC fit -> untangled (skinned)':>31s} {'s':>11s}")
    totals = np.zeros(8)
    for name, (body_name, garment) in rest_garments(root, names or [*SUITS, *LOOSE], say).items():
        body = gt.read_obj(root / "bodies" / f"{body_name}.obj")
        rig = rig_of(root, body_name, skeleton, weights)
        prepared = gt.prepare_garment(body, garment)
        product = gt.inpainted_weights(body.V, body.F, weights, garment.V, garment.F)[0]
        for pose in poses:
            T = rig.transforms(rotations[pose])
            posed = body.with_vertices(rig.pose(body.V, T), name=pose)
            fits = [gt.fit_to_pose(body, posed.V, garment, prepared=prepared, name=pose, untangle=u)
                    for u in (False, True)]
            a, b = (gt.posed_counts(f.V, garment, posed, float(f.info["offset"]), rest_V=body.V) for f in fits)
            mdc = [gt.mdc(garment.V, f.V, garment.F) for f in fits]
            skinned = gt.mdc(garment.V, rig.pose(garment.V, T, product), garment.F)
            kept = fits[1].info["untangle"]["kept"]
            totals += [a["self_intersections_new"], b["self_intersections_new"], kept, 1,
                       a["crossings_outside_contact"], b["crossings_outside_contact"], a["crossings_at_contact"],
                       b["crossings_at_contact"]]
            say(f"{name:20s} {pose:10s} {a['self_intersections_new']:5d} -> {b['self_intersections_new']:5d} "
                f"{'yes' if kept else 'no':>5s} "
                f"{a['crossings_outside_contact']:3d} -> {b['crossings_outside_contact']:3d} "
                f"{a['crossings_at_contact']:4d} -> {b['crossings_at_contact']:4d} "
                f"{a['penetrating_vertices']:2d} -> {b['penetrating_vertices']:2d} "
                f"{mdc[0]:.4f} -> {mdc[1]:.4f} ({skinned:.4f}) "
                f"{fits[0].seconds['total']:.2f} + {fits[1].seconds['untangle']:.2f}")
    say(f"all: the garment's own crossings beyond its rest shape's {totals[0]:.0f} -> {totals[1]:.0f}; kept in "
        f"{totals[2]:.0f} of {totals[3]:.0f} fits; crossings away from the body's contact {totals[4]:.0f} -> "
        f"{totals[5]:.0f}, at it {totals[6]:.0f} -> {totals[7]:.0f}")
    return totals


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.motion", description=__doc__.split("\n\n")[0])
    p.add_argument("--garments", nargs="+", help="garments (default: the 8 suits and the 14 dresses and skirts)")
    p.add_argument("--poses", nargs="+", help="poses by name (default: the shared poses and those kept back)")
    p.add_argument("--shared-only", action="store_true", help="only the shared poses, none kept back")
    p.add_argument("--max-influences", type=int, default=gt.MAX_INFLUENCES,
                   help=f"bones per vertex of the product's weights (default {gt.MAX_INFLUENCES})")
    p.add_argument("--fit", action="store_true", help="also the pose fit (slower)")
    p.add_argument("--json", help="write every row to this JSON file")
    p.add_argument("--speed", action="store_true", help="only the pose fit's seconds per pose, beside the baseline")
    p.add_argument("--untangle", action="store_true",
                   help="only the pose fit as it is and untangled, in the shared poses (or --poses)")
    args = p.parse_args(argv)
    if args.speed:
        speed(poses=args.poses or POSES)
        return
    if args.untangle:
        untangle(args.garments, args.poses or POSES)
        return
    rows = run(args.garments, args.poses, args.fit, say=lambda line: print(line, file=sys.stderr, flush=True),
               kept_back=not args.shared_only, max_influences=args.max_influences)
    methods = [m for m in rows[0] if isinstance(rows[0][m], dict) and m != "fit"] if rows else []
    for loose, title in ((False, "MakeHuman suits"), (True, "the demo's dresses and skirts")):
        if any(r["loose"] == loose for r in rows):
            print(f"\n{title} (summed over the garments; stretch: means)\n")
            print("\n".join(per_pose_table(rows, loose, methods)))
            if args.fit:
                print()
                print("\n".join(fit_table(rows, loose)))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
