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

Meshes of quads and n-gons are counted under every reading of their polygons (``readings.Readings``:
both splits of a quad, every diagonal as an edge), so that a count of 0 holds for the file whichever
triangulation the user's tool makes of it, and a pair counted is a crossing under some triangulation.
A plain (m,3) triangle array is one reading.

The broad phase is ``broad_phase``'s grid (``box_pairs``, or a ``BoxGrid`` binned once and asked again).

How: a broad phase on a uniform grid of axis-aligned boxes (vectorised; each candidate pair is
produced once, in the cell holding the lower corner of the two boxes' overlap), then a narrow
phase of orientation predicates (orient3d). Each predicate is first evaluated in floating point
with a guaranteed error bound (Shewchuk's, widened); where the bound cannot certify the sign,
the pair is decided again in exact integer arithmetic on the inputs' exact binary values.
"""

from __future__ import annotations

import numpy as np

from .broad_phase import box_pairs
from .predicates import (  # noqa: F401  (the narrow phase, re-exported: its users import it from here)
    FILTER,
    PAIR_BATCH,
    edge_triangle_pairs,
    orient3d_filtered,
    segment_meets_triangle_exact,
    segments_meet_triangles,
)
from .proximity import TriangleSurface, closest_on_triangles
from .readings import as_readings, mesh_edges  # noqa: F401
from .self_check import pairs_in_full

def crossings(V_a, F_a, V_b, F_b):
    """Intersections between two meshes, counted both ways, under every reading of their polygons.

    Parameters
    ----------
    V_a : (n,3) float
    F_a : (m,3) int or Readings
        The first mesh (a garment, or an inner layer): triangles, or every reading of its polygons
        (``readings.readings_of``), so that a crossing under any triangulation counts.
    V_b : (p,3) float
    F_b : (q,3) int or Readings
        The second mesh (the body, or an outer layer).

    Returns
    -------
    dict
        ``a_edges_through_b`` (edges of a that meet a triangle of b), ``a_edge_pairs`` (such
        (edge, triangle) pairs), ``b_edges_through_a``, ``b_edge_pairs``, ``uncertain`` (pairs the
        exact fallback decided) and the arrays ``a_pairs``, ``b_pairs`` (k,2) int64 (the edges, as vertex
        pairs) and ``a_triangles``, ``b_triangles`` (k,) (indices into the other mesh's triangles:
        ``Readings.F`` for readings).
    """
    A, B = as_readings(F_a), as_readings(F_b)
    pa, ua = edge_triangle_pairs(V_a, A.E, V_b, B.F)
    pb, ub = edge_triangle_pairs(V_b, B.E, V_a, A.F)
    return crossing_counts(A.E, pa, B.E, pb, ua + ub)


def crossing_counts(E_a, pa, E_b, pb, uncertain=0):
    """``crossings``' answer from its two lists of (edge, triangle) pairs.

    Parameters
    ----------
    E_a : (e,2) int
        Edges of a; ``pa`` (k,2): (edge of a, triangle of b) pairs that meet.
    E_b : (f,2) int
        Edges of b; ``pb`` (j,2): (edge of b, triangle of a).
    uncertain : int
    """
    return {"a_edges_through_b": int(np.unique(pa[:, 0]).size), "a_edge_pairs": int(pa.shape[0]),
            "b_edges_through_a": int(np.unique(pb[:, 0]).size), "b_edge_pairs": int(pb.shape[0]),
            "uncertain": int(uncertain), "a_pairs": E_a[pa[:, 0]].reshape(-1, 2), "a_triangles": pa[:, 1],
            "b_pairs": E_b[pb[:, 0]].reshape(-1, 2), "b_triangles": pb[:, 1]}


def self_intersections(V, F):
    """A mesh's own intersections: (edge, triangle) pairs of one mesh that share no vertex and meet.

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int or Readings
        Triangles, or every reading of the polygons: then a diagonal and a triangle of the same polygon,
        never in one reading, are not a pair.

    Returns
    -------
    count : int
        Intersecting pairs.
    edges : (k,2) int64
        The edge of each pair (vertex indices).
    triangles : (k,) int64
        The triangle of each pair (indices into F, or ``Readings.F``).
    """
    R = as_readings(F)
    pairs = pairs_in_full(V, R)
    return int(pairs.shape[0]), R.E[pairs[:, 0]], pairs[:, 1]


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
    """The smallest distance between two triangle meshes (0 where they intersect), under every reading.

    The minimum over vertex-triangle distances both ways (proven closest points) and edge-edge
    distances of the edges near each other. With ``Readings``, over every triangle and edge of every
    reading: the smallest distance the two meshes have under any triangulation.

    Parameters
    ----------
    V_a : (n,3) float
    F_a : (m,3) int or Readings
    V_b : (p,3) float
    F_b : (q,3) int or Readings

    Returns
    -------
    float
    """
    V_a = np.asarray(V_a, dtype=np.float64)
    V_b = np.asarray(V_b, dtype=np.float64)
    A, B = as_readings(F_a), as_readings(F_b)
    used_a = np.unique(A.F.reshape(-1))
    used_b = np.unique(B.F.reshape(-1))
    # An upper bound from nearby candidates, then every primitive pair within it, exactly.
    best = float(min(TriangleSurface(V_b, B.F).closest(V_a[used_a])[1].min(),
                     TriangleSurface(V_a, A.F).closest(V_b[used_b])[1].min()))
    if best == 0.0:
        return 0.0
    best = min(best, _point_triangle_min(V_a[used_a], V_b, B.F, best),
               _point_triangle_min(V_b[used_b], V_a, A.F, best))
    P0, P1 = V_a[A.E[:, 0]], V_a[A.E[:, 1]]
    Q0, Q1 = V_b[B.E[:, 0]], V_b[B.E[:, 1]]
    pairs = box_pairs(np.minimum(P0, P1) - best, np.maximum(P0, P1) + best,
                      np.minimum(Q0, Q1), np.maximum(Q0, Q1))
    for s in range(0, pairs.shape[0], PAIR_BATCH):
        i, j = pairs[s:s + PAIR_BATCH, 0], pairs[s:s + PAIR_BATCH, 1]
        if i.size:
            best = min(best, float(segment_distances(P0[i], P1[i], Q0[j], Q1[j]).min()))
    if best > 0 and check_crossings and crossings_exist(V_a, A, V_b, B):
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
    """True when the two meshes intersect (exact; ``F_a``, ``F_b`` triangles or Readings)."""
    c = crossings(V_a, F_a, V_b, F_b)
    return c["a_edge_pairs"] + c["b_edge_pairs"] > 0


def intersection_report(V, F, body_V, body_F, source_V=None, layers_below=()):
    """The intersection figures of a garment: crossings with the body, self-intersections,
    crossings with the layers under it and the smallest distance to the body, under every reading of
    the polygons given as ``Readings``.

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int or Readings
        The garment.
    body_V : (p,3) float
    body_F : (q,3) int or Readings
    source_V : (n,3) float, optional
        The garment before (on the source body): adds ``self_intersections_source``.
    layers_below : sequence of (V (k,3), F (l,3) or Readings), optional
        Garments under this one.

    Returns
    -------
    dict
        ``garment_edges_through_body``, ``body_edges_through_garment`` (edges), the same as
        ``*_pairs`` (edge-triangle pairs), ``self_intersections`` (pairs),
        ``self_intersections_source``, ``layer_crossings`` (pairs, with the layers below),
        ``min_body_distance``.
    """
    R, B = as_readings(F), as_readings(body_F)
    c = crossings(V, R, body_V, B)
    out = {"garment_edges_through_body": c["a_edges_through_b"],
           "garment_edge_body_pairs": c["a_edge_pairs"],
           "body_edges_through_garment": c["b_edges_through_a"],
           "body_edge_garment_pairs": c["b_edge_pairs"],
           "self_intersections": self_intersections(V, R)[0]}
    out["self_intersections_source"] = (self_intersections(source_V, R)[0] if source_V is not None else None)
    layer = 0
    for V_l, F_l in layers_below:
        cl = crossings(V, R, V_l, F_l)
        layer += cl["a_edge_pairs"] + cl["b_edge_pairs"]
    out["layer_crossings"] = layer
    out["min_body_distance"] = (0.0 if c["a_edge_pairs"] + c["b_edge_pairs"]
                                else minimum_distance(V, R, body_V, B, check_crossings=False))
    return out
