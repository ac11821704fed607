"""Exact intersection counts between triangle meshes, and the smallest distance between two.

What counts (the convention the tests pin down): an edge and a triangle are **closed** sets, and
they intersect when they have any point in common. An edge through a triangle's interior, through
one of its edges or corners, an edge end touching the triangle, an edge lying in the triangle's
plane across it: all count. Touching counts because the goal is a positive distance between cloth
and skin; a contact of measure zero is already a failure of that goal. An edge through the common
edge of two triangles meets both, so it gives two (edge, triangle) pairs but one crossing edge.
Within one mesh (self-intersections), pairs that share a vertex are left out: they touch by
construction. Triangles of zero area (exactly collinear corners) have no interior and are left
out as triangles; their edges are still tested as edges.

Every triangle-triangle intersection shows up as edge-triangle pairs: the segment two triangles
have in common ends on an edge of one of them. So garment edges through body triangles plus body
edges through garment triangles cover all garment-body intersections.

How: a broad phase on a uniform grid of axis-aligned boxes (vectorised; each candidate pair is
produced once, in the cell holding the lower corner of the two boxes' overlap), then a narrow
phase of orientation predicates (orient3d). Each predicate is first evaluated in floating point
with a guaranteed error bound (Shewchuk's, widened); where the bound cannot certify the sign,
the pair is decided again in exact integer arithmetic on the inputs' exact binary values.
"""

from __future__ import annotations

import numpy as np

from .proximity import TriangleSurface, closest_on_triangles

#: Floating-point filter: a computed orient3d whose magnitude exceeds ``FILTER * permanent`` has
#: the sign of the exact determinant. Shewchuk's bound for this evaluation order is
#: (7 + 56 eps) eps with eps = 2^-53; 16 eps leaves a margin.
FILTER = 16.0 * 2.0 ** -53
#: Boxes per grid cell side: the cell is this many times the median box size of the two sets.
CELL_SHARE = 1.0
#: Pairs handled per narrow-phase batch (bounds memory on huge meshes).
PAIR_BATCH = 1 << 20


