"""The final pass: no garment edge through the body, no body edge through the garment, checked exactly,
under every reading of the garment's and the body's polygons.

The vertex push-out (``penetration.fix_penetration``) leaves a garment whose vertices are outside
the body, but an edge can still cut through a body part narrower than the edge (a finger, the gap
between the thighs) and a body vertex can still poke through a garment triangle (a breast or
shoulder under a coarse garment). This pass finds every such crossing with the exact test of
``intersections`` and turns each into a lower bound on the garment's outward move at one
point (``Lifts``): a garment edge through a body triangle lifts its ends past the triangle's
plane; a body edge through a garment triangle lifts the triangle's point over it, shared by the
corners by their barycentric weights (the least lift of the corners that raises that point, so a
corner far from the contact hardly moves). Each vertex takes the largest lift it is given, the lifts
are spread over a few rings of the garment (a screened Laplace problem: the folds, shorter than the
spread, stay), and what moved is checked again, exactly. The same bounds keep a clearance: garment-
body pairs (vertex-triangle both ways, edge-edge) closer than ``CLEARANCE_SHARE`` of the offset are
lifted to ``CLEARANCE_PUSH`` times that, and crossings are cleared to the same distance, not to the
whole offset (further lifts only cost the design). It ends when nothing is left or after
``max_rounds``; then the round that left the fewest crossings is kept (each round pushes harder, which a
fold of the body or two body parts closing on the cloth can turn into more crossings), and the result says how
many are left (it never hides one).

Every check is made on every reading of the polygons (``readings.Readings``: both splits of each quad,
every diagonal as an edge) of the garment and of the body, so that the result is clean whichever
triangulation the user's tool makes of the file; a lift through a triangle of the other split moves
the same garment vertices.

Moving cloth can make it cross itself. Every round is checked against that: the self-intersections
among the triangles it moved are counted before and after, and a round that adds some is halved on
the garment parts involved (at most three times, then taken back there). After ``PROTECT_ROUNDS``
rounds a crossing of the body comes first: it is removed even if the cloth then crosses itself, and
the result counts what was added. The clearance is best effort: it never makes the cloth cross
itself, and the result counts the pairs still too close.

Given the source shape, the pass also undoes the self-intersections that the source does not have:
layers of cloth closer than the offset (a waistband, a pocket, a fold) are pushed onto the same
offset surface by the vertex push-out and pass through each other, and the transfer itself can
press them together. Around each such (edge, triangle) pair the cloth takes the shape it had before the
pass (where the pass pushed layers through each other, that shape lacks the pair and is bent over this
body already), then its source shape (``RESTORE_SHAPES``), each mapped by the affine map that fits it best to
where it is (an invertible affine map keeps which parts meet and which do not), blended into the rest over a
ring by its edges (``blend_edges``: each edge turns from one shape's to the other's, so the ring bends no more
than the two shapes do); the body is then cleared again where that moved, and a larger ring is tried if pairs
are left. A clean try that bends the cloth much more than the pass was given is looked at once more with its
core held loosely, kept if that is clean too and bends the cloth less (``RESTORE_LOOSE_HOLD``). What is left is
counted (``self_intersections_new``), never hidden.

What it costs: the body does not move, so its triangles, edges and vertices are binned once
(``Obstacle``: grids of ``broad_phase.BoxGrid``) and every check asks about the garment's parts only;
after the first full check only what a round moved is checked again (``crossings_again``,
``near_pairs_again``, ``SelfCheck``: the garment's own parts binned with room to move, binned again
only when something moved beyond it), and the self-intersections of the current shape are kept from
round to round, not counted again. Each predicate is the filtered floating-point orient3d, with the
exact fallback only where the filter cannot decide (``intersections.segments_meet_triangles``). The checks that
do not depend on each other (the crossings, the close pairs and the garment's own pairs) run side by side where a
core is free (``threads.together``).
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .intersections import segment_closest, segment_distances
from .mesh import discrete_curvature
from .obstacle import Obstacle, as_obstacle, edge_length, faces_touching, garment_crossings, polygon_pairs
from .penetration import spread_displacement, vertex_adjacency
from .proximity import closest_on_triangles
from .readings import Readings, as_readings, group_members
from .self_check import NO_PAIRS, SelfCheck, beyond_source, pairs_in_full, unique_pairs
from .threads import together

log = logging.getLogger(__name__)

#: The pass keeps every garment-body pair (vertex-triangle both ways, edge-edge) at least this share
#: of the offset apart; a closer pair is pushed to ``CLEARANCE_PUSH`` times that. Garment vertices
#: keep the whole offset (the penetration fix); asking it of every edge and body vertex too would
#: move skin-tight garments a lot (measured in lab.intersections).
CLEARANCE_SHARE = 0.25
CLEARANCE_PUSH = 1.5
#: Rings of garment vertices over which a crossing's push fades out.
SPREAD_RINGS = 2.0
#: Each round pushes further than the last by this share of the offset (escapes stubborn cases).
GAIN = 0.5
#: Rounds in which a push that makes the cloth cross itself is held back; later the body comes first.
PROTECT_ROUNDS = 3
#: Once nothing crosses, the clearance alone gets at most this many rounds (it is best effort).
CLEARANCE_ROUNDS = 2
#: Around a self-intersection the source does not have, the cloth within this many offsets (times the
#: radius's rank, up to ``RESTORE_RADII``) takes another shape (``restore_source_shape``).
RESTORE_RADIUS = 2.2
RESTORE_RADII = 4
#: The shapes tried at each radius, each left where it is, then moved out as one piece: the shape the cloth
#: had before the pass, around the pairs the pass made (it lacks them and is nearest the result: measured on
#: male suits onto female bodies far from the source, MDC 1.02-1.06x the result without the pass, against
#: 1.12-1.21x with the source's shape alone), then the source's, around every pair.
RESTORE_SHAPES = ("before the pass", "source")
#: The tries end after this many in a row that leave no fewer crossings, pairs the source lacks or close pairs than
#: the best so far (a garment pressed through the body can tangle it beyond any shape's reach: a suit carried onto
#: a posed body without the pose fit's contact rule, lab.motion's baseline, tried all 16 for up to 65 s).
RESTORE_PATIENCE = 8
#: A local affine fit whose smallest singular value is under this share of its largest would
#: flatten the cloth: a similarity is fitted instead.
FIT_CONDITION = 0.2
#: A restore that comes out clean but bends the cloth away from its source more than ``LOOSE_LOOK_FROM`` times as
#: much as the cloth the pass was given (mean change of ``discrete_curvature``, paper eq. 9: the measure of MDC)
#: is tried again with its core held this loosely (``blend_edges``: the core then shares the mismatch with the
#: ring), at each of ``LOOSE_RINGS``, and the one that bends the cloth least is kept if it is clean too. Held
#: exactly, the core is the affine image that undoes the pairs; held loosely it may not be, hence only as a second
#: look (lab/notes/file-check-study.md).
RESTORE_LOOSE_HOLD = 2.0
LOOSE_LOOK_FROM = 1.08
#: The second look's rings, as shares of the try's radius: the same, and half as wide again.
LOOSE_RINGS = (1.0, 1.5)


class Lifts:
    """Lower bounds on the garment's displacement D, one per contact: ``sum_j w_j n . D[v_j] >= h``
    (a point of the garment, given by its vertices and their weights, rises by ``h`` along ``n``).
    Collected over a round and met together by ``lift_displacement``."""

    def __init__(self):
        self.vid, self.weight, self.normal, self.need = [], [], [], []

    def add(self, vid, weight, normal, need):
        """Add bounds; those with ``need <= 0`` are met already and left out.

        Parameters
        ----------
        vid : (k,j) int
            The garment vertices of each point.
        weight : (k,j) float
            Their weights (barycentric coordinates).
        normal : (k,3) float
            Unit directions.
        need : (k,) float
        """
        keep = need > 0
        if keep.any():
            self.vid.append(np.asarray(vid, np.int64)[keep])
            self.weight.append(np.asarray(weight, np.float64)[keep])
            self.normal.append(np.asarray(normal, np.float64)[keep])
            self.need.append(np.asarray(need, np.float64)[keep])

    def extend(self, other):
        """Add every bound of another ``Lifts``."""
        self.vid += other.vid
        self.weight += other.weight
        self.normal += other.normal
        self.need += other.need

    def __len__(self):
        return int(sum(h.shape[0] for h in self.need))

    def arrays(self):
        """The bounds as ``row (r,), vid (r,), weight (r,)`` (one entry per vertex of a point) and
        ``normal (c,3), need (c,)`` (one per bound)."""
        rows, vid, weight, start = [], [], [], 0
        for v, w in zip(self.vid, self.weight):
            k, j = v.shape
            rows.append(np.repeat(np.arange(start, start + k), j))
            vid.append(v.ravel())
            weight.append(w.ravel())
            start += k
        return (np.concatenate(rows), np.concatenate(vid), np.concatenate(weight),
                np.concatenate(self.normal), np.concatenate(self.need))


# --------------------------------------------------------------------------- garment against the obstacle

def crossings_again(V, G: Readings, obstacle: Obstacle, c, moved):
    """``garment_crossings`` after only the ``moved`` ((n,) bool) vertices moved: the pairs of unmoved
    garment edges and triangles are kept from ``c``, the others checked again (exactly; the obstacle does
    not move). Same keys as ``crossings`` that the pass uses."""
    keep_a = ~moved[c["a_pairs"]].any(axis=1)
    keep_b = ~moved[G.F[c["b_triangles"]]].any(axis=1)
    new = garment_crossings(V, G, obstacle, moved)
    out = {"a_pairs": np.concatenate([c["a_pairs"][keep_a], new["a_pairs"]]),
           "a_triangles": np.concatenate([c["a_triangles"][keep_a], new["a_triangles"]]),
           "b_pairs": np.concatenate([c["b_pairs"][keep_b], new["b_pairs"]]),
           "b_triangles": np.concatenate([c["b_triangles"][keep_b], new["b_triangles"]])}
    out["a_edge_pairs"] = int(out["a_triangles"].shape[0])
    out["b_edge_pairs"] = int(out["b_triangles"].shape[0])
    return out


def crossing_lifts(V, G: Readings, obstacle: Obstacle, c, clear, lifts):
    """Bounds that take the garment out of every crossing, by ``clear``.

    A garment edge through an obstacle triangle: its point in the triangle's plane to ``clear`` outside
    it, the lift shared by the two ends by their weights. An obstacle edge through a garment triangle:
    the triangle's point over each end of the edge (its barycentric coordinates) to ``clear`` past that
    end along the skin's normal; the corners then share the lift by their weights, so a corner far from
    the body edge hardly moves.

    Parameters
    ----------
    V : (n,3) float64
    G : Readings
        The garment's.
    obstacle : Obstacle
    c : dict
        ``garment_crossings(V, G, obstacle)``.
    clear : float
    lifts : Lifts
        Added to.
    """
    if c["a_pairs"].shape[0]:
        n = obstacle.face_normals[c["a_triangles"]]
        a = obstacle.V[obstacle.F[c["a_triangles"], 0]]
        P, Q = V[c["a_pairs"][:, 0]], V[c["a_pairs"][:, 1]]
        # The edge's point in the triangle's plane rises over it, shared by the ends by their weights:
        # lifting each end past the plane would move a long edge across a tilted triangle by far more.
        den = np.einsum("ij,ij->i", Q - P, n)
        flat = np.abs(den) <= 1e-12 * np.linalg.norm(Q - P, axis=1)
        s = np.clip(np.divide(np.einsum("ij,ij->i", a - P, n), den, out=np.full(den.shape, 0.5), where=~flat), 0, 1)
        X = P + s[:, None] * (Q - P)
        lifts.add(c["a_pairs"], np.stack([1.0 - s, s], axis=1), n, clear - np.einsum("ij,ij->i", X - a, n))
    if c["b_pairs"].shape[0]:
        n = obstacle.vertex_normals[c["b_pairs"][:, 0]] + obstacle.vertex_normals[c["b_pairs"][:, 1]]
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        tri = G.F[c["b_triangles"]]
        for end in (0, 1):
            q = obstacle.V[c["b_pairs"][:, end]]
            p, bary = closest_on_triangles(q, V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]])
            lifts.add(tri, bary, n, np.einsum("ij,ij->i", q - p, n) + clear)


def near_pairs(V, G: Readings, obstacle: Obstacle, near, active=None):
    """Garment-obstacle pairs closer than ``near``: garment vertex - obstacle surface, obstacle vertex -
    garment triangle, garment edge - obstacle edge (every reading's edges and triangles).

    Parameters
    ----------
    V : (n,3) float64
    G : Readings
    obstacle : Obstacle
    near : float
    active : (n,) bool, optional
        Only garment vertices, triangles and edges with an active vertex are looked at.

    Returns
    -------
    dict
        ``vertex`` (k,) garment vertices, ``triangle`` (k,2) (obstacle vertex, garment triangle),
        ``edge`` (k,2) (garment edge, obstacle edge).
    """
    if active is None:
        active = np.ones(V.shape[0], bool)
    out = {"vertex": np.zeros(0, np.int64), "triangle": NO_PAIRS, "edge": NO_PAIRS}
    idx = np.flatnonzero(active)
    if idx.size == 0:
        return out
    out["vertex"] = idx[obstacle.surface.signed_distance(V[idx])[0] < near]
    Pg, Pb = polygon_pairs(V, G, obstacle, faces_touching(G, active), near)
    # Obstacle vertices (its polygons' corners) near the garment polygons' triangles.
    which, tri = G.triangles_of(Pg)
    keep = active[G.F[tri]].any(axis=1)
    tri, Pt = tri[keep], Pb[which[keep]]
    which, corner = group_members(obstacle.R.face_start, None, Pt)
    key = np.unique(obstacle.R.face_vertices[corner] * G.n_triangles + tri[which])
    i, t = key // G.n_triangles, key % G.n_triangles
    keep = _within(obstacle.V, i[:, None], V, G.F[t], near)
    i, t = i[keep], t[keep]
    T = V[G.F[t]]
    p, _ = closest_on_triangles(obstacle.V[i], T[:, 0], T[:, 1], T[:, 2])
    k = np.linalg.norm(p - obstacle.V[i], axis=1) < near
    out["triangle"] = np.stack([i[k], t[k]], axis=1)
    # The garment polygons' own edges near the obstacle polygons' own edges.
    which, e = G.edges_of(Pg)
    keep = active[G.E[e]].any(axis=1)
    e, Pe = e[keep], Pb[which[keep]]
    which, b = obstacle.R.edges_of(Pe)
    e = e[which]
    k = np.flatnonzero(_within(obstacle.V, obstacle.E[b], V, G.E[e], near))
    e, b = e[k], b[k]
    k = segment_distances(V[G.E[e, 0]], V[G.E[e, 1]], obstacle.V[obstacle.E[b, 0]], obstacle.V[obstacle.E[b, 1]]) < near
    out["edge"] = np.stack([e[k], b[k]], axis=1)
    return out


def _within(V_a, a, V_b, b, pad):
    """(k,) bool: the box of the points ``a`` (k,i) of V_a meets the box of ``b`` (k,j) of V_b grown by ``pad``,
    axis by axis."""
    keep = np.ones(a.shape[0], bool)
    for axis in range(3):
        x, y = V_a[:, axis][a], V_b[:, axis][b]
        a_lo, a_hi, b_lo, b_hi = x[:, 0], x[:, 0], y[:, 0], y[:, 0]
        for c in range(1, a.shape[1]):
            a_lo, a_hi = np.minimum(a_lo, x[:, c]), np.maximum(a_hi, x[:, c])
        for c in range(1, b.shape[1]):
            b_lo, b_hi = np.minimum(b_lo, y[:, c]), np.maximum(b_hi, y[:, c])
        keep &= (b_lo - pad <= a_hi) & (a_lo <= b_hi + pad)
    return keep


def near_pairs_again(V, G: Readings, obstacle: Obstacle, near, pairs, moved):
    """``near_pairs`` after only the ``moved`` ((n,) bool) vertices moved: the pairs of unmoved
    garment parts are kept, the others found again."""
    out = near_pairs(V, G, obstacle, near, moved)
    keep = {"vertex": ~moved[pairs["vertex"]], "triangle": ~moved[G.F[pairs["triangle"][:, 1]]].any(axis=1),
            "edge": ~moved[G.E[pairs["edge"][:, 0]]].any(axis=1)}
    return {k: np.concatenate([pairs[k][keep[k]], out[k]]) for k in out}


def near_count(pairs):
    """The number of pairs in a ``near_pairs`` answer."""
    return sum(int(v.shape[0]) for v in pairs.values())


def near_lifts(V, G: Readings, obstacle: Obstacle, offset, near, pairs, lifts):
    """Bounds that take garment parts closer to the obstacle than ``near`` away (no crossing needed): a
    garment vertex to ``offset`` (what the penetration fix gave it), the point of a garment triangle
    nearest an obstacle vertex and the point of a garment edge nearest an obstacle edge to
    ``CLEARANCE_PUSH * near``.

    Parameters
    ----------
    V : (n,3) float64
    G : Readings
    obstacle : Obstacle
    offset, near : float
    pairs : dict
        ``near_pairs(...)``.
    lifts : Lifts
        Added to.
    """
    close = pairs["vertex"]
    if close.size:
        sd, _, normal, _ = obstacle.surface.signed_distance(V[close])
        lifts.add(close[:, None], np.ones((close.size, 1)), normal, offset - sd)
    if pairs["triangle"].shape[0]:
        q = obstacle.V[pairs["triangle"][:, 0]]
        tri = G.F[pairs["triangle"][:, 1]]
        p, bary = closest_on_triangles(q, V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]])
        n = obstacle.vertex_normals[pairs["triangle"][:, 0]]
        lifts.add(tri, bary, n, np.einsum("ij,ij->i", q - p, n) + CLEARANCE_PUSH * near)
    if pairs["edge"].shape[0]:
        i, j = pairs["edge"][:, 0], pairs["edge"][:, 1]
        P0, P1 = V[G.E[i, 0]], V[G.E[i, 1]]
        Q0, Q1 = obstacle.V[obstacle.E[j, 0]], obstacle.V[obstacle.E[j, 1]]
        s, t = segment_closest(P0, P1, Q0, Q1)
        p = P0 + s[:, None] * (P1 - P0)
        q = Q0 + t[:, None] * (Q1 - Q0)
        n = obstacle.vertex_normals[obstacle.E[j, 0]] + obstacle.vertex_normals[obstacle.E[j, 1]]
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        lifts.add(G.E[i], np.stack([1.0 - s, s], axis=1), n, np.einsum("ij,ij->i", q - p, n) + CLEARANCE_PUSH * near)


def lift_displacement(A, lifts: Lifts, rings):
    """A smooth displacement that meets the bounds: each bound's lift goes to its vertices in
    proportion to their weights (the least lift that raises the point by ``h``: a corner far from
    the contact hardly moves), each vertex takes the largest it is given, and the moves are spread
    over ``rings`` rings of the garment (``penetration.spread_displacement``, a screened Laplace
    problem, which never moves a vertex further than the moves it spreads).

    Parameters
    ----------
    A : (n,n) sparse adjacency (csr, 0/1)
    lifts : Lifts
    rings : float

    Returns
    -------
    D : (n,3) float64
    """
    if not len(lifts):
        return np.zeros((A.shape[0], 3))
    row, vid, weight, normal, need = lifts.arrays()
    norm2 = np.zeros(need.size)
    np.add.at(norm2, row, weight ** 2)
    move = (weight * need[row] / norm2[row])[:, None] * normal[row]
    index, move = largest_per_vertex(vid, move)
    fixed = np.zeros(A.shape[0], bool)
    fixed[index] = True
    return spread_displacement(A, fixed, move, rings)


def largest_per_vertex(index, move):
    """For repeated vertices, keep the longest move. index (k,) int, move (k,3) float."""
    length = np.linalg.norm(move, axis=1)
    order = np.lexsort((-length, index))
    index, move = index[order], move[order]
    first = np.ones(index.shape[0], bool)
    first[1:] = index[1:] != index[:-1]
    return index[first], move[first]


# --------------------------------------------------------------------------- the garment against itself

class _SourceTangles:
    """The source garment's own self-intersecting pairs (found when first asked, unless given), and what of a
    result's pairs counts against it (``self_check.beyond_source``)."""

    def __init__(self, source_V, G: Readings, own=None):
        self.S, self.G, self.own = source_V, G, own

    def pairs(self):
        """The source's own self-intersecting pairs (k,2)."""
        if self.own is None:
            self.own = pairs_in_full(self.S, self.G)
        elif callable(self.own):
            self.own = self.own()
        return self.own

    def known(self):
        """Whether the source's pairs have been found (or were given)."""
        return self.own is not None and not callable(self.own)

    def beyond(self, pairs):
        """The pairs (k,2) of a result that count against the source."""
        return beyond_source(pairs, self.G, self.S, self.pairs())


def local_fit(X, Y, weight):
    """The affine map ``x -> x @ M + b`` that takes points X nearest to Y (weighted least squares),
    or, where that map would fold or flatten the cloth (singular values under ``FIT_CONDITION`` of
    the largest, or a reflection), the best similarity (rotation and one scale, Umeyama).

    Parameters
    ----------
    X, Y : (k,3) float64
    weight : (k,) float64
        Positive.

    Returns
    -------
    (k,3) float64
        The map applied to X.
    """
    w = weight / weight.sum()
    cx, cy = w @ X, w @ Y
    A, B = X - cx, Y - cy
    sw = np.sqrt(w)[:, None]
    M = np.linalg.lstsq(A * sw, B * sw, rcond=None)[0]
    sv = np.linalg.svd(M, compute_uv=False)
    if np.linalg.det(M) > 0 and sv[-1] >= FIT_CONDITION * sv[0]:
        return A @ M + cy
    U, s, Vt = np.linalg.svd((A * w[:, None]).T @ B)
    d = np.ones(3)
    d[2] = np.sign(np.linalg.det(U @ Vt)) or 1.0
    R = (U * d) @ Vt
    scale = (s * d).sum() / max((w * (A ** 2).sum(axis=1)).sum(), 1e-300)
    return scale * A @ R + cy


def restore_source_shape(V, F, E, source_V, pairs, radius, body=None, clear=0.0, hold=np.inf):
    """Around every listed self-intersection, the cloth takes the shape it has on the source.

    The vertices of the pairs, and the cloth within ``radius`` of them (in space, so every sheet
    of a fold that is there), take the affine image of their source shape nearest to where they are
    now (``local_fit``); from ``radius`` to ``2 * radius`` it blends into where they are by its edges
    (``blend_edges``, the core held to its fit by ``hold``). An invertible affine map keeps which edges and
    triangles of the source meet and which do not, so the pairs the source lacks are gone there; the
    blend can make new ones further out (a larger radius is the next try; the caller checks).

    Parameters
    ----------
    V : (n,3) float64
    F : (m,3) int64
    E : (e,2) int64
        ``mesh_edges(F)``.
    source_V : (n,3) float64
    pairs : (k,2) int64
        (edge index, triangle index) self-intersections of V.
    radius : float
    body : TriangleSurface, optional
        With it, each restored piece is moved out along its mean normal, as one (a translation keeps
        the source shape), until its closest vertex is ``clear`` from the body.
    clear : float
    hold : float
        ``blend_edges``': how strongly the restored core is held (``np.inf``: exactly, the affine image).

    Returns
    -------
    (n,3) float64
        A new array.
    """
    seeds = np.unique(np.concatenate([E[pairs[:, 0]].ravel(), F[pairs[:, 1]].ravel()]))
    # Seeds close together are one piece of cloth, fitted as one.
    close = cKDTree(V[seeds]).query_pairs(2 * radius, output_type="ndarray")
    count, label = connected_components(sp.coo_matrix((np.ones(close.shape[0]), (close[:, 0], close[:, 1])),
                                                      shape=(seeds.size, seeds.size)), directed=False)
    tree = cKDTree(V)
    weight, restored = np.zeros(V.shape[0]), V.copy()
    for c in range(count):
        piece = seeds[label == c]
        region = np.unique(np.concatenate(tree.query_ball_point(V[piece], 2 * radius)))
        w = np.clip(2.0 - cKDTree(V[piece]).query(V[region])[0] / radius, 0.0, 1.0)
        fit = local_fit(source_V[region], V[region], np.maximum(w, 1e-3))
        if body is not None:
            # The piece keeps its distance from the body as a whole: moved out along its mean
            # normal as far as its closest vertex needs (a translation keeps the source shape).
            sd, _, normal, _ = body.signed_distance(fit)
            direction = (w[:, None] * normal).sum(axis=0)
            direction /= max(np.linalg.norm(direction), 1e-300)
            along = np.maximum(normal @ direction, 0.5)
            need = np.max((clear - sd) / along, initial=0.0)
            fit = fit + need * direction
        larger = w > weight[region]
        weight[region[larger]] = w[larger]
        restored[region[larger]] = fit[larger]
    return blend_edges(V, E, restored, weight, hold)


def blend_edges(V, E, restored, weight, hold=np.inf):
    """The cloth blended from its ``restored`` shape (weight 1) into where it is (weight 0) by its edges.

    Each edge with a vertex of weight above 0 takes the blend of its two vectors, ``restored``'s and V's, by its
    ends' mean weight; the positions of those vertices are solved (least squares) for the blended edges, the
    vertices of weight 0 held where they are and those of weight 1 held to ``restored`` with weight ``hold``
    (``np.inf``: exactly). Blending the positions instead shears the ring by the gap between the two shapes, which
    creases it; blended edges bend it no more than the two shapes do. Where ``restored`` is V, the answer is V.

    Parameters
    ----------
    V, restored : (n,3) float64
    E : (e,2) int64
        The cloth's edges.
    weight : (n,) float64
        In [0, 1].
    hold : float
        How strongly the core (weight 1) is held to ``restored`` against its edges; ``np.inf``: it is
        ``restored``.

    Returns
    -------
    (n,3) float64
        A new array; the vertices of weight 0 as in V.
    """
    out = np.array(V, dtype=np.float64)
    free = weight > 0
    if np.isinf(hold):
        # The core takes ``restored`` exactly; only the ring is solved.
        core = weight >= 1.0
        out[core] = restored[core]
        free &= ~core
    if not free.any():
        return out
    i, j = E[:, 0], E[:, 1]
    touching = free[i] | free[j]
    i, j = i[touching], j[touching]
    w = 0.5 * (weight[i] + weight[j])[:, None]
    target = w * (restored[i] - restored[j]) + (1.0 - w) * (V[i] - V[j])
    fv = np.flatnonzero(free)
    index = np.full(V.shape[0], -1, dtype=np.int64)
    index[fv] = np.arange(fv.size)
    at_i, at_j = np.flatnonzero(free[i]), np.flatnonzero(free[j])
    G = sp.csr_matrix((np.concatenate([np.ones(at_i.size), -np.ones(at_j.size)]),
                       (np.concatenate([at_i, at_j]), np.concatenate([index[i[at_i]], index[j[at_j]]]))),
                      shape=(i.size, fv.size))
    # An edge's end that does not move is known (where it is, or an exact core's restored place): it goes to the
    # right-hand side.
    target[~free[i]] -= out[i[~free[i]]]
    target[~free[j]] += out[j[~free[j]]]
    # A soft core is held to its place; the ring by a trace of its blended position, so that a piece of cloth
    # without a held vertex (a loose shell in the ring) still has one answer.
    w_free = weight[fv]
    held = np.where(w_free >= 1.0, hold, 1e-9)
    place = w_free[:, None] * restored[fv] + (1.0 - w_free)[:, None] * V[fv]
    M = (G.T @ G + sp.diags(held)).tocsc()
    out[fv] = spla.splu(M).solve(np.asarray(G.T @ target + held[:, None] * place))
    return out


def separate(V, F, body_V, body_F, offset, *, spread_rings=SPREAD_RINGS, max_rounds=12, surface=None,
             keep_offset=True, source_V=None, source_pairs=None, crossings=None, count_own=True):
    """Remove every crossing between a garment and a body, keeping the folds.

    Parameters
    ----------
    V : (n,3) float
        Garment vertices (best after ``penetration.fix_penetration``: its vertices outside).
    F : (m,3) int or Readings
        Garment triangles, or every reading of its polygons (``readings.readings_of``): then no crossing
        is left under any triangulation of them.
    body_V : (p,3) float
    body_F : (q,3) int, Readings or Obstacle
        The body (or, for outfits, the body and the layers under this one, as one mesh); an
        ``Obstacle`` made already is used as it is (``body_V`` and ``surface`` are then its own).
    offset : float
        The cloth's thickness: garment vertices near the body are lifted to it; crossings and the
        other close pairs are cleared to ``CLEARANCE_PUSH * CLEARANCE_SHARE`` of it (more in later
        rounds, by ``GAIN`` of it per round).
    spread_rings : float
        Rings of garment vertices over which a push fades.
    max_rounds : int
    surface : TriangleSurface, optional
        Of the body's own triangles, when already built.
    keep_offset : bool
        Also push out garment parts closer to the body than ``CLEARANCE_SHARE * offset`` (vertex
        to triangle both ways, edge to edge): the smallest distance kept.
    source_V : (n,3) float, optional
        The garment's source shape. With it, the self-intersections of the result that the source
        does not have (the transfer pressed close layers of cloth through each other) are undone
        too: the cloth around them takes the shape it had before the pass, then its source shape
        (``restore_source_shape``, ``RESTORE_SHAPES``), and the body is cleared again where that moved it,
        with a larger radius at each of ``RESTORE_RADII``.
    source_pairs : (k,2) int, or a callable that returns them, optional
        The source's own self-intersecting pairs (``SelfCheck(source_V, G).all(source_V)``), when known (a
        callable is asked only when they are needed).
    crossings : dict, optional
        ``obstacle.garment_crossings(V, F, body_F)`` when ``body_F`` is an ``Obstacle`` and they were counted
        already (a caller that counts before deciding to clear).
    count_own : bool
        Count the garment's own self-intersections in full (before and after). False (only without
        ``source_V``): they are checked only where a round moves the cloth, as the rounds need (the same
        result); the info then has no ``self_intersections_*`` figures.

    Returns
    -------
    V : (n,3) float64
        A new array.
    info : dict
        ``crossings_before``, ``crossings_after`` (edge-triangle pairs, both ways),
        ``near_before``, ``near_after`` (primitive pairs closer than ``CLEARANCE_SHARE * offset``),
        ``clearance`` (that distance),
        ``rounds``, ``moved_vertices``, ``self_intersections_before``, ``self_intersections_after`` (pairs
        of the garment), ``self_intersections_added`` (after minus before; 0 unless it could not avoid
        them), ``undone`` (pushes taken back because they made the cloth cross itself). With
        ``source_V``: ``self_intersections_source`` (pairs of the source, when they were needed or given),
        ``self_intersections_new`` (pairs left that count against the source: ``self_check.beyond_source``) and
        ``restored_vertices``. ``kept_input``: True when nothing
        tried was better than the input (more crossings, else more self-intersections, else more near pairs
        than it had): the input is returned.
    """
    V = np.array(V, dtype=np.float64)
    G = as_readings(F)
    obstacle = as_obstacle(body_V, body_F, surface, edge_length(V, G))
    if source_V is not None:
        source_V = np.asarray(source_V, dtype=np.float64)
        if source_V.shape != V.shape:
            raise ValueError(f"source_V must have the garment's shape {V.shape}, got {source_V.shape}")
    if not count_own and source_V is not None:
        raise ValueError("the source's self-intersections are undone only with the garment's own counted in full")
    A = vertex_adjacency(V.shape[0], G.split)
    check = SelfCheck(V, G)
    V_start = V.copy()
    start_pairs = check.all(V) if count_own else _PairsAround(NO_PAIRS, np.zeros(V.shape[0], bool))
    V, info, state = clear_body(V, G, A, obstacle, offset, spread_rings, max_rounds, keep_offset, check,
                                known=(None, (crossings if obstacle is body_F else None, None, start_pairs)))
    if source_V is None:
        given = {}
        if count_own:
            pairs = state[2]
            info.update(self_intersections_before=int(start_pairs.shape[0]),
                        self_intersections_after=int(pairs.shape[0]),
                        self_intersections_added=int(pairs.shape[0] - start_pairs.shape[0]))
            given["self_intersections_after"] = int(start_pairs.shape[0])
        info["kept_input"] = False
        if info["crossings_after"] > info["crossings_before"]:
            log.warning("the crossings pass left %d crossings (%d before): the garment is kept as it was",
                        info["crossings_after"], info["crossings_before"])
            return _as_given(V_start, info, **given)
        return V, info
    info["self_intersections_before"] = int(start_pairs.shape[0])
    return _restore(V, V_start, start_pairs, G, A, obstacle, offset, spread_rings, max_rounds, keep_offset, check,
                    source_V, source_pairs, info, state)


def _restore(V, V_start, start_pairs, G, A, obstacle, offset, spread_rings, max_rounds, keep_offset, check,
             source_V, source_pairs, info, state):
    """``separate``'s second half, with the source shape: the self-intersections the source lacks undone."""
    V_cleared = V
    tangles = _SourceTangles(source_V, G, source_pairs)
    pairs = state[2]
    new = tangles.beyond(pairs)
    # Tries start from the latest shape that still has pairs to undo (``base``); the best result
    # (fewest crossings, then pairs the source lacks, then pairs closer than the clearance) is kept.
    base = best = (V, pairs, new, state, info["crossings_after"], info["near_after"], 0, 0)
    given = None    # the pairs beyond the source's that the pass was given (not its own)
    idle = 0        # tries in a row that did not improve on the best
    best_how = None  # the try that made the best: where it started and how
    for attempt in range(RESTORE_RADII * len(RESTORE_SHAPES) * 2):
        if best[4] == 0 and best[2].shape[0] == 0:
            break   # clean: no crossing, nothing the source lacks (pairs closer than the clearance may be left)
        if idle >= RESTORE_PATIENCE:
            break
        V_b, pairs_b, new_b, state_b = base[:4]
        # At each radius, each of RESTORE_SHAPES, left where it is, then moved out as one piece.
        rank, which, moved_out = np.unravel_index(attempt, (RESTORE_RADII, len(RESTORE_SHAPES), 2))
        shape, seeds = source_V, new_b
        if RESTORE_SHAPES[which] == "before the pass":
            if given is None:
                given = tangles.beyond(start_pairs)
            shape, seeds = V_start, new_b[~_rows_in(new_b, given)]
            if seeds.shape[0] == 0:
                continue
        radius = (rank + 1) * RESTORE_RADIUS * offset
        how = (shape, seeds, radius, obstacle.surface if moved_out else None)
        W, again, state_w = _restore_try(base, how, np.inf, G, A, obstacle, offset, spread_rings, max_rounds,
                                         keep_offset, check)
        pairs_w = state_w[2]
        new_w = tangles.beyond(pairs_w)
        log.debug("restore %d: %d self-intersections the source lacks (%d before), %d crossings, %d near",
                  attempt + 1, new_w.shape[0], new_b.shape[0], again["crossings_after"], again["near_after"])
        tried = (W, pairs_w, new_w, state_w, again["crossings_after"], again["near_after"],
                 base[6] + again["rounds"], base[7] + again["undone"])
        idle += 1
        if (tried[4], tried[2].shape[0], tried[5]) < (best[4], best[2].shape[0], best[5]):
            best, idle, best_how = tried, 0, (base, how)
        if tried[4] <= base[4] and 0 < new_w.shape[0] < new_b.shape[0]:
            base = tried
    if best_how is not None and best[4] == 0 and best[2].shape[0] == 0:
        best = _held_loosely(best, best_how, V_start, source_V, tangles, G, A, obstacle, offset, spread_rings,
                             max_rounds, keep_offset, check)
    V, pairs, new, _, info["crossings_after"], info["near_after"], rounds, undone = best
    info["rounds"] += rounds
    info["undone"] += undone
    if tangles.known():
        info["self_intersections_source"] = int(tangles.pairs().shape[0])
    if ((info["crossings_after"], pairs.shape[0], info["near_after"])
            > (info["crossings_before"], info["self_intersections_before"], info["near_before"])):
        # Nothing it tried is better than what it was given (a garment pressed through the body can leave
        # it more crossings and tangles than before): the garment is returned as it came.
        log.warning("the crossings pass left %d crossings and %d self-intersections (%d and %d before): the "
                    "garment is kept as it was", info["crossings_after"], pairs.shape[0], info["crossings_before"],
                    info["self_intersections_before"])
        new = tangles.beyond(start_pairs)
        return _as_given(V_start, info, restored_vertices=0, self_intersections_after=int(start_pairs.shape[0]),
                         self_intersections_new=int(new.shape[0]))
    info["kept_input"] = False
    info["moved_vertices"] = int(np.any(V != V_start, axis=1).sum())
    info["restored_vertices"] = int(np.any(V != V_cleared, axis=1).sum())
    info["self_intersections_after"] = int(pairs.shape[0])
    info["self_intersections_new"] = int(new.shape[0])
    info["self_intersections_added"] = info["self_intersections_after"] - info["self_intersections_before"]
    if new.shape[0]:
        log.warning("%d self-intersections the source garment does not have are left", new.shape[0])
    return V, info


def _restore_try(base, how, hold, G, A, obstacle, offset, spread_rings, max_rounds, keep_offset, check):
    """One try of the restore from ``base`` (a state of ``_restore``): the cloth around ``how``'s seeds restored
    (``how``: shape, seeds, radius, the body to move it out of or None; ``hold``: how strongly the core is held,
    as ``blend_edges`` takes it), then the body cleared again where that moved it. Returns ``clear_body``'s
    answer."""
    shape, seeds, radius, body = how
    W = restore_source_shape(base[0], G.F, G.E, shape, seeds, radius, body, offset, hold)
    return clear_body(W, G, A, obstacle, offset, spread_rings, max_rounds, keep_offset, check,
                      known=(base[0], base[3]))


def _held_loosely(best, best_how, V_start, source_V, tangles, G, A, obstacle, offset, spread_rings, max_rounds,
                  keep_offset, check):
    """A clean restore's best state, or, where it bends the cloth away from the source more than ``LOOSE_LOOK_FROM``
    times as much as ``V_start`` (the cloth the pass was given) does, the same try with the core held loosely
    (``RESTORE_LOOSE_HOLD``) and its radius times each of ``LOOSE_RINGS``: the one that bends it least (mean
    ``discrete_curvature`` change), if less than the best and clean too (no crossing, no pair the source lacks, no
    more close pairs)."""
    r = discrete_curvature(source_V, G.F)

    def bend(X):
        return np.abs(discrete_curvature(X, G.F) - r).mean()

    bent = bend(best[0])
    if bent <= LOOSE_LOOK_FROM * bend(V_start):
        return best
    base, (shape, seeds, radius, body) = best_how
    for wider in LOOSE_RINGS:
        W, again, state_w = _restore_try(base, (shape, seeds, wider * radius, body), RESTORE_LOOSE_HOLD, G, A,
                                         obstacle, offset, spread_rings, max_rounds, keep_offset, check)
        new_w = tangles.beyond(state_w[2])
        if again["crossings_after"] or new_w.shape[0] or again["near_after"] > best[5]:
            continue
        b = bend(W)
        if b < bent:
            log.debug("the restore held loosely kept: it bends the cloth less")
            bent, best = b, (W, state_w[2], new_w, state_w, 0, again["near_after"], base[6] + again["rounds"],
                             base[7] + again["undone"])
    return best


def _as_given(V_start, info, **counts):
    """``separate``'s input returned as it came: its info says so, with the input's own counts (``counts``:
    those of the self-intersection checks)."""
    info.update(crossings_after=info["crossings_before"], near_after=info["near_before"], moved_vertices=0,
                self_intersections_added=0, kept_input=True, **counts)
    return V_start, info


def clear_body(V, G: Readings, A, obstacle: Obstacle, offset, spread_rings, max_rounds, keep_offset,
               check: SelfCheck, known=None):
    """``separate`` without the source: the rounds that clear the body and keep the clearance.

    ``known`` is ``(V_known, state)`` of an earlier call on this garment (``V_known`` None: the state is
    V's own; a None in the state: not known): only what moved since is checked again. Returns the best
    round's V (``_Round.rank``; the input's when no round is better), info and the state (crossings, near
    pairs and self-intersecting pairs of the V returned: a ``_PairsAround`` when it came as one)."""
    V_in = V
    near = CLEARANCE_SHARE * offset if keep_offset else 0.0
    c, close, pairs = _known_state(V, G, obstacle, near, keep_offset, check, known)
    info = {"crossings_before": c["a_edge_pairs"] + c["b_edge_pairs"], "undone": 0}
    lifts = Lifts()
    if keep_offset:
        near_lifts(V, G, obstacle, offset, near, close, lifts)
    n_near = near_count(close) if keep_offset else 0
    info["near_before"] = n_near
    info["clearance"] = near
    rounds = 0
    # The rounds' best state (fewest crossings, then fewest own pairs; the latest of equals) is what is returned:
    # where the body folds or closes on the cloth a later, harder push can leave more than an earlier one.
    best = _Round(V, c, close, pairs, n_near)
    best_rank = best.rank()
    while (c["a_edge_pairs"] + c["b_edge_pairs"] or n_near) and rounds < max_rounds:
        rounds += 1
        crossing_lifts(V, G, obstacle, c, (CLEARANCE_PUSH * CLEARANCE_SHARE + GAIN * (rounds - 1)) * offset, lifts)
        D = lift_displacement(A, lifts, spread_rings)
        step = np.any(D != 0, axis=1)
        V_new = V.copy()
        V_new[step] += D[step]
        crossing = c["a_edge_pairs"] + c["b_edge_pairs"] > 0
        # A crossing of the body comes first: after these rounds, it is removed even where the cloth
        # then crosses itself (counted in self_intersections_added). The clearance alone never makes
        # the cloth cross itself.
        guard = rounds <= PROTECT_ROUNDS or not crossing
        V_new, undone, pairs = _keep_self_intersections(V, V_new, step, A, check, pairs, guard)
        info["undone"] += undone
        changed = np.any(V_new != V, axis=1)
        V = V_new
        # The crossings and the close pairs of what moved, side by side where a core is free.
        c, close = together(lambda: crossings_again(V, G, obstacle, c, changed),
                            lambda: near_pairs_again(V, G, obstacle, near, close, changed) if keep_offset else None)
        lifts = Lifts()
        last_near = n_near
        if keep_offset:
            near_lifts(V, G, obstacle, offset, near, close, lifts)
            n_near = near_count(close)
        log.debug("round %d: %d crossings, %d near, %d vertices moved",
                  rounds, c["a_edge_pairs"] + c["b_edge_pairs"], n_near, int(step.sum()))
        this = _Round(V, c, close, pairs, n_near)
        rank = this.rank()
        if rank <= best_rank:
            best, best_rank = this, rank
        if c["a_edge_pairs"] + c["b_edge_pairs"] == 0 and (n_near >= last_near or rounds >= CLEARANCE_ROUNDS):
            break   # clean; only the clearance is left, and it no longer improves or has had its rounds
    V, c, close, pairs, n_near = best
    info["rounds"] = rounds
    info["crossings_after"] = c["a_edge_pairs"] + c["b_edge_pairs"]
    info["near_after"] = n_near
    info["moved_vertices"] = int(np.any(V != V_in, axis=1).sum())
    if info["crossings_after"]:
        log.warning("%d garment-body crossings left after %d rounds", info["crossings_after"], rounds)
    return V, info, (c, close, pairs)


class _Round(NamedTuple):
    """A state of ``clear_body``'s rounds: the garment, its crossings, close pairs, own pairs and close count."""
    V: np.ndarray
    c: dict
    close: dict | None
    pairs: "np.ndarray | _PairsAround"
    n_near: int

    def rank(self):
        """Which of two states is better: fewer edges through the other mesh (garment edges through the body
        plus body edges through the garment, as the counts of a result are made), then fewer (edge, triangle)
        pairs, then fewer of the garment's own pairs (where they are all known)."""
        edges = sum(np.unique(self.c[k], axis=0).shape[0] for k in ("a_pairs", "b_pairs"))
        own = 0 if isinstance(self.pairs, _PairsAround) else self.pairs.shape[0]
        return edges, self.c["a_edge_pairs"] + self.c["b_edge_pairs"], own


def _known_state(V, G, obstacle, near, keep_offset, check, known):
    """The crossings, near pairs and self-intersecting pairs of V: from ``known`` where it has them (see
    ``clear_body``), checked again where V moved since, found in full where it has not."""
    V_known, (c, close, pairs) = known if known is not None else (None, (None, None, None))
    changed = None if V_known is None else np.any(V != V_known, axis=1)

    def crossed():
        if c is None:
            return garment_crossings(V, G, obstacle)
        return c if changed is None else crossings_again(V, G, obstacle, c, changed)

    def closer():
        if not keep_offset:
            return None
        if close is None:
            return near_pairs(V, G, obstacle, near)
        return close if changed is None else near_pairs_again(V, G, obstacle, near, close, changed)

    def own():
        if pairs is None:
            return check.all(V)
        if changed is None:
            return pairs
        if isinstance(pairs, _PairsAround):
            # Around what moved, found again: then known there too.
            return _PairsAround(check.again(V, pairs.pairs, changed), pairs.known | changed)
        return check.again(V, pairs, changed)

    # Three checks that share nothing that changes, side by side where cores are free.
    c, close, pairs = together(crossed, closer, own)
    return c, close, pairs


class _PairsAround(NamedTuple):
    """The garment's own self-intersecting pairs known only around some vertices: every pair with a ``known``
    ((n,) bool) vertex in its edge or its triangle (``separate(..., count_own=False)``: the rounds find them
    where they move the cloth, and need no others)."""
    pairs: np.ndarray
    known: np.ndarray


def _keep_self_intersections(V_old, V_new, step, A, check: SelfCheck, pairs, guard=True):
    """Take back moves that made the garment cross itself: halve them around the new
    self-intersections until none is new (at most a few times, then the old positions there).

    Parameters
    ----------
    V_old, V_new : (n,3) float64
    step : (n,) bool
        The vertices that moved.
    A : (n,n) sparse adjacency
    check : SelfCheck
    pairs : (k,2) int or _PairsAround
        The self-intersecting pairs of V_old (or those around some vertices: those around ``step`` are then
        found first, where not known).
    guard : bool
        False: the moves are kept as they are (only the pairs are counted again).

    Returns
    -------
    V : (n,3) float64
    undone : int
        Vertices whose move was reduced.
    pairs : (j,2) int64 or _PairsAround
        The self-intersecting pairs of V (known around the vertices known before and ``step``; unguarded, a
        ``_PairsAround`` knows none).
    """
    G = check.G
    around = isinstance(pairs, _PairsAround)
    if around and not guard:
        # Nothing is taken back and no count of the garment's own pairs is kept: none is needed now. A move may
        # make pairs with cloth anywhere near it, so nothing is known after it; a later round that guards finds
        # the pairs around what it moves then (the same pairs, the same decisions).
        return V_new, 0, _PairsAround(NO_PAIRS, np.zeros(V_new.shape[0], bool))
    if around:
        unknown = step & ~pairs.known
        found = check.local(V_old, unknown) if unknown.any() else NO_PAIRS
        known = pairs.known | step
        pairs = unique_pairs(np.concatenate([pairs.pairs, found]))
    touched = check.touching(pairs, step)
    kept, before = pairs[~touched], pairs[touched]
    undone = 0
    after = check.local(V_new, step)
    for attempt in range(4):
        # Pairs are named by edge and triangle; a move that trades one for another nearby does
        # not add a self-intersection, so the count decides.
        if not guard or after.shape[0] <= before.shape[0]:
            break
        added = after[~_rows_in(after, before)]
        verts = np.unique(np.concatenate([G.E[added[:, 0]].ravel(), G.F[added[:, 1]].ravel()]))
        region = np.zeros(V_new.shape[0], bool)
        region[verts] = True
        region |= (A @ region.astype(np.float64)) > 0
        region &= step
        undone += int(region.sum())
        keep = 0.5 if attempt < 3 else 0.0
        V_new = V_new.copy()
        V_new[region] = V_old[region] + keep * (V_new[region] - V_old[region])
        # Only the pairs of what was taken back can have changed.
        after = check.again(V_new, after, region)
    pairs = unique_pairs(np.concatenate([kept, after]))
    return V_new, undone, _PairsAround(pairs, known) if around else pairs


def _rows_in(a, b):
    """(k,) bool: which rows of the int pairs a (k,2) are rows of b (j,2)."""
    if a.shape[0] == 0 or b.shape[0] == 0:
        return np.zeros(a.shape[0], bool)
    base = int(max(a[:, 1].max(), b[:, 1].max())) + 1
    return np.isin(a[:, 0] * base + a[:, 1], b[:, 0] * base + b[:, 1])
