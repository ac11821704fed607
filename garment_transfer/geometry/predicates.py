"""The narrow phase of the intersection checks: exact closed segment-triangle tests.

Each orientation predicate (orient3d) is first evaluated in floating point with a guaranteed error bound
(Shewchuk's, widened); where the bound cannot certify the sign, the pair is decided again in exact integer
arithmetic on the inputs' exact binary values. ``edge_triangle_pairs`` runs the broad phase
(``broad_phase``) and then these tests. The convention (closed sets, touching counts, triangles of zero
area left out) is ``intersections``'.
"""

from __future__ import annotations

import numpy as np

from .broad_phase import box_pairs

#: Floating-point filter: a computed orient3d whose magnitude exceeds ``FILTER * permanent`` has
#: the sign of the exact determinant. Shewchuk's bound for this evaluation order is
#: (7 + 56 eps) eps with eps = 2^-53; 16 eps leaves a margin.
FILTER = 16.0 * 2.0 ** -53
#: Pairs handled per narrow-phase batch (bounds memory on huge meshes).
PAIR_BATCH = 1 << 20


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


def triangle_planes(A, B, C):
    """What ``segment_sides`` needs of triangles, made once for triangles asked about again and again (a body that
    does not move): ``(A, n, m)``, each (k,3): a corner, ``(B - A) x (C - A)`` and the magnitudes of its
    products (for the error bound), in floating point.

    Parameters
    ----------
    A, B, C : (k,3) float64
    """
    bd, cd = B - A, C - A
    xy, xz = bd[:, 1] * cd[:, 2], bd[:, 2] * cd[:, 1]
    yz, yx = bd[:, 2] * cd[:, 0], bd[:, 0] * cd[:, 2]
    zx, zy = bd[:, 0] * cd[:, 1], bd[:, 1] * cd[:, 0]
    n = np.stack([xy - xz, yz - yx, zx - zy], axis=1)
    m = np.stack([np.abs(xy) + np.abs(xz), np.abs(yz) + np.abs(yx), np.abs(zx) + np.abs(zy)], axis=1)
    return A, n, m


def segment_sides(P, Q, planes, rows):
    """``orient3d_filtered(A, B, C, P)`` and ``(A, B, C, Q)`` for segments PQ against triangles given by
    ``triangle_planes``: +1 or -1 where floating point certifies the sign, 0 where it cannot.

    Each is the floating-point evaluation of ``orient3d_filtered(P, B, C, A)`` (the differences from A, the
    cross product of the triangle's two, the dot product with the point's; the same error bound), whose sign is
    the opposite: only the point's part is computed per pair.

    Parameters
    ----------
    P, Q : (k,3) float64
    planes : tuple
        ``triangle_planes`` of the triangles.
    rows : (k,) int
        Each segment's triangle (a row of ``planes``).

    Returns
    -------
    (k,) int8, (k,) int8
    """
    A, n, m = (x[rows] for x in planes)
    out = []
    for X in (P, Q):
        ad = X - A
        det = ad[:, 0] * n[:, 0] + ad[:, 1] * n[:, 1] + ad[:, 2] * n[:, 2]
        ad = np.abs(ad)
        perm = ad[:, 0] * m[:, 0] + ad[:, 1] * m[:, 1] + ad[:, 2] * m[:, 2]
        out.append(np.where(np.abs(det) > FILTER * perm, np.sign(det), 0).astype(np.int8))
    return out[0], out[1]


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

def edge_triangle_pairs(V_e, E, V_t, F, same_mesh=False, *, edge_diagonal_of=None, triangle_face=None,
                        triangle_grid=None, edge_grid=None):
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
    edge_diagonal_of : (e,) int, optional
        With ``triangle_face`` (m,) int: pairs where the edge is a diagonal of the triangle's polygon
        (``Readings.diagonal_of``, ``Readings.face``) are left out: they are never in one reading.
    triangle_grid : BoxGrid, optional
        The triangles' boxes, binned already (``V_t[F]``'s, or larger boxes that hold them).
    edge_grid : BoxGrid, optional
        The edges' boxes, binned already (used when no ``triangle_grid`` is given).

    Returns
    -------
    pairs : (k,2) int64
        ``(edge index, triangle index)``, sorted.
    uncertain : int
        Pairs decided by the exact fallback.
    """
    V_e = np.asarray(V_e, dtype=np.float64)
    V_t = np.asarray(V_t, dtype=np.float64)
    E = np.asarray(E, dtype=np.int64).reshape(-1, 2)
    F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
    if E.shape[0] == 0 or F.shape[0] == 0:
        return np.zeros((0, 2), np.int64), 0
    cand = _candidates(V_e, E, V_t, F, triangle_grid, edge_grid)
    if same_mesh and cand.size:
        e, f = E[cand[:, 0]], F[cand[:, 1]]
        shared = (e[:, :1] == f).any(axis=1) | (e[:, 1:] == f).any(axis=1)
        cand = cand[~shared]
    if edge_diagonal_of is not None and cand.size:
        d = np.asarray(edge_diagonal_of)[cand[:, 0]]
        cand = cand[~((d >= 0) & (d == np.asarray(triangle_face)[cand[:, 1]]))]
    hits, uncertain = [], 0
    for s in range(0, cand.shape[0], PAIR_BATCH):
        c = cand[s:s + PAIR_BATCH]
        e, f = E[c[:, 0]], F[c[:, 1]]
        meet, u = segments_meet_triangles(V_e[e[:, 0]], V_e[e[:, 1]], V_t[f[:, 0]], V_t[f[:, 1]], V_t[f[:, 2]])
        hits.append(c[meet])
        uncertain += u
    pairs = np.concatenate(hits) if hits else np.zeros((0, 2), np.int64)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    return pairs, uncertain


def _candidates(V_e, E, V_t, F, triangle_grid=None, edge_grid=None):
    """(k,2) (edge, triangle) pairs whose boxes overlap: from a grid given (only the other side's boxes
    are made), or one made for the call."""
    if edge_grid is not None and triangle_grid is None:
        T = V_t[F]
        return edge_grid.query(T.min(axis=1), T.max(axis=1))[:, ::-1]
    P, Q = V_e[E[:, 0]], V_e[E[:, 1]]
    lo_e, hi_e = np.minimum(P, Q), np.maximum(P, Q)
    if triangle_grid is not None:
        return triangle_grid.query(lo_e, hi_e)
    T = V_t[F]
    lo_t, hi_t = T.min(axis=1), T.max(axis=1)
    # Only what lies within the other set's bounding box can meet it (a skirt and a whole body).
    ke = np.flatnonzero(np.all((lo_e <= hi_t.max(axis=0)) & (hi_e >= lo_t.min(axis=0)), axis=1))
    kt = np.flatnonzero(np.all((lo_t <= hi_e.max(axis=0)) & (hi_t >= lo_e.min(axis=0)), axis=1))
    if ke.size == 0 or kt.size == 0:
        return np.zeros((0, 2), np.int64)
    cand = box_pairs(lo_e[ke], hi_e[ke], lo_t[kt], hi_t[kt])
    return np.stack([ke[cand[:, 0]], kt[cand[:, 1]]], axis=1)