def mesh_edges(F):
    """Unique undirected edges of triangles.

    Parameters
    ----------
    F : (m,3) int

    Returns
    -------
    E : (e,2) int64
        Sorted pairs, each edge once.
    """
    F = np.asarray(F, dtype=np.int64)
    if F.size == 0:
        return np.zeros((0, 2), np.int64)
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    n = int(F.max()) + 1
    key = np.unique(e[:, 0] * n + e[:, 1])
    return np.stack([key // n, key % n], axis=1)


# --------------------------------------------------------------------------- broad phase

def box_pairs(lo_a, hi_a, lo_b, hi_b, cell=None):
    """Pairs of overlapping axis-aligned boxes, one from each set, each pair once.

    Parameters
    ----------
    lo_a, hi_a : (p,3) float
        Boxes of the first set (closed: touching boxes overlap).
    lo_b, hi_b : (q,3) float
    cell : float, optional
        Grid cell size (default ``CELL_SHARE`` times the larger median box extent).

    Returns
    -------
    pairs : (k,2) int64
        ``(i, j)`` with box i of the first set overlapping box j of the second.
    """
    if lo_a.shape[0] == 0 or lo_b.shape[0] == 0:
        return np.zeros((0, 2), np.int64)
    if cell is None:
        ext = max(float(np.median((hi_a - lo_a).max(axis=1))), float(np.median((hi_b - lo_b).max(axis=1))))
        cell = CELL_SHARE * ext
    span = max(float(np.max(hi_a)) - float(np.min(lo_a)), float(np.max(hi_b)) - float(np.min(lo_b)), 1e-300)
    # Very large boxes would cover too many cells: never more than ~200 cells per side.
    cell = max(cell, span / 200.0, 1e-300)
    origin = np.minimum(lo_a.min(axis=0), lo_b.min(axis=0))
    ilo_a, ihi_a = _cell_range(lo_a, hi_a, origin, cell)
    ilo_b, ihi_b = _cell_range(lo_b, hi_b, origin, cell)
    dims = np.maximum(ihi_a.max(axis=0), ihi_b.max(axis=0)) + 1
    item_a, key_a = _cell_entries(ilo_a, ihi_a, dims)
    item_b, key_b = _cell_entries(ilo_b, ihi_b, dims)
    order = np.argsort(key_b, kind="stable")
    key_b, item_b = key_b[order], item_b[order]
    start = np.searchsorted(key_b, key_a, side="left")
    stop = np.searchsorted(key_b, key_a, side="right")
    count = stop - start
    keep = count > 0
    item_a, key_a, start, count = item_a[keep], key_a[keep], start[keep], count[keep]
    i = np.repeat(item_a, count)
    cell_key = np.repeat(key_a, count)
    offs = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    j = item_b[np.repeat(start, count) + offs]
    overlap = np.all((lo_a[i] <= hi_b[j]) & (lo_b[j] <= hi_a[i]), axis=1)
    i, j, cell_key = i[overlap], j[overlap], cell_key[overlap]
    # The pair belongs to the cell of the lower corner of the overlap box only: no duplicates.
    corner = np.floor((np.maximum(lo_a[i], lo_b[j]) - origin) / cell).astype(np.int64)
    corner = np.minimum(np.maximum(corner, 0), dims - 1)
    own = (corner[:, 0] * dims[1] + corner[:, 1]) * dims[2] + corner[:, 2] == cell_key
    return np.stack([i[own], j[own]], axis=1)


def _cell_range(lo, hi, origin, cell):
    ilo = np.floor((lo - origin) / cell).astype(np.int64)
    ihi = np.floor((hi - origin) / cell).astype(np.int64)
    return np.maximum(ilo, 0), np.maximum(ihi, 0)


def _cell_entries(ilo, ihi, dims):
    """Every (box, cell key) of the cells each box covers."""
    size = ihi - ilo + 1
    count = size.prod(axis=1)
    item = np.repeat(np.arange(ilo.shape[0]), count)
    local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    sz = size[item]
    dz = local % sz[:, 2]
    dy = (local // sz[:, 2]) % sz[:, 1]
    dx = local // (sz[:, 2] * sz[:, 1])
    c = ilo[item] + np.stack([dx, dy, dz], axis=1)
    return item, (c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2]


# --------------------------------------------------------------------------- predicates

def orient3d_filtered(a, b, c, d):
    """Sign of ``det[b-a, c-a, d-a]`` where floating point can certify it.

    Parameters
    ----------
    a, b, c, d : (k,3) float64

    Returns
    -------
    sign : (k,) int8
        +1 or -1 where certain, 0 where the filter cannot tell (not necessarily a zero determinant).
    """
    ad, bd, cd = a - d, b - d, c - d
    x = bd[:, 1] * cd[:, 2] - bd[:, 2] * cd[:, 1]
    y = bd[:, 2] * cd[:, 0] - bd[:, 0] * cd[:, 2]
    z = bd[:, 0] * cd[:, 1] - bd[:, 1] * cd[:, 0]
    det = ad[:, 0] * x + ad[:, 1] * y + ad[:, 2] * z
    perm = (np.abs(ad[:, 0]) * (np.abs(bd[:, 1] * cd[:, 2]) + np.abs(bd[:, 2] * cd[:, 1]))
            + np.abs(ad[:, 1]) * (np.abs(bd[:, 2] * cd[:, 0]) + np.abs(bd[:, 0] * cd[:, 2]))
            + np.abs(ad[:, 2]) * (np.abs(bd[:, 0] * cd[:, 1]) + np.abs(bd[:, 1] * cd[:, 0])))
    sure = np.abs(det) > FILTER * perm
    # det of (a-d, b-d, c-d) equals -det[b-a, c-a, d-a]; keep the documented orientation.
    return np.where(sure, -np.sign(det), 0).astype(np.int8)


def _exact(points):
    """Exact integer coordinates for a few points: one power-of-two scale for all of them."""
    ratios = [[float(x).as_integer_ratio() for x in p] for p in points]
    den = max(d for r in ratios for _, d in r)
    return [tuple(n * (den // d) for n, d in r) for r in ratios]


def _sub(p, q):
    return (p[0] - q[0], p[1] - q[1], p[2] - q[2])


def _orient3d_exact(a, b, c, d):
    u, v, w = _sub(b, a), _sub(c, a), _sub(d, a)
    det = (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
           + u[2] * (v[0] * w[1] - v[1] * w[0]))
    return (det > 0) - (det < 0)


def _orient2d_exact(a, b, c):
    det = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    return (det > 0) - (det < 0)


def _on_segment_2d(a, b, p):
    """p collinear with ab: is it within the closed segment?"""
    return min(a[0], b[0]) <= p[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= p[1] <= max(a[1], b[1])


def _segments_meet_2d(p, q, a, b):
    d1, d2 = _orient2d_exact(a, b, p), _orient2d_exact(a, b, q)
    d3, d4 = _orient2d_exact(p, q, a), _orient2d_exact(p, q, b)
    if d1 * d2 < 0 and d3 * d4 < 0:
        return True
    return ((d1 == 0 and _on_segment_2d(a, b, p)) or (d2 == 0 and _on_segment_2d(a, b, q))
            or (d3 == 0 and _on_segment_2d(p, q, a)) or (d4 == 0 and _on_segment_2d(p, q, b)))


def _inside_triangle_2d(p, a, b, c):
    s = (_orient2d_exact(a, b, p), _orient2d_exact(b, c, p), _orient2d_exact(c, a, p))
    return not (min(s) < 0 < max(s))


def segment_meets_triangle_exact(p, q, a, b, c):
    """Exact closed segment-triangle test on five points (each three floats).

    Returns
    -------
    bool
        True when the closed segment pq and the closed triangle abc share a point; False for a
        triangle of zero area (see the module's convention).
    """
    p, q, a, b, c = _exact([p, q, a, b, c])
    n = (
        (b[1] - a[1]) * (c[2] - a[2]) - (b[2] - a[2]) * (c[1] - a[1]),
        (b[2] - a[2]) * (c[0] - a[0]) - (b[0] - a[0]) * (c[2] - a[2]),
        (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]),
    )
    if n == (0, 0, 0):
        return False
    s1, s2 = _orient3d_exact(a, b, c, p), _orient3d_exact(a, b, c, q)
    if s1 * s2 > 0:
        return False
    if s1 == 0 and s2 == 0:
        # In the triangle's plane: drop the axis of the largest normal component (never zero).
        axis = max(range(3), key=lambda k: abs(n[k]))
        keep = [k for k in range(3) if k != axis]
        p2, q2, a2, b2, c2 = ([pt[k] for k in keep] for pt in (p, q, a, b, c))
        if _inside_triangle_2d(p2, a2, b2, c2) or _inside_triangle_2d(q2, a2, b2, c2):
            return True
        return (_segments_meet_2d(p2, q2, a2, b2) or _segments_meet_2d(p2, q2, b2, c2)
                or _segments_meet_2d(p2, q2, c2, a2))
    t = (_orient3d_exact(p, q, a, b), _orient3d_exact(p, q, b, c), _orient3d_exact(p, q, c, a))
    return not (min(t) < 0 < max(t))


def segments_meet_triangles(P, Q, A, B, C):
    """Exact closed segment-triangle tests, pairwise.

    Parameters
    ----------
    P, Q : (k,3) float64
        Segment ends.
    A, B, C : (k,3) float64
        Triangle corners.

    Returns
    -------
    meet : (k,) bool
    uncertain : int
        How many pairs the floating-point filter could not decide (decided exactly instead).
    """
    s1 = orient3d_filtered(A, B, C, P)
    s2 = orient3d_filtered(A, B, C, Q)
    meet = np.zeros(P.shape[0], bool)
    # Both ends certainly on one side: no contact. Most candidates end here.
    open_ = ~((s1 != 0) & (s1 == s2))
    idx = np.flatnonzero(open_)
    t1 = orient3d_filtered(P[idx], Q[idx], A[idx], B[idx])
    t2 = orient3d_filtered(P[idx], Q[idx], B[idx], C[idx])
    t3 = orient3d_filtered(P[idx], Q[idx], C[idx], A[idx])
    crossing = (s1[idx] * s2[idx] < 0)
    sure = crossing & (t1 != 0) & (t2 != 0) & (t3 != 0)
    meet[idx[sure]] = (t1[sure] == t2[sure]) & (t2[sure] == t3[sure])
    # A certain crossing of the plane with two certain opposite line orientations is a miss,
    # whatever the third one is.
    miss = crossing & ~sure & (((t1 * t2) < 0) | ((t2 * t3) < 0) | ((t3 * t1) < 0))
    rest = idx[~sure & ~miss]
    for r in rest:
        meet[r] = segment_meets_triangle_exact(P[r], Q[r], A[r], B[r], C[r])
    return meet, int(rest.size)


# --------------------------------------------------------------------------- counts

def edge_triangle_pairs(V_e, E, V_t, F, same_mesh=False):
    """Every (edge, triangle) pair that intersects, exactly.

    Parameters
    ----------
    V_e : (n,3) float
        Vertices of the edges' mesh.
    E : (e,2) int
        Edges.
    V_t : (p,3) float
        Vertices of the triangles' mesh.
    F : (m,3) int
        Triangles.
    same_mesh : bool
        The edges and triangles belong to one mesh: pairs sharing a vertex are left out.

    Returns
    -------
    pairs : (k,2) int64
        ``(edge index, triangle index)``, sorted.
    uncertain : int
        Pairs decided by the exact fallback.
    """
    V_e = np.asarray(V_e, dtype=np.float64)
    V_t = np.asarray(V_t, dtype=np.float64)
    E = np.asarray(E, dtype=np.int64)
    F = np.asarray(F, dtype=np.int64)
    if E.shape[0] == 0 or F.shape[0] == 0:
        return np.zeros((0, 2), np.int64), 0
    P, Q = V_e[E[:, 0]], V_e[E[:, 1]]
    T = V_t[F]
    lo_e, hi_e, lo_t, hi_t = np.minimum(P, Q), np.maximum(P, Q), T.min(axis=1), T.max(axis=1)
    # Only what lies within the other set's bounding box can meet it (a skirt and a whole body).
    ke = np.flatnonzero(np.all((lo_e <= hi_t.max(axis=0)) & (hi_e >= lo_t.min(axis=0)), axis=1))
    kt = np.flatnonzero(np.all((lo_t <= hi_e.max(axis=0)) & (hi_t >= lo_e.min(axis=0)), axis=1))
    if ke.size == 0 or kt.size == 0:
        return np.zeros((0, 2), np.int64), 0
    cand = box_pairs(lo_e[ke], hi_e[ke], lo_t[kt], hi_t[kt])
    cand = np.stack([ke[cand[:, 0]], kt[cand[:, 1]]], axis=1)
    if same_mesh and cand.size:
        e, f = E[cand[:, 0]], F[cand[:, 1]]
        shared = (e[:, :1] == f).any(axis=1) | (e[:, 1:] == f).any(axis=1)
        cand = cand[~shared]
    hits, uncertain = [], 0
    for s in range(0, cand.shape[0], PAIR_BATCH):
        c = cand[s:s + PAIR_BATCH]
        ei, fi = c[:, 0], c[:, 1]
        meet, u = segments_meet_triangles(P[ei], Q[ei], T[fi, 0], T[fi, 1], T[fi, 2])
        hits.append(c[meet])
        uncertain += u
    pairs = np.concatenate(hits) if hits else np.zeros((0, 2), np.int64)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    return pairs, uncertain


def crossings(V_a, F_a, V_b, F_b):
    """Intersections between two meshes, counted both ways.

    Parameters
    ----------
    V_a : (n,3) float
    F_a : (m,3) int
        The first mesh (a garment, or an inner layer).
    V_b : (p,3) float
    F_b : (q,3) int
        The second mesh (the body, or an outer layer).

    Returns
    -------
    dict
        ``a_edges_through_b`` (edges of a that meet a triangle of b), ``a_edge_pairs`` (such
        (edge, triangle) pairs), ``b_edges_through_a``, ``b_edge_pairs``, ``uncertain`` (pairs the
        exact fallback decided) and the arrays ``a_pairs``, ``b_pairs`` (k,2) int64.
    """
    E_a, E_b = mesh_edges(F_a), mesh_edges(F_b)
    pa, ua = edge_triangle_pairs(V_a, E_a, V_b, F_b)
    pb, ub = edge_triangle_pairs(V_b, E_b, V_a, F_a)
    return {"a_edges_through_b": int(np.unique(pa[:, 0]).size), "a_edge_pairs": int(pa.shape[0]),
            "b_edges_through_a": int(np.unique(pb[:, 0]).size), "b_edge_pairs": int(pb.shape[0]),
            "uncertain": ua + ub, "a_pairs": E_a[pa[:, 0]] if pa.size else np.zeros((0, 2), np.int64),
            "a_triangles": pa[:, 1], "b_pairs": E_b[pb[:, 0]] if pb.size else np.zeros((0, 2), np.int64),
            "b_triangles": pb[:, 1]}


def self_intersections(V, F):
    """A mesh's own intersections: (edge, triangle) pairs of one mesh that share no vertex and meet.

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int

    Returns
    -------
    count : int
        Intersecting pairs.
    edges : (k,2) int64
        The edge of each pair (vertex indices).
    triangles : (k,) int64
        The triangle of each pair.
    """
    E = mesh_edges(F)
    pairs, _ = edge_triangle_pairs(V, E, V, F, same_mesh=True)
    return int(pairs.shape[0]), E[pairs[:, 0]], pairs[:, 1]


# --------------------------------------------------------------------------- distance

def segment_distances(P0, P1, Q0, Q1):
    """Distances between segments P0P1 and Q0Q1, pairwise (Lumelsky's clamped parameters).

    Parameters
    ----------
    P0, P1, Q0, Q1 : (k,3) float64

    Returns
    -------
    d : (k,) float64
    """
    s, t = segment_closest(P0, P1, Q0, Q1)
    diff = (P0 + s[:, None] * (P1 - P0)) - (Q0 + t[:, None] * (Q1 - Q0))
    return np.linalg.norm(diff, axis=1)


def segment_closest(P0, P1, Q0, Q1):
    """Parameters of the closest points of segments P0P1 and Q0Q1, pairwise (Lumelsky).

    Parameters
    ----------
    P0, P1, Q0, Q1 : (k,3) float64

    Returns
    -------
    s, t : (k,) float64
        In [0, 1]: the closest points are ``P0 + s (P1 - P0)`` and ``Q0 + t (Q1 - Q0)``.
    """
    u, v, w = P1 - P0, Q1 - Q0, P0 - Q0
    a = np.einsum("ij,ij->i", u, u)
    b = np.einsum("ij,ij->i", u, v)
    c = np.einsum("ij,ij->i", v, v)
    d = np.einsum("ij,ij->i", u, w)
    e = np.einsum("ij,ij->i", v, w)
    den = a * c - b * b
    s = np.clip(np.divide(b * e - c * d, den, out=np.zeros_like(den), where=den > 1e-300 * (a * c + 1e-300)),
                0.0, 1.0)
    t = np.divide(b * s + e, c, out=np.zeros_like(c), where=c > 0)
    t_c = np.clip(t, 0.0, 1.0)
    s = np.where(t != t_c, np.clip(np.divide(b * t_c - d, a, out=np.zeros_like(a), where=a > 0), 0.0, 1.0), s)
    return s, t_c


def minimum_distance(V_a, F_a, V_b, F_b, check_crossings=True):
    """The smallest distance between two triangle meshes (0 where they intersect).

    The minimum over vertex-triangle distances both ways (proven closest points) and edge-edge
    distances of the edges near each other.

    Parameters
    ----------
    V_a : (n,3) float
    F_a : (m,3) int
    V_b : (p,3) float
    F_b : (q,3) int

    Returns
    -------
    float
    """
    V_a = np.asarray(V_a, dtype=np.float64)
    V_b = np.asarray(V_b, dtype=np.float64)
    F_a = np.asarray(F_a, dtype=np.int64)
    F_b = np.asarray(F_b, dtype=np.int64)
    used_a = np.unique(F_a.reshape(-1))
    used_b = np.unique(F_b.reshape(-1))
    # An upper bound from nearby candidates, then every primitive pair within it, exactly.
    best = float(min(TriangleSurface(V_b, F_b).closest(V_a[used_a])[1].min(),
                     TriangleSurface(V_a, F_a).closest(V_b[used_b])[1].min()))
    if best == 0.0:
        return 0.0
    best = min(best, _point_triangle_min(V_a[used_a], V_b, F_b, best),
               _point_triangle_min(V_b[used_b], V_a, F_a, best))
    E_a, E_b = mesh_edges(F_a), mesh_edges(F_b)
    P0, P1 = V_a[E_a[:, 0]], V_a[E_a[:, 1]]
    Q0, Q1 = V_b[E_b[:, 0]], V_b[E_b[:, 1]]
    pairs = box_pairs(np.minimum(P0, P1) - best, np.maximum(P0, P1) + best,
                      np.minimum(Q0, Q1), np.maximum(Q0, Q1))
    for s in range(0, pairs.shape[0], PAIR_BATCH):
        i, j = pairs[s:s + PAIR_BATCH, 0], pairs[s:s + PAIR_BATCH, 1]
        if i.size:
            best = min(best, float(segment_distances(P0[i], P1[i], Q0[j], Q1[j]).min()))
    if best > 0 and check_crossings and crossings_exist(V_a, F_a, V_b, F_b):
        return 0.0
    return best


def _point_triangle_min(P, V, F, bound):
    """Smallest distance from points P (k,3) to triangles (V, F) among those within ``bound``."""
    T = V[F]
    pairs = box_pairs(P - bound, P + bound, T.min(axis=1), T.max(axis=1))
    best = bound
    for s in range(0, pairs.shape[0], PAIR_BATCH):
        i, j = pairs[s:s + PAIR_BATCH, 0], pairs[s:s + PAIR_BATCH, 1]
        if i.size:
            Qc, _ = closest_on_triangles(P[i], T[j, 0], T[j, 1], T[j, 2])
            best = min(best, float(np.linalg.norm(P[i] - Qc, axis=1).min()))
    return best


def crossings_exist(V_a, F_a, V_b, F_b):
    """True when the two meshes intersect (exact)."""
    c = crossings(V_a, F_a, V_b, F_b)
    return c["a_edge_pairs"] + c["b_edge_pairs"] > 0


def intersection_report(V, F, body_V, body_F, source_V=None, layers_below=()):
    """The intersection figures of a garment: crossings with the body, self-intersections,
    crossings with the layers under it and the smallest distance to the body.

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int
        The garment.
    body_V : (p,3) float
    body_F : (q,3) int
    source_V : (n,3) float, optional
        The garment before (on the source body): adds ``self_intersections_source``.
    layers_below : sequence of (V (k,3), F (l,3)), optional
        Garments under this one.

    Returns
    -------
    dict
        ``garment_edges_through_body``, ``body_edges_through_garment`` (edges), the same as
        ``*_pairs`` (edge-triangle pairs), ``self_intersections`` (pairs),
        ``self_intersections_source``, ``layer_crossings`` (pairs, with the layers below),
        ``min_body_distance``.
    """
    c = crossings(V, F, body_V, body_F)
    out = {"garment_edges_through_body": c["a_edges_through_b"],
           "garment_edge_body_pairs": c["a_edge_pairs"],
           "body_edges_through_garment": c["b_edges_through_a"],
           "body_edge_garment_pairs": c["b_edge_pairs"],
           "self_intersections": self_intersections(V, F)[0]}
    out["self_intersections_source"] = (self_intersections(source_V, F)[0] if source_V is not None else None)
    layer = 0
    for V_l, F_l in layers_below:
        cl = crossings(V, F, V_l, F_l)
        layer += cl["a_edge_pairs"] + cl["b_edge_pairs"]
    out["layer_crossings"] = layer
    out["min_body_distance"] = (0.0 if c["a_edge_pairs"] + c["b_edge_pairs"]
                                else minimum_distance(V, F, body_V, body_F, check_crossings=False))
    return out
