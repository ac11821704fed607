"""A body (or a body and the layers under a garment) that a garment must clear, binned once, and a garment
checked against it: crossings, and the smallest distance, under every reading of both meshes' polygons.

The body does not move while a garment is checked against it (by the crossing pass, round after round, or once
on a result as written), so its triangles, edges and vertices are binned once (``broad_phase.BoxGrid``) and
each check asks about the garment's parts only, or only those that moved.
"""

from __future__ import annotations

import numpy as np

from .broad_phase import BoxGrid
from .intersections import crossing_counts, segment_distances
from .mesh import triangle_normals
from .predicates import segment_sides, segments_meet_triangles, triangle_planes
from .proximity import TriangleSurface, closest_on_triangles
from .readings import Readings, as_readings, group_members


class Obstacle:
    """What the garment must clear (a body, or a body and the layers under a garment), as a check asks about
    it: every reading of its polygons, its polygons' boxes binned once (it does not move).

    A polygon's box holds all its readings' triangles and edges, and a body's polygons are smaller than a
    garment's edges: a garment edge's box meets few of them, and only those are taken apart into triangles and
    edges (four times fewer binned boxes than the triangles of both splits of every quad).

    Parameters
    ----------
    V : (p,3) float
    F : (q,3) int or Readings
        Triangles, or every reading of the polygons (``readings.readings_of``).
    surface : TriangleSurface, optional
        Of ``V`` and the mesh's own triangles (``Readings.split``), when already built: closest points,
        signed distance and normals.
    cell : float, optional
        The grids' cell side: best about the size of what will be asked about (the garment's edges); at
        least the median size of the obstacle's polygons.

    Attributes
    ----------
    V : (p,3) float64
    R : Readings
    F, E : (t,3), (e,2) int64
        Every reading's triangles and edges.
    surface : TriangleSurface
    face_normals : (t,3) float64
        Unit normals of ``F``.
    """

    def __init__(self, V, F, surface=None, cell=None):
        self.V = np.asarray(V, dtype=np.float64)
        self.R = as_readings(F)
        self.F, self.E = self.R.F, self.R.E
        self.surface = surface if surface is not None else TriangleSurface(self.V, self.R.split)
        lo, hi = self.R.face_boxes(self.V)
        # Cells much smaller than the boxes asked about would each be listed many times.
        self.cell = max(float(np.median((hi - lo).max(axis=1))), float(cell or 0.0))
        self.polygon_grid = BoxGrid(lo, hi, self.cell)
        self.face_normals = triangle_normals(self.V, self.F)[0]
        self._vertex_grid = None
        self._planes = None

    @property
    def planes(self):
        """``predicates.triangle_planes`` of every reading's triangles ``F`` (made when first asked, kept)."""
        if self._planes is None:
            T = self.F
            self._planes = triangle_planes(self.V[T[:, 0]], self.V[T[:, 1]], self.V[T[:, 2]])
        return self._planes

    @property
    def vertex_normals(self):
        return self.surface.vertex_normals

    @property
    def vertex_grid(self):
        """The vertices as points, binned."""
        if self._vertex_grid is None:
            used = np.unique(self.F)
            self._vertex_grid = BoxGrid(self.V[used], self.V[used], cell=self.cell)
            self._vertex_ids = used
        return self._vertex_grid

    def vertices_near(self, lo, hi):
        """(k,2) (query box, obstacle vertex) pairs: the vertices in each box (lo, hi (q,3))."""
        pairs = self.vertex_grid.query(lo, hi)
        return np.stack([pairs[:, 0], self._vertex_ids[pairs[:, 1]]], axis=1)

    def triangles_near(self, lo, hi):
        """(k,2) (query box, obstacle triangle) pairs whose boxes overlap (lo, hi (q,3))."""
        pairs = self.polygon_grid.query(lo, hi)
        which, tri = self.R.triangles_of(pairs[:, 1])
        q = pairs[which, 0]
        T = self.V[self.F[tri]]
        keep = np.all((lo[q] <= T.max(axis=1)) & (T.min(axis=1) <= hi[q]), axis=1)
        return np.stack([q[keep], tri[keep]], axis=1)

    def edges_near(self, lo, hi):
        """(k,2) (query box, obstacle edge) pairs whose boxes overlap (lo, hi (q,3))."""
        pairs = self.polygon_grid.query(lo, hi)
        which, edge = self.R.edges_of(pairs[:, 1])
        q = pairs[which, 0]
        P, Q = self.V[self.E[edge, 0]], self.V[self.E[edge, 1]]
        keep = np.all((lo[q] <= np.maximum(P, Q)) & (np.minimum(P, Q) <= hi[q]), axis=1)
        return np.stack([q[keep], edge[keep]], axis=1)


