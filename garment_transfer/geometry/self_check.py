"""A mesh's own intersections under every reading of its polygons, found in full or again where it moved.

A self-intersection is an (edge, triangle) pair of the mesh's readings (``readings.Readings``) that share no
vertex, are not a diagonal and a triangle of one polygon (never in one reading), and meet (the exact test of
``predicates``). Most boxes of a mesh's edges overlap the triangles around them, which share a vertex with
them: a broad phase on edges and triangles spends nearly all its time on pairs that are left out. So the
broad phase runs on polygons: pairs of polygons whose boxes overlap and that share no vertex give every
(edge, triangle) pair between them (a polygon's box holds its edges and triangles); the pairs between
polygons that share a vertex are listed once from the topology (``Readings.topology``'s ``near``) and only
their boxes are tested. On the MakeHuman suits this is about ten times faster than edges against triangles.
"""

from __future__ import annotations

import numpy as np

from .broad_phase import BoxGrid
from .predicates import segments_meet_triangles
from .readings import Readings, expand_polygon_pairs, group_members

NO_PAIRS = np.zeros((0, 2), np.int64)
#: The polygons' grid cell, in median polygon extents, for a mesh checked once in full (``SelfCheck(..., cell=)``):
#: the self-join pairs the entries of each cell, and cells of 1.5 extents list each polygon in fewer cells (on the
#: 13K-quad MakeHuman body 0.08 s against 0.12 s at 1 extent). A mesh checked again where it moved keeps cells of
#: 1 extent: there each check asks about a few polygons, and larger cells hand it more to test (the crossing pass
#: of a suit against a whole posed body took up to twice as long at 1.5).
SELF_CELL = 1.5


