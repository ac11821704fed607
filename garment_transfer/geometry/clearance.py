"""The final pass: no garment edge through the body, no body edge through the garment, checked exactly.

The vertex push-out (``penetration.fix_penetration``) leaves a garment whose vertices are outside
the body, but an edge can still cut through a body part narrower than the edge (a finger, the gap
between the thighs) and a body vertex can still poke through a garment triangle (a breast or
shoulder under a coarse garment). This pass finds every such crossing with the exact test of
``intersections.crossings`` and turns each into a lower bound on the garment's outward move at one
point (``Lifts``): a garment edge through a body triangle lifts its ends past the triangle's
plane; a body edge through a garment triangle lifts the triangle's point over it, shared by the
corners by their barycentric weights (the least lift of the corners that raises that point, so a
corner far from the contact hardly moves). Each vertex takes the largest lift it is given, the lifts
are spread over a few rings of the garment (a screened Laplace problem: the folds, shorter than the
spread, stay), and what moved is checked again, exactly. The same bounds keep a clearance: garment-
body pairs (vertex-triangle both ways, edge-edge) closer than ``CLEARANCE_SHARE`` of the offset are
lifted to ``CLEARANCE_PUSH`` times that, and crossings are cleared to the same distance, not to the
whole offset (further lifts only cost the design). It ends when nothing is left or after
``max_rounds`` (the result says how many are left; it never hides one).

Moving cloth can make it cross itself. Every round is checked against that: the self-intersections
among the triangles it moved are counted before and after, and a round that adds some is halved on
the garment parts involved (at most three times, then taken back there). After ``PROTECT_ROUNDS``
rounds a crossing of the body comes first: it is removed even if the cloth then crosses itself, and
the result counts what was added. The clearance is best effort: it never makes the cloth cross
itself, and the result counts the pairs still too close.

Given the source shape, the pass also undoes the self-intersections that the source does not have:
layers of cloth closer than the offset (a waistband, a pocket, a fold) are pushed onto the same
offset surface by the vertex push-out and pass through each other, and the transfer itself can
press them together. Around each such (edge, triangle) pair the cloth takes its source shape,
mapped by the affine map that fits it best to where it is (an invertible affine map keeps which
parts of the source meet and which do not), blended into the rest over a ring; the body is then
cleared again where that moved, and a larger ring is tried if pairs are left. What is left is
counted (``self_intersections_new``), never hidden.

Between rounds only what moved is checked again (``crossings_again``, ``near_pairs_again``): the
body does not move, so the pairs of unmoved garment parts stay as they were.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .intersections import (
    box_pairs,
    crossings,
    edge_triangle_pairs,
    mesh_edges,
    segment_closest,
    segment_distances,
    segments_meet_triangles,
)
from .penetration import spread_displacement, vertex_adjacency
from .proximity import TriangleSurface, closest_on_triangles

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
#: Around a self-intersection the source does not have, the cloth within this many offsets (times
#: the try, up to ``RESTORE_TRIES``) takes its source shape (``restore_source_shape``).
RESTORE_RADIUS = 2.2
RESTORE_TRIES = 8
#: A local affine fit whose smallest singular value is under this share of its largest would
#: flatten the cloth: a similarity is fitted instead.
FIT_CONDITION = 0.2

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


def crossing_lifts(V, F, body: TriangleSurface, c, clear, lifts):
    """Bounds that take the garment out of every crossing, by ``clear``.

    A garment edge through a body triangle: each end to ``clear`` outside the triangle's plane. A
    body edge through a garment triangle: the triangle's point over each end of the edge (its
    barycentric coordinates) to ``clear`` past that end along the skin's normal; the corners then
    share the lift by their weights, so a corner far from the body edge hardly moves.

    Parameters
    ----------
    V : (n,3) float64
    F : (m,3) int64
    body : TriangleSurface
    c : dict
        ``intersections.crossings(V, F, body.V, body.F)``.
    clear : float
    lifts : Lifts
        Added to.
    """
    if c["a_pairs"].shape[0]:
        n = body.face_normals[c["a_triangles"]]
        a = body.V[body.F[c["a_triangles"], 0]]
        for end in (0, 1):
            vid = c["a_pairs"][:, end]
            lifts.add(vid[:, None], np.ones((vid.shape[0], 1)), n,
                      clear - np.einsum("ij,ij->i", V[vid] - a, n))
    if c["b_pairs"].shape[0]:
        n = body.vertex_normals[c["b_pairs"][:, 0]] + body.vertex_normals[c["b_pairs"][:, 1]]
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        tri = F[c["b_triangles"]]
        for end in (0, 1):
            q = body.V[c["b_pairs"][:, end]]
            p, bary = closest_on_triangles(q, V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]])
            lifts.add(tri, bary, n, np.einsum("ij,ij->i", q - p, n) + clear)


def near_pairs(V, F, E, body: TriangleSurface, body_E, near, active=None):
    """Garment-body pairs closer than ``near``: garment vertex - body triangle, body vertex - garment
    triangle, garment edge - body edge.

    Parameters
    ----------
    V : (n,3) float64
    F : (m,3) int64
    E : (e,2) int64
        ``mesh_edges(F)``.
    body : TriangleSurface
    body_E : (f,2) int64
        The body's edges.
    near : float
    active : (n,) bool, optional
        Only garment vertices, triangles and edges with an active vertex are looked at.

    Returns
    -------
    dict
        ``vertex`` (k,) garment vertices, ``triangle`` (k,2) (body vertex, garment triangle),
        ``edge`` (k,2) (garment edge, body edge).
    """
    if active is None:
        active = np.ones(V.shape[0], bool)
    out = {"vertex": np.zeros(0, np.int64), "triangle": np.zeros((0, 2), np.int64),
           "edge": np.zeros((0, 2), np.int64)}
    idx = np.flatnonzero(active)
    if idx.size == 0:
        return out
    out["vertex"] = idx[body.signed_distance(V[idx])[0] < near]
    t_act = np.flatnonzero(active[F].any(axis=1))
    e_act = np.flatnonzero(active[E].any(axis=1))
    T = V[F[t_act]]
    lo, hi = T.min(axis=(0, 1)) - near, T.max(axis=(0, 1)) + near
    bv = np.flatnonzero(np.all((body.V >= lo) & (body.V <= hi), axis=1))
    if bv.size and t_act.size:
        pairs = box_pairs(body.V[bv] - near, body.V[bv] + near, T.min(axis=1), T.max(axis=1))
        i, j = bv[pairs[:, 0]], pairs[:, 1]
        p, _ = closest_on_triangles(body.V[i], T[j, 0], T[j, 1], T[j, 2])
        k = np.linalg.norm(p - body.V[i], axis=1) < near
        out["triangle"] = np.stack([i[k], t_act[j[k]]], axis=1)
    P0, P1 = V[E[e_act, 0]], V[E[e_act, 1]]
    Q0, Q1 = body.V[body_E[:, 0]], body.V[body_E[:, 1]]
    kb = np.flatnonzero(np.all((np.maximum(Q0, Q1) >= lo) & (np.minimum(Q0, Q1) <= hi), axis=1))
    if kb.size and e_act.size:
        pairs = box_pairs(np.minimum(P0, P1) - near, np.maximum(P0, P1) + near,
                          np.minimum(Q0[kb], Q1[kb]), np.maximum(Q0[kb], Q1[kb]))
        i, j = e_act[pairs[:, 0]], kb[pairs[:, 1]]
        k = segment_distances(V[E[i, 0]], V[E[i, 1]], Q0[j], Q1[j]) < near
        out["edge"] = np.stack([i[k], j[k]], axis=1)
    return out


def near_pairs_again(V, F, E, body: TriangleSurface, body_E, near, pairs, moved):
    """``near_pairs`` after only the ``moved`` ((n,) bool) vertices moved: the pairs of unmoved
    garment parts are kept, the others found again."""
    out = near_pairs(V, F, E, body, body_E, near, moved)
    keep = {"vertex": ~moved[pairs["vertex"]], "triangle": ~moved[F[pairs["triangle"][:, 1]]].any(axis=1),
            "edge": ~moved[E[pairs["edge"][:, 0]]].any(axis=1)}
    return {k: np.concatenate([pairs[k][keep[k]], out[k]]) for k in out}


def near_count(pairs):
    """The number of pairs in a ``near_pairs`` answer."""
    return sum(int(v.shape[0]) for v in pairs.values())


def near_lifts(V, F, E, body: TriangleSurface, body_E, offset, near, pairs, lifts):
    """Bounds that take garment parts closer to the body than ``near`` away (no crossing needed): a
    garment vertex to ``offset`` (what the penetration fix gave it), the point of a garment triangle
    nearest a body vertex and the point of a garment edge nearest a body edge to ``CLEARANCE_PUSH *
    near``.

    Parameters
    ----------
    V : (n,3) float64
    F : (m,3) int64
    E : (e,2) int64
        ``mesh_edges(F)``.
    body : TriangleSurface
    body_E : (f,2) int64
        The body's edges.
    offset, near : float
    pairs : dict
        ``near_pairs(...)``.
    lifts : Lifts
        Added to.
    """
    close = pairs["vertex"]
    if close.size:
        sd, _, normal, _ = body.signed_distance(V[close])
        lifts.add(close[:, None], np.ones((close.size, 1)), normal, offset - sd)
    if pairs["triangle"].shape[0]:
        q = body.V[pairs["triangle"][:, 0]]
        tri = F[pairs["triangle"][:, 1]]
        p, bary = closest_on_triangles(q, V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]])
        n = body.vertex_normals[pairs["triangle"][:, 0]]
        lifts.add(tri, bary, n, np.einsum("ij,ij->i", q - p, n) + CLEARANCE_PUSH * near)
    if pairs["edge"].shape[0]:
        i, j = pairs["edge"][:, 0], pairs["edge"][:, 1]
        P0, P1 = V[E[i, 0]], V[E[i, 1]]
        Q0, Q1 = body.V[body_E[j, 0]], body.V[body_E[j, 1]]
        s, t = segment_closest(P0, P1, Q0, Q1)
        p = P0 + s[:, None] * (P1 - P0)
        q = Q0 + t[:, None] * (Q1 - Q0)
        n = body.vertex_normals[body_E[j, 0]] + body.vertex_normals[body_E[j, 1]]
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        lifts.add(E[i], np.stack([1.0 - s, s], axis=1), n, np.einsum("ij,ij->i", q - p, n) + CLEARANCE_PUSH * near)


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


def local_self_pairs(V, F, E, moved):
    """Self-intersecting (edge, triangle) pairs of one mesh that involve a moved vertex.

    Parameters
    ----------
    V : (n,3) float64
    F : (m,3) int64
    E : (e,2) int64
        ``mesh_edges(F)``.
    moved : (n,) bool

    Returns
    -------
    set of (int, int)
        (edge index, triangle index).
    """
    e_mov = np.flatnonzero(moved[E].any(axis=1))
    t_mov = np.flatnonzero(moved[F].any(axis=1))
    out = set()
    if e_mov.size:
        p, _ = edge_triangle_pairs(V, E[e_mov], V, F, same_mesh=True)
        out.update(zip(e_mov[p[:, 0]].tolist(), p[:, 1].tolist()))
    if t_mov.size:
        p, _ = edge_triangle_pairs(V, E, V, F[t_mov], same_mesh=True)
        out.update(zip(p[:, 0].tolist(), t_mov[p[:, 1]].tolist()))
    return out


def new_self_pairs(V, F, E, source_V, known=None):
    """The garment's self-intersections, and those of them that its source shape does not have.

    Parameters
    ----------
    V : (n,3) float64
    F : (m,3) int64
    E : (e,2) int64
        ``mesh_edges(F)``.
    source_V : (n,3) float64
        The same garment in its source shape.
    known : tuple, optional
        ``(V_known, pairs_known)``: the self-intersections of an earlier shape; only the edges and
        triangles that moved since are checked again.

    Returns
    -------
    pairs : (k,2) int64
        (edge index, triangle index) pairs that meet in V (exact test).
    new : (j,2) int64
        Those that do not meet in source_V (exact test, pair by pair).
    """
    if known is None:
        pairs, _ = edge_triangle_pairs(V, E, V, F, same_mesh=True)
    else:
        V_known, pairs_known = known
        moved = np.any(V != V_known, axis=1)
        kept = pairs_known[~(moved[E[pairs_known[:, 0]]].any(axis=1) | moved[F[pairs_known[:, 1]]].any(axis=1))]
        again = np.array(sorted(local_self_pairs(V, F, E, moved)), np.int64).reshape(-1, 2)
        pairs = np.concatenate([kept, again])
        pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    e, t = E[pairs[:, 0]], F[pairs[:, 1]]
    S = source_V
    meet, _ = segments_meet_triangles(S[e[:, 0]], S[e[:, 1]], S[t[:, 0]], S[t[:, 1]], S[t[:, 2]])
    return pairs, pairs[~meet]


class _SourceTangles:
    """Where the source garment crosses itself (measured only when first asked).

    A pair of the result that does not meet on the source but touches a vertex of the source's own
    self-intersections is that crossing sliding by an edge; it is left (not undone) as long as the
    result has no more self-intersecting pairs than the source."""

    def __init__(self, source_V, F, E):
        self.S, self.F, self.E = source_V, F, E
        self.tangled = None

    def left_out(self, pairs, new):
        """``new`` ((k,2) pairs the source lacks) without those at the source's own tangles, while
        ``pairs`` (all the result's) are no more than the source's."""
        if new.shape[0] == 0:
            return new
        if self.tangled is None:
            own, _ = edge_triangle_pairs(self.S, self.E, self.S, self.F, same_mesh=True)
            self.count = own.shape[0]
            self.tangled = np.zeros(self.S.shape[0], bool)
            self.tangled[self.E[own[:, 0]]] = True
            self.tangled[self.F[own[:, 1]]] = True
        if pairs.shape[0] > self.count:
            return new
        at = self.tangled[self.E[new[:, 0]]].any(axis=1) | self.tangled[self.F[new[:, 1]]].any(axis=1)
        return new[~at]


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


def restore_source_shape(V, F, E, source_V, pairs, radius, body=None, clear=0.0):
    """Around every listed self-intersection, the cloth takes the shape it has on the source.

    The vertices of the pairs, and the cloth within ``radius`` of them (in space, so every sheet
    of a fold that is there), take the affine image of their source shape nearest to where they are
    now (``local_fit``); from ``radius`` to ``2 * radius`` it blends into where they are. An
    invertible affine map keeps which edges and triangles of the source meet and which do not, so
    the pairs the source lacks are gone there; the blend can make new ones further out (a larger
    radius is the next try).

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
    return V + weight[:, None] * (restored - V)


def separate(V, F, body_V, body_F, offset, *, spread_rings=SPREAD_RINGS, max_rounds=12, surface=None,
             keep_offset=True, source_V=None):
    """Remove every crossing between a garment and a body, keeping the folds.

    Parameters
    ----------
    V : (n,3) float
        Garment vertices (best after ``penetration.fix_penetration``: its vertices outside).
    F : (m,3) int
        Garment triangles.
    body_V : (p,3) float
    body_F : (q,3) int
        The body (or, for outfits, the body and the layers under this one, as one mesh).
    offset : float
        The cloth's thickness: garment vertices near the body are lifted to it; crossings and the
        other close pairs are cleared to ``CLEARANCE_PUSH * CLEARANCE_SHARE`` of it (more in later
        rounds, by ``GAIN`` of it per round).
    spread_rings : float
        Rings of garment vertices over which a push fades.
    max_rounds : int
    surface : TriangleSurface, optional
        Of the body, when already built.
    keep_offset : bool
        Also push out garment parts closer to the body than ``CLEARANCE_SHARE * offset`` (vertex
        to triangle both ways, edge to edge): the smallest distance kept.
    source_V : (n,3) float, optional
        The garment's source shape. With it, the self-intersections of the result that the source
        does not have (the transfer pressed close layers of cloth through each other) are undone
        too: the cloth around them takes its source shape (``restore_source_shape``), and the body
        is cleared again where that moved it, with a larger radius at each of ``RESTORE_TRIES``.

    Returns
    -------
    V : (n,3) float64
        A new array.
    info : dict
        ``crossings_before``, ``crossings_after`` (edge-triangle pairs, both ways),
        ``near_before``, ``near_after`` (primitive pairs closer than ``CLEARANCE_SHARE * offset``),
        ``clearance`` (that distance),
        ``rounds``, ``moved_vertices``, ``self_intersections_added`` (0 unless it could not avoid
        them), ``undone`` (pushes taken back because they made the cloth cross itself). With
        ``source_V``: ``self_intersections_before``, ``self_intersections_after`` (edge-triangle
        pairs), ``self_intersections_new`` (pairs left that the source does not have) and
        ``restored_vertices``. ``kept_input``: True when nothing tried was better than the input (more
        crossings, else more self-intersections, else more near pairs than it had): the input is returned.
    """
    V = np.array(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    body = surface if surface is not None else TriangleSurface(body_V, body_F)
    if source_V is not None:
        source_V = np.asarray(source_V, dtype=np.float64)
        if source_V.shape != V.shape:
            raise ValueError(f"source_V must have the garment's shape {V.shape}, got {source_V.shape}")
    A = vertex_adjacency(V.shape[0], F)
    E = mesh_edges(F)
    body_E = mesh_edges(body.F)
    V_start = V.copy()
    V, info, state = clear_body(V, F, E, A, body, body_E, offset, spread_rings, max_rounds, keep_offset)
    if source_V is None:
        moved = np.any(V != V_start, axis=1)
        info["self_intersections_added"] = (len(local_self_pairs(V, F, E, moved))
                                            - len(local_self_pairs(V_start, F, E, moved))) if moved.any() else 0
        info["kept_input"] = False
        if info["crossings_after"] > info["crossings_before"]:
            log.warning("the crossings pass left %d crossings (%d before): the garment is kept as it was",
                        info["crossings_after"], info["crossings_before"])
            return _as_given(V_start, info)
        return V, info
    V_cleared = V
    tangles = _SourceTangles(source_V, F, E)
    pairs, new = new_self_pairs(V, F, E, source_V)
    new = tangles.left_out(pairs, new)
    # The input's count, from the result's where the body rounds moved nothing.
    info["self_intersections_before"] = int(new_self_pairs(V_start, F, E, source_V, known=(V, pairs))[0].shape[0])
    # Tries start from the latest shape that still has pairs to undo (``base``); the best result
    # (fewest crossings, then pairs the source lacks, then pairs closer than the clearance) is kept.
    near_given = info["near_after"]
    base = best = (V, pairs, new, state, info["crossings_after"], info["near_after"], 0, 0)
    for attempt in range(RESTORE_TRIES):
        if best[2].shape[0] == 0 and best[5] <= near_given:
            break
        V_b, pairs_b, new_b, state_b = base[:4]
        # Each radius is tried with the cloth left where it is, then moved out as one piece.
        radius = (attempt // 2 + 1) * RESTORE_RADIUS * offset
        W = restore_source_shape(V_b, F, E, source_V, new_b, radius, body if attempt % 2 else None, offset)
        W, again, state_w = clear_body(W, F, E, A, body, body_E, offset, spread_rings, max_rounds, keep_offset,
                                        known=(V_b, state_b))
        pairs_w, new_w = new_self_pairs(W, F, E, source_V, known=(V_b, pairs_b))
        new_w = tangles.left_out(pairs_w, new_w)
        log.debug("restore %d: %d self-intersections the source lacks (%d before), %d crossings, %d near",
                  attempt + 1, new_w.shape[0], new_b.shape[0], again["crossings_after"], again["near_after"])
        tried = (W, pairs_w, new_w, state_w, again["crossings_after"], again["near_after"],
                 base[6] + again["rounds"], base[7] + again["undone"])
        if (tried[4], tried[2].shape[0], tried[5]) < (best[4], best[2].shape[0], best[5]):
            best = tried
        if tried[4] <= base[4] and 0 < new_w.shape[0] < new_b.shape[0]:
            base = tried
    V, pairs, new, _, info["crossings_after"], info["near_after"], rounds, undone = best
    info["rounds"] += rounds
    info["undone"] += undone
    if ((info["crossings_after"], pairs.shape[0], info["near_after"])
            > (info["crossings_before"], info["self_intersections_before"], info["near_before"])):
        # Nothing it tried is better than what it was given (a garment pressed through the body can leave
        # it more crossings and tangles than before): the garment is returned as it came.
        log.warning("the crossings pass left %d crossings and %d self-intersections (%d and %d before): the "
                    "garment is kept as it was", info["crossings_after"], pairs.shape[0], info["crossings_before"],
                    info["self_intersections_before"])
        pairs, new = new_self_pairs(V_start, F, E, source_V)
        return _as_given(V_start, info, restored_vertices=0, self_intersections_after=int(pairs.shape[0]),
                         self_intersections_new=int(tangles.left_out(pairs, new).shape[0]))
    info["kept_input"] = False
    info["moved_vertices"] = int(np.any(V != V_start, axis=1).sum())
    info["restored_vertices"] = int(np.any(V != V_cleared, axis=1).sum())
    info["self_intersections_after"] = int(pairs.shape[0])
    info["self_intersections_new"] = int(new.shape[0])
    info["self_intersections_added"] = info["self_intersections_after"] - info["self_intersections_before"]
    if new.shape[0]:
        log.warning("%d self-intersections the source garment does not have are left", new.shape[0])
    return V, info


def _as_given(V_start, info, **counts):
    """``separate``'s input returned as it came: its info says so, with the input's own counts (``counts``:
    those of the source-shape checks)."""
    info.update(crossings_after=info["crossings_before"], near_after=info["near_before"], moved_vertices=0,
                self_intersections_added=0, kept_input=True, **counts)
    return V_start, info


def clear_body(V, F, E, A, body: TriangleSurface, body_E, offset, spread_rings, max_rounds, keep_offset,
                known=None):
    """``separate`` without the source: the rounds that clear the body and keep the clearance.

    ``known`` is ``(V_known, state)`` of an earlier call on this garment: only what moved since is
    checked again. Returns V, info and the state (crossings and near pairs of the V returned)."""
    moved = np.zeros(V.shape[0], bool)
    near = CLEARANCE_SHARE * offset if keep_offset else 0.0
    if known is None:
        c = crossings(V, F, body.V, body.F)
        close = near_pairs(V, F, E, body, body_E, near) if keep_offset else None
    else:
        V_known, (c_known, close_known) = known
        changed = np.any(V != V_known, axis=1)
        c = crossings_again(V, F, E, body, body_E, c_known, changed)
        close = near_pairs_again(V, F, E, body, body_E, near, close_known, changed) if keep_offset else None
    info = {"crossings_before": c["a_edge_pairs"] + c["b_edge_pairs"], "undone": 0}
    lifts = Lifts()
    if keep_offset:
        near_lifts(V, F, E, body, body_E, offset, near, close, lifts)
    n_near = near_count(close) if keep_offset else 0
    info["near_before"] = n_near
    info["clearance"] = near
    rounds = 0
    while (c["a_edge_pairs"] + c["b_edge_pairs"] or n_near) and rounds < max_rounds:
        rounds += 1
        crossing_lifts(V, F, body, c, (CLEARANCE_PUSH * CLEARANCE_SHARE + GAIN * (rounds - 1)) * offset, lifts)
        D = lift_displacement(A, lifts, spread_rings)
        step = np.any(D != 0, axis=1)
        V_new = V.copy()
        V_new[step] += D[step]
        crossing = c["a_edge_pairs"] + c["b_edge_pairs"] > 0
        if rounds <= PROTECT_ROUNDS or not crossing:
            # A crossing of the body comes first: after these rounds, it is removed even where
            # the cloth then crosses itself (counted in self_intersections_added). The clearance
            # alone never makes the cloth cross itself.
            V_new, undone = _keep_self_intersections(V, V_new, F, E, step, A)
            info["undone"] += undone
        changed = np.any(V_new != V, axis=1)
        moved |= changed
        V = V_new
        c = crossings_again(V, F, E, body, body_E, c, changed)
        lifts = Lifts()
        last_near = n_near
        if keep_offset:
            close = near_pairs_again(V, F, E, body, body_E, near, close, changed)
            near_lifts(V, F, E, body, body_E, offset, near, close, lifts)
            n_near = near_count(close)
        log.debug("round %d: %d crossings, %d near, %d vertices moved",
                  rounds, c["a_edge_pairs"] + c["b_edge_pairs"], n_near, int(step.sum()))
        if c["a_edge_pairs"] + c["b_edge_pairs"] == 0 and n_near >= last_near:
            break   # only the clearance is left, and it no longer improves
    info["rounds"] = rounds
    info["crossings_after"] = c["a_edge_pairs"] + c["b_edge_pairs"]
    info["near_after"] = n_near
    info["moved_vertices"] = int(moved.sum())
    if info["crossings_after"]:
        log.warning("%d garment-body crossings left after %d rounds", info["crossings_after"], rounds)
    return V, info, (c, close)


def crossings_again(V, F, E, body: TriangleSurface, body_E, c, moved):
    """``crossings(V, F, body.V, body.F)`` after only the ``moved`` ((n,) bool) vertices moved: the
    pairs of unmoved garment edges and triangles are kept from ``c``, the others checked again
    (exactly; the body does not move). Same keys as ``crossings`` that the pass uses."""
    keep_a = ~moved[c["a_pairs"]].any(axis=1)
    keep_b = ~moved[F[c["b_triangles"]]].any(axis=1)
    e_mov = np.flatnonzero(moved[E].any(axis=1))
    t_mov = np.flatnonzero(moved[F].any(axis=1))
    pa, _ = edge_triangle_pairs(V, E[e_mov], body.V, body.F)
    pb, _ = edge_triangle_pairs(body.V, body_E, V, F[t_mov])
    out = {"a_pairs": np.concatenate([c["a_pairs"][keep_a], E[e_mov[pa[:, 0]]].reshape(-1, 2)]),
           "a_triangles": np.concatenate([c["a_triangles"][keep_a], pa[:, 1]]),
           "b_pairs": np.concatenate([c["b_pairs"][keep_b], body_E[pb[:, 0]].reshape(-1, 2)]),
           "b_triangles": np.concatenate([c["b_triangles"][keep_b], t_mov[pb[:, 1]]])}
    out["a_edge_pairs"] = int(out["a_triangles"].shape[0])
    out["b_edge_pairs"] = int(out["b_triangles"].shape[0])
    return out


def _keep_self_intersections(V_old, V_new, F, E, step, A):
    """Take back moves that made the garment cross itself: halve them around the new
    self-intersections until none is new (at most a few times, then the old positions there).

    Parameters
    ----------
    V_old, V_new : (n,3) float64
    F : (m,3) int64
    E : (e,2) int64
    step : (n,) bool
        The vertices that moved.
    A : (n,n) sparse adjacency

    Returns
    -------
    V : (n,3) float64
    undone : int
        Vertices whose move was reduced.
    """
    before = local_self_pairs(V_old, F, E, step)
    undone = 0
    for attempt in range(4):
        after = local_self_pairs(V_new, F, E, step)
        added = after - before
        # Pairs are named by edge and triangle; a move that trades one for another nearby does
        # not add a self-intersection, so the count decides.
        if len(after) <= len(before):
            return V_new, undone
        edges = E[[a for a, _ in added]].ravel()
        verts = np.unique(np.concatenate([edges, F[[b for _, b in added]].ravel()]))
        region = np.zeros(V_new.shape[0], bool)
        region[verts] = True
        region |= (A @ region.astype(np.float64)) > 0
        region &= step
        undone += int(region.sum())
        keep = 0.5 if attempt < 3 else 0.0
        V_new = V_new.copy()
        V_new[region] = V_old[region] + keep * (V_new[region] - V_old[region])
    return V_new, undone