def as_obstacle(V, F, surface=None, cell=None) -> Obstacle:
    """``Obstacle(V, F, surface, cell)``; F may already be one (then V, surface and cell are its own)."""
    return F if isinstance(F, Obstacle) else Obstacle(V, F, surface, cell)


def edge_length(V, G: Readings):
    """The median length of the sides and diagonals of a garment's polygons (its grids' cell)."""
    return float(np.median(np.linalg.norm(V[G.E[:, 0]] - V[G.E[:, 1]], axis=1))) if G.n_edges else 0.0


def garment_crossings(V, G: Readings, obstacle: Obstacle, active=None):
    """``intersections.crossings(V, G, obstacle.V, obstacle.R)``, the obstacle's bins asked about the
    garment's polygons (those with an ``active`` ((n,) bool) vertex, or all): one query gives the pairs of
    polygons whose boxes overlap, and each such pair the garment's edges against the obstacle's triangles and
    the obstacle's edges against the garment's triangles.

    Returns
    -------
    dict
        As ``crossings``: ``a_*`` the garment's edges through the obstacle's triangles (``a_triangles``
        index ``obstacle.F``), ``b_*`` the obstacle's edges through the garment's triangles
        (``b_triangles`` index ``G.F``).
    """
    V = np.asarray(V, dtype=np.float64)
    Pg, Pb = polygon_pairs(V, G, obstacle, np.arange(G.n_faces) if active is None else faces_touching(G, active))
    blo, bhi = obstacle.polygon_grid.lo, obstacle.polygon_grid.hi
    # Garment edges (each polygon's own: every edge once) whose box meets an obstacle polygon's, against its
    # triangles.
    which, edge = G.edges_of(Pg)
    Pe = Pb[which]
    if active is not None:
        keep = active[G.E[edge]].any(axis=1)
        edge, Pe = edge[keep], Pe[keep]
    keep = _boxes_meet(V, G.E[edge], blo[Pe], bhi[Pe])
    edge, Pe = edge[keep], Pe[keep]
    j, tri = obstacle.R.triangles_of(Pe)
    edge = edge[j]
    pa, ua = _meet(V, G.E[edge], obstacle.V, obstacle.F[tri], np.stack([edge, tri], axis=1), obstacle.planes, tri)
    # The garment polygons' triangles whose box meets an obstacle polygon's, against its own edges.
    which, tri = G.triangles_of(Pg)
    Pt = Pb[which]
    if active is not None:
        keep = active[G.F[tri]].any(axis=1)
        tri, Pt = tri[keep], Pt[keep]
    keep = _boxes_meet(V, G.F[tri], blo[Pt], bhi[Pt])
    tri, Pt = tri[keep], Pt[keep]
    j, edge = obstacle.R.edges_of(Pt)
    T = G.F[tri]
    planes = triangle_planes(V[T[:, 0]], V[T[:, 1]], V[T[:, 2]])
    tri = tri[j]
    pb, ub = _meet(obstacle.V, obstacle.E[edge], V, G.F[tri], np.stack([edge, tri], axis=1), planes, j)
    return crossing_counts(G.E, _sorted(pa), obstacle.E, _sorted(pb), ua + ub)


def _meet(V_e, ends, V_t, corners, pairs, planes, rows):
    """The pairs (k,2) whose segment (``ends`` (k,2) vertices of V_e) meets its triangle (``corners`` (k,3)
    vertices of V_t, row ``rows`` of ``planes``: ``predicates.triangle_planes``): the segments with both ends
    certainly on one side of the triangle's plane are left out (most of them), the rest tested exactly."""
    s1, s2 = segment_sides(V_e[ends[:, 0]], V_e[ends[:, 1]], planes, rows)
    k = np.flatnonzero((s1 == 0) | (s1 != s2))
    e, t = ends[k], corners[k]
    meet, uncertain = segments_meet_triangles(V_e[e[:, 0]], V_e[e[:, 1]], V_t[t[:, 0]], V_t[t[:, 1]], V_t[t[:, 2]])
    return pairs[k[meet]], uncertain