def unique_pairs(pairs):
    """(k,2) int pairs, each once, sorted."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if pairs.shape[0] == 0:
        return pairs
    base = int(pairs[:, 1].max()) + 1
    key = np.unique(pairs[:, 0] * base + pairs[:, 1])
    return np.stack([key // base, key % base], axis=1)


def overlapping(V, corners, which=None):
    """Which (edge, triangle) pairs have overlapping bounding boxes in V (n,3): indices (k,) int64.

    ``corners`` (5,m) int: each pair's edge's two vertices and triangle's three, a row each; ``which`` (j,)
    int: test only those pairs (all by default). Tested axis by axis on what the last axis kept (the first
    axis leaves about half the pairs of neighbouring polygons)."""
    keep = which
    for axis in range(3):
        x = np.ascontiguousarray(V[:, axis])[corners if keep is None else corners[:, keep]]
        edge_lo, edge_hi = np.minimum(x[0], x[1]), np.maximum(x[0], x[1])
        tri_lo = np.minimum(np.minimum(x[2], x[3]), x[4])
        tri_hi = np.maximum(np.maximum(x[2], x[3]), x[4])
        overlap = (edge_lo <= tri_hi) & (tri_lo <= edge_hi)
        keep = np.flatnonzero(overlap) if keep is None else keep[overlap]
    return keep


class SelfCheck:
    """The self-intersecting (edge, triangle) pairs of one mesh's readings, in full (``all``) or of what moved
    (``local``).

    The polygons' boxes stay binned as the mesh moves: before a check, the boxes of the polygons that moved
    since the last one are moved in the bins (``BoxGrid.update``).

    Parameters
    ----------
    V : (n,3) float
        A shape of the mesh (for the bins' cell size).
    R : Readings
    cell : float
        The bins' cell side in median polygon extents (``SELF_CELL`` for a mesh checked once in full).
    """

    def __init__(self, V, R: Readings, cell=1.0):
        self.R = R
        self.top = R.topology()
        lo, hi = R.face_boxes(np.asarray(V, dtype=np.float64))
        self.cell = cell * float(np.median((hi - lo).max(axis=1))) if lo.shape[0] else 0.0
        self.V_binned = None

    @property
    def G(self) -> Readings:
        return self.R

    def _sync(self, V):
        """The polygon bins made for V: from scratch the first time, else the boxes of what moved since."""
        if self.V_binned is None:
            lo, hi = self.R.face_boxes(V)
            self.grid = BoxGrid(lo, hi, self.cell)
        else:
            moved = np.flatnonzero(np.any(V != self.V_binned, axis=1))
            if moved.size:
                faces = self._faces_of(moved)
                self.grid.update(faces, *self._boxes(V, faces))
        self.V_binned = V.copy()

    def _boxes(self, V, faces):
        """(k,3), (k,3): the boxes of the polygons ``faces`` (k,) in V."""
        which, corner = group_members(self.R.face_start, None, faces)
        X = V[self.R.face_vertices[corner]]
        start = np.searchsorted(which, np.arange(faces.shape[0]))
        return np.minimum.reduceat(X, start, axis=0), np.maximum.reduceat(X, start, axis=0)

    def _faces_of(self, vertices):
        """The polygons with a corner among ``vertices`` (k,) int, each once."""
        _, k = group_members(self.top["faces_start"], None, np.asarray(vertices, dtype=np.int64))
        return np.unique(self.top["faces_order"][k])

    def _near_of(self, vertices):
        """The ``near`` pairs with one of ``vertices`` (k,) int in the edge or the triangle, each once."""
        _, k = group_members(self.top["near_start"], None, np.asarray(vertices, dtype=np.int64))
        return np.unique(self.top["near_order"][k])

    def all(self, V):
        """Every self-intersecting pair of V: (k,2) (edge, triangle) indices into ``R.E``, ``R.F``, sorted."""
        V = np.asarray(V, dtype=np.float64)
        self._sync(V)
        pairs = self._apart(self.grid.self_pairs())
        return self._test(V, np.concatenate([pairs, pairs[:, ::-1]]), self._near_overlapping(V))

    def local(self, V, moved):
        """The self-intersecting pairs of V with a ``moved`` ((n,) bool) vertex in the edge or the triangle,
        sorted."""
        V = np.asarray(V, dtype=np.float64)
        self._sync(V)
        vertices = np.flatnonzero(moved)
        faces = self._faces_of(vertices)
        if faces.size == 0:
            return NO_PAIRS
        pairs = self.grid.query(self.grid.lo[faces], self.grid.hi[faces])
        pairs = self._apart(np.stack([faces[pairs[:, 0]], pairs[:, 1]], axis=1))
        near = self._near_overlapping(V, self._near_of(vertices))
        found = self._test(V, np.concatenate([pairs, pairs[:, ::-1]]), near)
        return found[self.touching(found, moved)]

    def _near_overlapping(self, V, which=None):
        """The ``near`` pairs (all, or those listed in ``which``) whose edge's and triangle's boxes overlap."""
        return self.top["near"][overlapping(V, self.top["near_corners"], which)]

    def _apart(self, pairs):
        """The polygon pairs (k,2) that share no vertex (the others are in ``near``)."""
        p = self.R.n_faces
        key = pairs[:, 0] * p + pairs[:, 1]
        touching = self.top["touching"]
        at = np.minimum(np.searchsorted(touching, key), max(touching.size - 1, 0))
        return pairs[touching[at] != key] if touching.size else pairs

    def _test(self, V, polygon_pairs, near):
        """The pairs that meet among every (edge, triangle) of the polygon pairs and the ``near`` pairs (whose
        boxes overlap: ``_near_overlapping``)."""
        R = self.R
        cand = expand_polygon_pairs(R, polygon_pairs[:, 0], polygon_pairs[:, 1])
        corners = np.concatenate([R.E[cand[:, 0]].T, R.F[cand[:, 1]].T])
        # Boxes first: most pairs of neighbouring polygons are apart.
        cand = np.concatenate([cand[overlapping(V, corners)], near])
        e, t = R.E[cand[:, 0]], R.F[cand[:, 1]]
        meet, _ = segments_meet_triangles(V[e[:, 0]], V[e[:, 1]], V[t[:, 0]], V[t[:, 1]], V[t[:, 2]])
        return unique_pairs(cand[meet])

    def touching(self, pairs, moved):
        """(k,) bool: the pairs (k,2) with a ``moved`` vertex in the edge or the triangle."""
        return moved[self.R.E[pairs[:, 0]]].any(axis=1) | moved[self.R.F[pairs[:, 1]]].any(axis=1)

    def again(self, V, pairs, moved):
        """The self-intersecting pairs of V, given ``pairs`` of an earlier shape from which only ``moved``
        vertices moved."""
        return unique_pairs(np.concatenate([pairs[~self.touching(pairs, moved)], self.local(V, moved)]))


def pairs_in_full(V, R: Readings):
    """Every self-intersecting pair of a mesh checked once in full: ``SelfCheck.all`` in cells of ``SELF_CELL``;
    (k,2) (edge, triangle) indices into ``R.E``, ``R.F``, sorted."""
    V = np.asarray(V, dtype=np.float64)
    return SelfCheck(V, R, cell=SELF_CELL).all(V)


def beyond_source(pairs, R: Readings, source_V, source_pairs):
    """The self-intersecting pairs of a result that count against its source: those its source shape does not
    have (exact test, pair by pair), less those at the source's own tangles while the result has no more pairs
    than the source (a crossing the source has, slid by an edge).

    Parameters
    ----------
    pairs : (k,2) int
        The result's self-intersecting (edge, triangle) pairs.
    R : Readings
    source_V : (n,3) float
        The garment's source shape.
    source_pairs : (j,2) int
        The source's own self-intersecting pairs.

    Returns
    -------
    (i,2) int64
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    e, t = R.E[pairs[:, 0]], R.F[pairs[:, 1]]
    S = np.asarray(source_V, dtype=np.float64)
    meet, _ = segments_meet_triangles(S[e[:, 0]], S[e[:, 1]], S[t[:, 0]], S[t[:, 1]], S[t[:, 2]])
    new = pairs[~meet]
    if new.shape[0] == 0 or pairs.shape[0] > source_pairs.shape[0]:
        return new
    tangled = np.zeros(S.shape[0], bool)
    tangled[R.E[source_pairs[:, 0]]] = True
    tangled[R.F[source_pairs[:, 1]]] = True
    at = tangled[R.E[new[:, 0]]].any(axis=1) | tangled[R.F[new[:, 1]]].any(axis=1)
    return new[~at]
