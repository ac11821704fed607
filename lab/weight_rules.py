"""Weight rules tried for garments in motion, against the nearest-surface rule: crossings and stretch per pose.

Every rule starts from the body's weights read at each garment vertex's closest point (the nearest-surface rule)
and the vertices matched where the cloth lies on the skin facing the same way (``rigging.match``); they differ in
what the other vertices get:

- ``nearest``: the nearest-surface rule itself (every influence; Blender's Data Transfer);
- ``inpainted``: the product's rule (``inpainted_weights``: the smoothest fill, ``-L + L M^-1 L``, 8 influences);
- ``inpainted4``: the same with 4 influences;
- ``paper``: the inpainting, then the paper's smoothing pass (Abdrashitov et al. 2023, their code: 10 rounds of
  0.2 towards the neighbours' mean, only on the unmatched vertices and the matched ones within the match
  distance of them);
- ``harmonic``: the fill minimising ``-L`` alone (no biharmonic term: no extrapolation of a gradient);
- ``match5``: matching up to 5% of the body's scale (the paper's threshold, about 10 cm), then inpainting;
- ``geodesic``: each unmatched vertex takes the weights of the matched vertex nearest along the garment's edges
  (a piecewise constant fill: a skirt's columns follow the hip above them rigidly);
- ``seams``: the nearest-surface weights, smoothed (5 rounds of 0.5) only within one ring of their seams (edges
  whose weights differ by more than 0.5);
- ``soft``: the fill pulled towards the nearest-surface weights where the cloth is close to the body
  (``+ lambda |w - nearest|^2``, lambda falling with the distance over 2% of the body's scale);
- ``legs_averaged``: the inpainting, then each unmatched vertex's left and right bones averaged (a skirt's hem
  moves with both legs alike).
- ``range_of_motion`` (and ``range_of_motion70``): the weights checked as riggers check them, by a range of
  motion made from the skeleton alone: the ``ROM_BONES`` bones on which the inpainted and the nearest rule
  disagree most (the weight each bone and the bones below it move, summed over the garment; roots left out),
  each swung by +-45 (70) degrees about the two axes across it; where the two rules differ in that bone's weight
  by more than 0.02, each vertex's depth inside the posed body under each rule; a vertex takes the nearest
  rule's weights where the inpainted rule's depths over all the swings exceed the nearest rule's by 0.05% of the
  body's size, the choice grown by two rings and smoothed by two, the two rules blended by it, 8 influences.

Stretch (the share of triangles stretched by more than 20% and 100%) is measured on every garment and pose
(skinning is cheap); crossings, the costly part, with ``--crossings`` on the garments given.

    python -m lab.weight_rules [--garments g ...] [--rules r ...] [--crossings] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import dijkstra

import garment_transfer as gt
from garment_transfer.geometry import connected_pieces, vertex_areas
from garment_transfer.rigging import (cotangent_laplacian, inpaint, match, skin_weights, smoothness_matrix,
                                      surface_weights)

from .motion import LOOSE, POSES, SUITS, PosedBody, crossing_figures, mirror_name, pose_set, rest_garments, \
    rig_of, stretch_figures
from .paths import makehuman_folder


def _adjacency_mean(n, F):
    i, j = F.reshape(-1), np.roll(F, 1, axis=1).reshape(-1)
    A = sp.csr_matrix((np.ones(i.size), (i, j)), shape=(n, n))
    A = ((A + A.T) > 0).astype(np.float64)
    degree = np.asarray(A.sum(axis=1)).ravel()
    return A, sp.diags(1.0 / np.maximum(degree, 1.0)) @ A


def _smooth(X, mean, rounds, alpha, where=None):
    X = X.copy()
    for _ in range(rounds):
        Y = (1 - alpha) * X + alpha * (mean @ X)
        X = Y if where is None else np.where(where[:, None], Y, X)
    return X


class Problem:
    """What every rule needs of one garment on one body: nearest weights, matches, distances."""

    def __init__(self, body, garment, weights, surface, distance_share=0.02):
        self.body, self.garment, self.weights = body, garment, weights
        scale = gt.body_scale(body.V)
        self.scale = scale
        self.matched, self.dist, _, _ = match(body.V, body.F, garment.V, garment.F, distance_share * scale,
                                              surface=surface)
        # A piece with no matched vertex follows its vertex nearest the body (as inpainted_weights does).
        _, label = connected_pieces(garment.n_vertices, garment.F)
        for piece in np.unique(label):
            members = np.flatnonzero(label == piece)
            if not self.matched[members].any():
                self.matched[members[np.argmin(self.dist[members])]] = True
        near = surface_weights(body.V, body.F, weights.W, garment.V, surface)
        self.present = np.flatnonzero(np.asarray(abs(near).sum(axis=0)).ravel() > 0)
        self.nearest = near[:, self.present].toarray()
        self.A, self.mean = _adjacency_mean(garment.n_vertices, garment.F)

    def known(self):
        return self.matched

    def values(self):
        X = np.zeros_like(self.nearest)
        X[self.matched] = self.nearest[self.matched]
        return X

    def weights_of(self, X, k=8):
        X = np.clip(X, 0.0, 1.0)
        p = X.shape[0]
        W = sp.csr_matrix((X.ravel(), (np.repeat(np.arange(p), self.present.size), np.tile(self.present, p))),
                          shape=(p, len(self.weights.groups)))
        w = skin_weights(self.weights.groups, W, "trial")
        return w.limited(k) if k else w.normalised()


def _inpainted(P, Q=None):
    g = P.garment
    return inpaint(smoothness_matrix(g.V, g.F) if Q is None else Q, P.known(), P.values())


def rule_paper(P):
    X = _inpainted(P)
    region = ~P.matched
    if region.any() and P.matched.any():
        from scipy.spatial import cKDTree

        d, _ = cKDTree(P.garment.V[region]).query(P.garment.V[P.matched])
        region[np.flatnonzero(P.matched)[d < 0.02 * P.scale]] = True
    return P.weights_of(_smooth(X, P.mean, 10, 0.2, region))


def rule_harmonic(P):
    g = P.garment
    return P.weights_of(_inpainted(P, (-cotangent_laplacian(g.V, g.F)).tocsc()))


def rule_geodesic(P):
    g = P.garment
    i, j = g.F.reshape(-1), np.roll(g.F, 1, axis=1).reshape(-1)
    G = sp.csr_matrix((np.linalg.norm(g.V[i] - g.V[j], axis=1), (i, j)), shape=(g.n_vertices,) * 2)
    _, _, source = dijkstra(G.maximum(G.T), directed=False, indices=np.flatnonzero(P.matched), min_only=True,
                            return_predecessors=True)
    X = P.values()
    free = ~P.matched & (source >= 0)
    X[free] = X[source[free]]
    return P.weights_of(X, k=0)


def rule_seams(P):
    X = P.nearest
    A = P.A.tocoo()
    jump = np.abs(X[A.row] - X[A.col]).sum(axis=1)
    band = np.zeros(X.shape[0], dtype=bool)
    band[A.row[jump > 0.5]] = True
    band |= (P.A @ band.astype(np.float64)) > 0
    return P.weights_of(_smooth(X, P.mean, 5, 0.5, band), k=0)


def rule_soft(P, mu=100.0, sigma=0.02):
    g = P.garment
    Q = smoothness_matrix(g.V, g.F)
    area = vertex_areas(g.V, g.F)
    lam = mu * np.exp(-(P.dist / (sigma * P.scale)) ** 2) * area / area.mean()
    X, known, free = P.values(), P.known(), ~P.known()
    Quu = (Q[free][:, free] + sp.diags(lam[free])).tocsc()
    X[free] = spla.splu(Quu).solve(-(Q[free][:, known] @ X[known]) + lam[free, None] * P.nearest[free])
    return P.weights_of(X)


def rule_legs_averaged(P):
    X = _inpainted(P)
    names = [P.weights.groups[j] for j in P.present]
    index = {n: i for i, n in enumerate(names)}
    mirror = np.array([index.get(mirror_name(n), i) for i, n in enumerate(names)])
    free = ~P.matched
    X[free] = 0.5 * (X[free] + X[free][:, mirror])
    return P.weights_of(X)


#: The bones a range of motion swings (``rule_range_of_motion``).
ROM_BONES = 8


def _moved_by(weights, skeleton):
    """(p, b): at each vertex, the weight that each bone and the bones below it move."""
    moved = weights.subset(skeleton.names).W.toarray()
    for b in range(skeleton.n_bones - 1, -1, -1):   # parents come before their children
        if skeleton.parents[b] >= 0:
            moved[:, skeleton.parents[b]] += moved[:, b]
    return moved


def _rows_of(weights, rows):
    return gt.SkinWeights(weights.groups, weights.W.tocsr()[rows], weights.name)


def rule_range_of_motion(b, g, w, s, rig, degrees=45.0, bones=ROM_BONES, share=0.0005, rings=2):
    from scipy.spatial.transform import Rotation

    inpainted = gt.inpainted_weights(b.V, b.F, w, g.V, g.F, surface=s)[0]
    nearest = gt.nearest_weights(b.V, b.F, w, g.V, surface=s, max_influences=gt.MAX_INFLUENCES)
    skeleton = rig.skeleton
    differ = np.abs(_moved_by(inpainted, skeleton) - _moved_by(nearest, skeleton))
    total = differ.sum(axis=0)
    total[np.asarray(skeleton.parents) < 0] = 0.0
    heads, tails = rig.rest()
    score = np.zeros(g.n_vertices)
    for bone in [k for k in np.argsort(-total)[:bones] if total[k] > 0]:
        rows = np.flatnonzero(differ[:, bone] > 0.02)
        along = (tails[bone] - heads[bone]) / np.linalg.norm(tails[bone] - heads[bone])
        across = np.cross(along, np.eye(3)[np.argmin(np.abs(along))])
        across /= np.linalg.norm(across)
        for axis in (across, np.cross(along, across)):
            for sign in (1.0, -1.0):
                R = np.tile(np.eye(3), (skeleton.n_bones, 1, 1))
                R[bone] = Rotation.from_rotvec(sign * np.radians(degrees) * axis).as_matrix()
                T = rig.transforms(R)
                posed = gt.TriangleSurface(rig.pose(b.V, T), b.F)
                depth = [np.maximum(0.0, -posed.signed_distance(rig.pose(g.V[rows], T, _rows_of(x, rows)))[0])
                         for x in (inpainted, nearest)]
                score[rows] += depth[0] - depth[1]
    A, mean = _adjacency_mean(g.n_vertices, g.F)
    share_nearest = (score > share * gt.body_scale(b.V)).astype(np.float64)
    for _ in range(rings):
        share_nearest = np.maximum(share_nearest, mean @ share_nearest)
    share_nearest = _smooth(share_nearest[:, None], mean, rings, 0.5)[:, 0]
    W = sp.diags(1.0 - share_nearest) @ inpainted.W + sp.diags(share_nearest) @ nearest.W
    return gt.SkinWeights(inpainted.groups, sp.csr_matrix(W), "range of motion").limited(gt.MAX_INFLUENCES)


#: The rules that need the body's rig (called with it).
RIGGED = {"range_of_motion", "range_of_motion70"}


def rules():
    """name -> rule(body, garment, body weights, surface) -> SkinWeights (those of ``RIGGED`` take the body's rig
    after the surface)."""
    def nearest(b, g, w, s):
        return gt.nearest_weights(b.V, b.F, w, g.V, surface=s)

    def inpainted(b, g, w, s, k=gt.MAX_INFLUENCES):
        return gt.inpainted_weights(b.V, b.F, w, g.V, g.F, surface=s, max_influences=k)[0]

    def trial(fn, share=0.02):
        return lambda b, g, w, s: fn(Problem(b, g, w, s, share))

    return {"nearest": nearest, "inpainted": inpainted, "inpainted4": lambda b, g, w, s: inpainted(b, g, w, s, 4),
            "paper": trial(rule_paper), "harmonic": trial(rule_harmonic),
            "match5": lambda b, g, w, s: gt.inpainted_weights(b.V, b.F, w, g.V, g.F, surface=s,
                                                              distance=0.05 * gt.body_scale(b.V))[0],
            "geodesic": trial(rule_geodesic), "seams": trial(rule_seams), "soft": trial(rule_soft),
            "legs_averaged": trial(rule_legs_averaged), "range_of_motion": rule_range_of_motion,
            "range_of_motion70": lambda b, g, w, s, rig: rule_range_of_motion(b, g, w, s, rig, degrees=70.0)}


def run(garments, names, with_crossings, say):
    root = makehuman_folder()
    if root is None:
        raise SystemExit("the MakeHuman fixtures are not there (../shared/data/makehuman)")
    skeleton = gt.read_skeleton(root / "rig" / "skeleton.json")
    body_weights = gt.read_weights(root / "rig" / "weights.json", 13380)
    poses = pose_set(root, skeleton)
    table = rules()
    chosen = {n: table[n] for n in names}
    rows, posed = [], {}
    for name, (body_name, garment) in rest_garments(root, garments, say).items():
        body = gt.read_obj(root / "bodies" / f"{body_name}.obj")
        rig = rig_of(root, body_name, skeleton, body_weights)
        surface = gt.TriangleSurface(body.V, body.F)
        offset = gt.OFFSET_SHARE * gt.body_scale(body.V)
        gF = gt.every_split(garment)
        weights = {n: make(body, garment, body_weights, surface, *([rig] if n in RIGGED else []))
                   for n, make in chosen.items()}
        for pose, R in poses.items():
            T = rig.transforms(R)
            row = {"garment": name, "pose": pose, "loose": name not in SUITS}
            if with_crossings and (body_name, pose) not in posed:
                posed[body_name, pose] = PosedBody(body, rig.pose(body.V, T), offset)
            for n, w in weights.items():
                V = rig.pose(garment.V, T, w)
                row[n] = stretch_figures(garment.V, V, garment.F)
                if with_crossings:
                    row[n].update(crossing_figures(V, gF, posed[body_name, pose]))
            rows.append(row)
        say(f"{name}: done")
    return rows


def table_lines(rows, names, loose):
    sel = [r for r in rows if r["loose"] == loose]
    poses = list(dict.fromkeys(r["pose"] for r in sel))
    crossings = "crossings" in sel[0][names[0]]
    lines = ["| rule | stretched >20%: mean | >100% | poses with fewer >20% than nearest |"
             + (" crossings (x nearest) | away from contact (x nearest) | poses with no more crossings |"
                if crossings else ""),
             "|---|---:|---:|---:|" + ("---:|---:|---:|" if crossings else "")]
    for n in names:
        s20 = {p: np.mean([r[n]["stretched_20"] for r in sel if r["pose"] == p]) for p in poses}
        near = {p: np.mean([r["nearest"]["stretched_20"] for r in sel if r["pose"] == p]) for p in poses}
        line = (f"| {n} | {np.mean(list(s20.values())):.4f} | {np.mean([r[n]['stretched_100'] for r in sel]):.4f} | "
                f"{sum(s20[p] < near[p] for p in poses)} of {len(poses)} |")
        if crossings:
            c = {p: sum(r[n]["crossings"] for r in sel if r["pose"] == p) for p in poses}
            cn = {p: sum(r["nearest"]["crossings"] for r in sel if r["pose"] == p) for p in poses}
            a, an = (sum(r[m]["away_from_contact"] for r in sel) for m in (n, "nearest"))
            line += (f" {sum(c.values())} ({sum(c.values()) / max(sum(cn.values()), 1):.2f}) | {a} "
                     f"({a / max(an, 1):.2f}) | {sum(c[p] <= cn[p] for p in poses)} of {len(poses)} |")
        lines.append(line)
    return lines


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.weight_rules", description=__doc__.split("\n\n")[0])
    p.add_argument("--garments", nargs="+", help="default: the 8 suits and the 14 dresses and skirts")
    p.add_argument("--rules", nargs="+", default=list(rules()), choices=list(rules()))
    p.add_argument("--crossings", action="store_true", help="count crossings too (slow)")
    p.add_argument("--json", help="write every row to this JSON file")
    args = p.parse_args(argv)
    names = list(dict.fromkeys(["nearest", *args.rules]))
    rows = run(args.garments or [*SUITS, *LOOSE], names, args.crossings,
               lambda line: print(line, file=sys.stderr, flush=True))
    for loose, title in ((False, "MakeHuman suits"), (True, "the demo's dresses and skirts")):
        if any(r["loose"] == loose for r in rows):
            print(f"\n{title}, {len({r['pose'] for r in rows})} poses ({len(POSES)} shared, the rest kept back)\n")
            print("\n".join(table_lines(rows, names, loose)))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