def _boxes_meet(V, corners, lo, hi):
    """(k,) bool: the box of each row of ``corners`` (k,c) vertices of V meets the box (lo, hi (k,3))."""
    keep = np.ones(corners.shape[0], bool)
    for axis in range(3):
        x = V[:, axis][corners]
        lo_x, hi_x = x[:, 0], x[:, 0]
        for c in range(1, corners.shape[1]):
            lo_x, hi_x = np.minimum(lo_x, x[:, c]), np.maximum(hi_x, x[:, c])
        keep &= (lo_x <= hi[:, axis]) & (lo[:, axis] <= hi_x)
    return keep


def polygon_pairs(V, G: Readings, obstacle: Obstacle, faces, pad=0.0):
    """The pairs of a garment polygon among ``faces`` (k,) int and an obstacle polygon whose boxes (the garment's
    grown by ``pad``) overlap: (garment polygons (j,), obstacle polygons (j,))."""
    lo, hi = face_boxes_of(G, V, faces)
    pairs = obstacle.polygon_grid.query(lo - pad, hi + pad)
    return faces[pairs[:, 0]], pairs[:, 1]


def faces_touching(G: Readings, active):
    """The polygons with an ``active`` ((n,) bool) corner."""
    corner = active[G.face_vertices]
    return np.unique(np.repeat(np.arange(G.n_faces), np.diff(G.face_start))[corner])


def face_boxes_of(G: Readings, V, faces):
    """(k,3), (k,3): the boxes of the polygons ``faces`` (k,) int in V."""
    which, corner = group_members(G.face_start, None, faces)
    X = V[G.face_vertices[corner]]
    start = np.searchsorted(which, np.arange(faces.shape[0]))
    return np.minimum.reduceat(X, start, axis=0), np.maximum.reduceat(X, start, axis=0)


def _sorted(pairs):
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def garment_distance(V, G: Readings, obstacle: Obstacle):
    """The smallest distance between a garment and the obstacle under every reading of both (0 where they
    meet; assumes no crossing, as ``intersections.minimum_distance(check_crossings=False)``).

    An upper bound first (each garment vertex's distance to the obstacle's own triangles, which are among its
    readings'), then every primitive pair within it, exactly: garment vertex - obstacle triangle, obstacle
    vertex - garment triangle, garment edge - obstacle edge.

    Returns
    -------
    float
    """
    V = np.asarray(V, dtype=np.float64)
    used = np.unique(G.F)
    best = float(obstacle.surface.closest(V[used])[1].min())
    if best == 0.0:
        return 0.0
    P = V[used]
    pairs = obstacle.triangles_near(P - best, P + best)
    if pairs.size:
        T = obstacle.V[obstacle.F[pairs[:, 1]]]
        q, _ = closest_on_triangles(P[pairs[:, 0]], T[:, 0], T[:, 1], T[:, 2])
        best = min(best, float(np.linalg.norm(P[pairs[:, 0]] - q, axis=1).min()))
    T = V[G.F]
    pairs = obstacle.vertices_near(T.min(axis=1) - best, T.max(axis=1) + best)
    if pairs.size:
        T = T[pairs[:, 0]]
        q = obstacle.V[pairs[:, 1]]
        p, _ = closest_on_triangles(q, T[:, 0], T[:, 1], T[:, 2])
        best = min(best, float(np.linalg.norm(p - q, axis=1).min()))
    P0, P1 = V[G.E[:, 0]], V[G.E[:, 1]]
    pairs = obstacle.edges_near(np.minimum(P0, P1) - best, np.maximum(P0, P1) + best)
    if pairs.size:
        i, j = pairs[:, 0], pairs[:, 1]
        Q0, Q1 = obstacle.V[obstacle.E[j, 0]], obstacle.V[obstacle.E[j, 1]]
        best = min(best, float(segment_distances(P0[i], P1[i], Q0, Q1).min()))
    return best
