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
offset surface by the vertex push-out and pass through each other. For each such (edge, triangle)
pair, the outer of the two (on the body's outer side in the source layout) is lifted back to its
source side of the other, outward only. Design comes first: if the garment's MDC against its source
would rise above ``UNTANGLE_BUDGET`` times the pass's input's, the pairs whose undoing creases the
cloth most are left (counted in ``self_intersections_new``).

Between rounds only what moved is checked again (``crossings_again``, ``near_pairs_again``): the
body does not move, so the pairs of unmoved garment parts stay as they were.
"""

from __future__ import annotations

import logging

import numpy as np

from .metrics import discrete_curvature
from .intersections import (box_pairs, crossings, edge_triangle_pairs, mesh_edges, segment_closest, segment_distances,
                            segments_meet_triangles)
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
#: Self-intersections the source does not have are undone to this share of the offset apart ...
UNTANGLE_GAP = 0.1
#: ... as long as the garment's MDC against its source stays under this share of the pass's input's
#: (the design comes first: a tangle whose undoing would crease the cloth is left).
UNTANGLE_BUDGET = 1.08
UNTANGLE_TRIES = 4


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


def untangle_lifts(V, F, E, source_V, pairs, body: TriangleSurface, gap, lifts):
    """Bounds that undo self-intersections the source garment does not have: the side of the
    triangle its edge was on in the source is restored, ``gap`` past the triangle's plane. Only the
    outer of the two moves (the one the body's outward normal points to in that layout), outward,
    so untangling never pushes cloth toward the body.

    Parameters
    ----------
    V : (n,3) float64
    F : (m,3) int64
    E : (e,2) int64
        ``mesh_edges(F)``.
    source_V : (n,3) float64
        The garment's source shape (same vertex order).
    pairs : (k,2) int64
        (edge index, triangle index) pairs that meet in V and not in source_V.
    body : TriangleSurface
    gap : float
    lifts : Lifts
        Added to.
    """
    if pairs.shape[0] == 0:
        return
    e, t = E[pairs[:, 0]], F[pairs[:, 1]]
    S, T = source_V[t], V[t]
    ns = np.cross(S[:, 1] - S[:, 0], S[:, 2] - S[:, 0])
    side = np.sign(np.einsum("ij,ij->i", source_V[e].mean(axis=1) - S[:, 0], ns))
    nc = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    length = np.linalg.norm(nc, axis=1)
    ok = (length > 0) & (side != 0)
    e, t, T, side = e[ok], t[ok], T[ok], side[ok]
    u = side[:, None] * nc[ok] / length[ok, None]
    outward = body.signed_distance(V[e].mean(axis=1))[2]
    edge_outer = np.einsum("ij,ij->i", u, outward) > 0
    k = edge_outer
    for end in (0, 1):
        x = V[e[:, end]]
        need = gap - np.einsum("ij,ij->i", x - T[:, 0], u)
        lifts.add(e[k, end][:, None], np.ones((int(k.sum()), 1)), u[k], need[k])
        p, bary = closest_on_triangles(x[~k], T[~k, 0], T[~k, 1], T[~k, 2])
        lifts.add(t[~k], bary, -u[~k], gap + np.einsum("ij,ij->i", p - x[~k], u[~k]))


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
        The garment's source shape. With it, the self-intersections of V that the source does not
        have (the transfer pressed close layers of cloth through each other) are undone too
        (``untangle_lifts``), and the counts are reported.

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
        ``source_V``: ``self_intersections_before``,
        ``self_intersections_after`` (edge-triangle pairs) and ``self_intersections_new`` (pairs
        left that the source does not have).
    """
    V = np.array(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    body = surface if surface is not None else TriangleSurface(body_V, body_F)
    A = vertex_adjacency(V.shape[0], F)
    E = mesh_edges(F)
    moved = np.zeros(V.shape[0], bool)
    body_E = mesh_edges(body.F)
    near = CLEARANCE_SHARE * offset if keep_offset else 0.0
    c = crossings(V, F, body.V, body.F)
    info = {"crossings_before": c["a_edge_pairs"] + c["b_edge_pairs"], "undone": 0}
    track = source_V is not None
    if track:
        source_V = np.asarray(source_V, dtype=np.float64)
        if source_V.shape != V.shape:
            raise ValueError(f"source_V must have the garment's shape {V.shape}, got {source_V.shape}")
        # Only the pairs that meet in V are asked about on the source (exactly, pair by pair).
        in_source = _SourcePairs(source_V, F, E)
        pairs = _pair_set(edge_triangle_pairs(V, E, V, F, same_mesh=True)[0])
        info["self_intersections_before"] = len(pairs)
    given_up = set()
    n_new = len(in_source.new(pairs)) if track else 0
    # The MDC budget of the untangling is set by the pass's input (measured when first needed: pairs
    # the source lacks may also appear in a later round).
    curvature_source = budget = None
    lifts = Lifts()
    if keep_offset:
        close = near_pairs(V, F, E, body, body_E, near)
        near_lifts(V, F, E, body, body_E, offset, near, close, lifts)
    n_near = near_count(close) if keep_offset else 0
    info["near_before"] = n_near
    info["clearance"] = near
    V_start = V.copy()
    rounds = 0
    while (c["a_edge_pairs"] + c["b_edge_pairs"] or n_near or n_new) and rounds < max_rounds:
        rounds += 1
        crossing_lifts(V, F, body, c, (CLEARANCE_PUSH * CLEARANCE_SHARE + GAIN * (rounds - 1)) * offset, lifts)
        if n_new:
            if budget is None:
                curvature_source = discrete_curvature(source_V, F)
                budget = UNTANGLE_BUDGET * np.abs(curvature_source - discrete_curvature(V_start, F)).sum()
            todo = np.array(sorted(in_source.new(pairs) - given_up), np.int64).reshape(-1, 2)
            D, dropped = _untangle_within_budget(V, F, E, A, source_V, todo, body, offset, lifts, spread_rings,
                                                 curvature_source, budget)
            given_up |= dropped
        else:
            D = lift_displacement(A, lifts, spread_rings)
        step = np.any(D != 0, axis=1)
        V_new = V.copy()
        V_new[step] += D[step]
        crossing = c["a_edge_pairs"] + c["b_edge_pairs"] > 0
        before = _touching(pairs, E, F, step) if track else local_self_pairs(V, F, E, step)
        if rounds <= PROTECT_ROUNDS or not crossing:
            # A crossing of the body comes first: after these rounds, it is removed even where
            # the cloth then crosses itself (counted in self_intersections_added). The clearance
            # alone never makes the cloth cross itself.
            V_new, undone, after = _keep_self_intersections(V, V_new, F, E, step, A, before)
            info["undone"] += undone
        elif track:
            after = local_self_pairs(V_new, F, E, step)
        if track:
            pairs = (pairs - before) | after
        changed = np.any(V_new != V, axis=1)
        moved |= changed
        V = V_new
        c = crossings_again(V, F, E, body, body_E, c, changed)
        lifts = Lifts()
        last_near, last_new = n_near, n_new
        if keep_offset:
            close = near_pairs_again(V, F, E, body, body_E, near, close, changed)
            near_lifts(V, F, E, body, body_E, offset, near, close, lifts)
            n_near = near_count(close)
        n_new = len(in_source.new(pairs) - given_up) if track else 0
        log.debug("round %d: %d crossings, %d near, %d new self-intersections, %d vertices moved",
                  rounds, c["a_edge_pairs"] + c["b_edge_pairs"], n_near, n_new, int(step.sum()))
        if c["a_edge_pairs"] + c["b_edge_pairs"] == 0 and n_near >= last_near and n_new >= last_new:
            break   # only the clearance and self-intersections are left, and they no longer improve
    info["rounds"] = rounds
    info["crossings_after"] = c["a_edge_pairs"] + c["b_edge_pairs"]
    info["near_after"] = n_near
    info["moved_vertices"] = int(moved.sum())
    if track:
        info["self_intersections_after"] = len(pairs)
        info["self_intersections_new"] = len(in_source.new(pairs))
        info["self_intersections_added"] = len(pairs) - info["self_intersections_before"]
    else:
        info["self_intersections_added"] = (len(local_self_pairs(V, F, E, moved))
                                            - len(local_self_pairs(V_start, F, E, moved))) if moved.any() else 0
    if info["crossings_after"]:
        log.warning("%d garment-body crossings left after %d rounds", info["crossings_after"], rounds)
    return V, info


def _untangle_within_budget(V, F, E, A, source_V, todo, body, offset, lifts, rings, curvature_source, budget):
    """The round's displacement with the untangling of ``todo`` pairs added, as far as the MDC budget
    allows: if the garment would leave it, the pairs whose undoing changes the curvature most are
    given up (until the excess is paid for) and the displacement solved again, a few times; if still
    over, no pair is untangled this round (all are given up).

    Returns
    -------
    D : (n,3) float64
    given_up : set of (int, int)
    """
    def solve(chosen):
        both = Lifts()
        both.extend(lifts)
        untangle_lifts(V, F, E, source_V, chosen, body, UNTANGLE_GAP * offset, both)
        D = lift_displacement(A, both, rings)
        dev = np.abs(curvature_source - discrete_curvature(V + D, F))
        return D, dev

    D, dev = solve(todo)
    base = np.abs(curvature_source - discrete_curvature(V, F))
    keep = np.arange(todo.shape[0])
    for _ in range(UNTANGLE_TRIES):
        if dev.sum() <= budget:
            return D, _pair_set(np.delete(todo, keep, axis=0))
        cost = np.maximum(dev - base, 0.0)
        chosen = todo[keep]
        per_pair = np.maximum(cost[E[chosen[:, 0]]].max(axis=1), cost[F[chosen[:, 1]]].max(axis=1))
        order = np.argsort(-per_pair)
        cut = int(np.searchsorted(np.cumsum(per_pair[order]), dev.sum() - budget)) + 1
        keep = np.sort(keep[order[cut:]])
        if keep.size == 0:
            break
        D, dev = solve(todo[keep])
    return lift_displacement(A, lifts, rings), _pair_set(todo)


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


class _SourcePairs:
    """Which (edge, triangle) pairs of the garment meet on its source shape, asked pair by pair
    (exact test) and remembered."""

    def __init__(self, source_V, F, E):
        self.S, self.F, self.E = source_V, F, E
        self.known = {}

    def new(self, pairs):
        """The pairs of a set that do not meet on the source."""
        ask = np.array([p for p in pairs if p not in self.known], np.int64).reshape(-1, 2)
        if ask.shape[0]:
            e, t = self.E[ask[:, 0]], self.F[ask[:, 1]]
            meet, _ = segments_meet_triangles(self.S[e[:, 0]], self.S[e[:, 1]], self.S[t[:, 0]], self.S[t[:, 1]],
                                              self.S[t[:, 2]])
            self.known.update(zip(map(tuple, ask.tolist()), meet.tolist()))
        return {p for p in pairs if not self.known[p]}


def _pair_set(pairs):
    """(k,2) int (edge, triangle) pairs as a set of tuples."""
    return set(zip(pairs[:, 0].tolist(), pairs[:, 1].tolist()))


def _touching(pairs, E, F, moved):
    """The (edge, triangle) pairs of a set that involve a moved vertex ((n,) bool)."""
    return {(a, b) for a, b in pairs if moved[E[a]].any() or moved[F[b]].any()}


def _keep_self_intersections(V_old, V_new, F, E, step, A, before):
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
    before : set of (int, int)
        ``local_self_pairs(V_old, F, E, step)``.

    Returns
    -------
    V : (n,3) float64
    undone : int
        Vertices whose move was reduced.
    after : set of (int, int)
        ``local_self_pairs(V, F, E, step)`` of the V returned.
    """
    undone = 0
    for attempt in range(4):
        after = local_self_pairs(V_new, F, E, step)
        added = after - before
        # Pairs are named by edge and triangle; a move that trades one for another nearby does
        # not add a self-intersection, so the count decides.
        if len(after) <= len(before):
            return V_new, undone, after
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
    return V_new, undone, local_self_pairs(V_new, F, E, step)
