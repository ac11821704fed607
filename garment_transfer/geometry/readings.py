"""Every way a tool may read a mesh's polygons as triangles: the union of all its triangulations.

A quad is two triangles, but which two depends on who reads it: this package splits it along its shorter
diagonal, Blender's Triangulate modifier and its renderers along one of their own choosing, a game engine or
another exporter along the first. A non-planar quad is two different surfaces under the two splits, so a
promise about the surface (no garment edge through the body, no body edge through the garment) is made for
both. ``Readings`` holds, for a mesh of polygons, every triangle any triangulation of a polygon can have and
every edge (the sides and every diagonal); a check run on all of them holds for every reading at once:

- an intersection of a garment read one way with a body read one way is an edge of one meeting a triangle of
  the other (``intersections``), and those edges and triangles are among the readings';
- conversely, every (edge, triangle) pair of two meshes' readings is present together in some pair of
  readings, so a pair found is a crossing a user can see.

Within one mesh, a diagonal of a polygon and a triangle of the same polygon are never in one triangulation
(they cross in the polygon), so such pairs are not self-intersections (``diagonal_of``). A quad has 4
triangles and 2 diagonals; an n-gon of up to ``ALL_TRIANGLES_UP_TO`` corners every triangle of its corners
(n(n-1)(n-2)/6: what ear clipping or Blender's beauty fill may choose); a larger one every fan (n(n-2)),
which covers the fans other tools make, not every triangulation.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from itertools import combinations

import numpy as np

from .broad_phase import stable_order

#: Polygons with at most this many corners are read as every triangle of their corners; larger ones as
#: every fan (the count of all triangles grows as n^3).
ALL_TRIANGLES_UP_TO = 12


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


@dataclass
class Readings:
    """The triangles and edges of every triangulation of a mesh's polygons.

    Attributes
    ----------
    F : (t,3) int64
        Every triangle of every reading (for a quad: both splits, 4 triangles), grouped by polygon.
    face : (t,) int64
        The polygon each comes from (non-decreasing).
    E : (e,2) int64
        Every edge: the polygons' sides and every diagonal, each once (sorted pairs).
    diagonal_of : (e,) int64
        For a diagonal, its polygon; -1 for a side of some polygon.
    owner : (e,) int64
        One polygon that holds each edge (a diagonal's own; the first of a side's): every edge lies in its
        owner's bounding box, so boxes of polygons stand for those of their edges and triangles.
    split : (m,3) int64
        The mesh's own triangulation (``Mesh.F``): for closest points, normals and the vertex graph.
    face_vertices : (k,) int64
    face_start : (p+1,) int64
        The polygons: polygon j is ``face_vertices[face_start[j]:face_start[j+1]]``.
    """

    F: np.ndarray
    face: np.ndarray
    E: np.ndarray
    diagonal_of: np.ndarray
    owner: np.ndarray
    split: np.ndarray
    face_vertices: np.ndarray
    face_start: np.ndarray
    _members: dict = field(default=None, repr=False)
    _topology: dict = field(default=None, repr=False)

    @property
    def n_triangles(self) -> int:
        return int(self.F.shape[0])

    @property
    def n_edges(self) -> int:
        return int(self.E.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.face_start.shape[0] - 1)

    def same_polygon(self, edges, triangles):
        """(k,) bool: the edge is a diagonal of the triangle's polygon (never in one reading with it).

        Parameters
        ----------
        edges, triangles : (k,) int
            Indices into ``E`` and ``F``.
        """
        d = self.diagonal_of[edges]
        return (d >= 0) & (d == self.face[triangles])

    def face_boxes(self, V):
        """(p,3), (p,3): each polygon's bounding box in V (it holds every triangle and edge of its readings)."""
        X = V[self.face_vertices]
        start = self.face_start[:-1]
        return np.minimum.reduceat(X, start, axis=0), np.maximum.reduceat(X, start, axis=0)

    def members(self) -> dict:
        """Which triangles and edges each polygon has (made once, kept): ``tri_start`` (p+1,) (the triangles
        ``tri_start[j]:tri_start[j+1]`` of ``F`` are polygon j's), ``edge_start`` (p+1,) and ``edge_order`` (e,)
        (the edges ``edge_order[edge_start[j]:edge_start[j+1]]`` are those polygon j owns)."""
        if self._members is None:
            p = self.n_faces
            tri_start, _ = _csr(self.face, p)
            edge_start, edge_order = _csr(self.owner, p)
            self._members = {"tri_start": tri_start, "edge_start": edge_start, "edge_order": edge_order}
        return self._members

    def triangles_of(self, P):
        """Every triangle of the polygons P (k,) int: (which (m,) index into P, triangle (m,) index into F)."""
        m = self.members()
        return group_members(m["tri_start"], None, np.asarray(P, dtype=np.int64))

    def edges_of(self, P):
        """Every edge the polygons P (k,) int own: (which (m,) index into P, edge (m,) index into E)."""
        m = self.members()
        return group_members(m["edge_start"], m["edge_order"], np.asarray(P, dtype=np.int64))

    def topology(self) -> dict:
        """What a self-intersection check needs of the polygons alone (made once, kept): ``members`` and
        ``touching`` (q,) int64: keys ``a * p + b`` of every ordered pair of polygons that share a vertex (a
        polygon with itself included), sorted; ``near`` (r,2) int64: every (edge, triangle) pair of polygons
        that share a vertex whose edge and triangle share none and are not a diagonal and a triangle of one
        polygon (the pairs a check of polygons that share no vertex would miss), and ``near_corners`` (5,r)
        int32: their edge's two vertices and triangle's three, a row each; per vertex, its near pairs
        (``near_start`` (n+1,), ``near_order``) and its polygons (``faces_start`` (n+1,), ``faces_order``).
        """
        if self._topology is None:
            self._topology = dict(self.members(), **_self_topology(self))
        return self._topology


def _csr(groups, count):
    """(count+1,) starts of the runs of each label in ``groups`` (k,) int, and the order that sorts them."""
    return np.concatenate([[0], np.cumsum(np.bincount(groups, minlength=count))]), stable_order(groups)


def group_members(start, order, P):
    """The members of each group in P (k,) int, given the groups' ``start`` (and ``order``, None when the
    members are in order already): (which (m,) index into P, member (m,))."""
    n = start[P + 1] - start[P]
    which = np.repeat(np.arange(P.shape[0]), n)
    member = np.repeat(start[P], n) + np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    return which, (member if order is None else order[member])


def _self_topology(R: Readings) -> dict:
    p = R.n_faces
    sizes = np.diff(R.face_start)
    poly_of_corner = np.repeat(np.arange(p), sizes)
    # Polygons around each vertex, then every ordered pair of polygons at one vertex.
    by_vertex = stable_order(R.face_vertices)
    verts = R.face_vertices[by_vertex]
    polys = poly_of_corner[by_vertex]
    vstart = np.searchsorted(verts, np.arange(int(verts.max()) + 2 if verts.size else 1))
    count = np.diff(vstart)
    a = np.repeat(polys, np.repeat(count, count))
    rep = np.repeat(vstart[:-1], count * count)
    local = np.arange(rep.size) - np.repeat(np.cumsum(count * count) - count * count, count * count)
    b = polys[rep + local % np.repeat(count, count * count)]
    touching = np.unique(a * p + b)
    m = R.members()
    edges, tris = _expand(touching // p, touching % p, m["edge_start"], m["edge_order"], m["tri_start"])
    # Column by column in 32 bits: the pairs number about 16 per pair of touching quads.
    small = np.int32 if R.face_vertices.size and int(R.face_vertices.max()) < 2 ** 31 else np.int64
    E, F = R.E.astype(small), R.F.astype(small)
    e0, e1 = E[edges, 0], E[edges, 1]
    t0, t1, t2 = F[tris, 0], F[tris, 1], F[tris, 2]
    shared = (e0 == t0) | (e0 == t1) | (e0 == t2) | (e1 == t0) | (e1 == t1) | (e1 == t2)
    keep = np.flatnonzero(~shared & ~R.same_polygon(edges, tris))
    # Each polygon pair once, each edge owned by one polygon: every (edge, triangle) pair comes once.
    near = np.stack([edges[keep], tris[keep]], axis=1)
    corners = np.stack([e0[keep], e1[keep], t0[keep], t1[keep], t2[keep]], axis=1)
    n = int(R.face_vertices.max()) + 1 if R.face_vertices.size else 0
    near_start, near_order = _csr(corners.reshape(-1), n)
    faces_start, faces_order = _csr(R.face_vertices, n)
    return {"touching": touching, "near": near, "near_corners": np.ascontiguousarray(corners.T, dtype=np.int32),
            # Per vertex: the near pairs and the polygons it is in (``_runs`` reads them).
            "near_start": near_start, "near_order": near_order // 5,
            "faces_start": faces_start, "faces_order": poly_of_corner[faces_order]}


def _expand(P, Q, edge_start, edge_order, tri_start):
    """Every (edge owned by P[i], triangle of Q[i]) for pairs of polygons (P, Q (k,) int): (edges, triangles)."""
    ne = edge_start[P + 1] - edge_start[P]
    nt = tri_start[Q + 1] - tri_start[Q]
    n = ne * nt
    pair = np.repeat(np.arange(P.shape[0]), n)
    local = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    nt_p = nt[pair]
    edges = edge_order[edge_start[P][pair] + local // nt_p]
    tris = tri_start[Q][pair] + local % nt_p
    return edges, tris


def expand_polygon_pairs(R: Readings, P, Q):
    """Every (edge owned by P[i], triangle of Q[i]) pair for pairs of polygons P, Q (k,) int.

    Returns
    -------
    (j,2) int64
        (index into ``R.E``, index into ``R.F``).
    """
    m = R.members()
    edges, tris = _expand(np.asarray(P, np.int64), np.asarray(Q, np.int64), m["edge_start"], m["edge_order"],
                          m["tri_start"])
    return np.stack([edges, tris], axis=1)


def _polygon_triangles(fv, fs, sizes, faces):
    """Every reading's triangles of the polygons ``faces`` (all of one size per call), with their owners."""
    k = int(sizes[faces[0]])
    corners = fv[fs[faces][:, None] + np.arange(k)]
    if k <= ALL_TRIANGLES_UP_TO:
        local = np.array(list(combinations(range(k), 3)), np.int64)
    else:
        local = np.array([(a, (a + i) % k, (a + i + 1) % k) for a in range(k) for i in range(1, k - 1)], np.int64)
    tris = corners[:, local].reshape(-1, 3)
    return tris, np.repeat(faces, local.shape[0])


def _polygon_edges(fv, fs, sizes, faces):
    """Every pair of corners of the polygons ``faces`` (one size per call), each marked side or diagonal."""
    k = int(sizes[faces[0]])
    corners = fv[fs[faces][:, None] + np.arange(k)]
    pairs = np.array(list(combinations(range(k), 2)), np.int64)
    side = ((pairs[:, 1] - pairs[:, 0]) == 1) | ((pairs[:, 0] == 0) & (pairs[:, 1] == k - 1))
    e = np.sort(corners[:, pairs].reshape(-1, 2), axis=1)
    return e, np.tile(side, faces.shape[0]), np.repeat(faces, pairs.shape[0])


def polygon_readings(face_vertices, face_start, split) -> Readings:
    """``Readings`` of polygons.

    Parameters
    ----------
    face_vertices : (k,) int
    face_start : (p+1,) int
        Polygon j is ``face_vertices[face_start[j]:face_start[j+1]]``.
    split : (m,3) int
        Their triangulation (``Mesh.F``).

    Returns
    -------
    Readings
    """
    fv = np.asarray(face_vertices, dtype=np.int64)
    fs = np.asarray(face_start, dtype=np.int64)
    sizes = np.diff(fs)
    faces = np.arange(sizes.shape[0])
    tris, owners, edges, sides, edge_owner = [], [], [], [], []
    for k in np.unique(sizes):
        group = faces[sizes == k]
        t, o = _polygon_triangles(fv, fs, sizes, group)
        e, s, eo = _polygon_edges(fv, fs, sizes, group)
        tris.append(t)
        owners.append(o)
        edges.append(e)
        sides.append(s)
        edge_owner.append(eo)
    F, face = np.concatenate(tris), np.concatenate(owners)
    by_face = np.argsort(face, kind="stable")
    F, face = F[by_face], face[by_face]
    E, side, owner = np.concatenate(edges), np.concatenate(sides), np.concatenate(edge_owner)
    n = int(fv.max()) + 1 if fv.size else 1
    key = E[:, 0] * n + E[:, 1]
    # A pair that is a side of any polygon is a side (owned by its first polygon); a diagonal keeps its one.
    order = np.lexsort((owner, ~side, key))
    key, side, owner = key[order], side[order], owner[order]
    first = np.ones(key.shape[0], bool)
    first[1:] = key[1:] != key[:-1]
    key, side, owner = key[first], side[first], owner[first]
    E = np.stack([key // n, key % n], axis=1)
    return Readings(F.astype(np.int64), face.astype(np.int64), E, np.where(side, -1, owner).astype(np.int64),
                    owner.astype(np.int64), np.asarray(split, dtype=np.int64), fv, fs)


def triangle_readings(F) -> Readings:
    """``Readings`` of a triangle mesh: its own triangles and edges (one reading)."""
    F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
    return polygon_readings(F.reshape(-1), np.arange(F.shape[0] + 1, dtype=np.int64) * 3, F)


def readings_of(mesh) -> Readings:
    """``Readings`` of a ``Mesh`` (its polygons; a mesh of triangles has one reading).

    The readings depend on the polygons alone (but ``split``, the mesh's own): for shapes of one mesh (a body's
    shape keys, a catalogue's targets, ``Mesh.with_vertices``, which keeps the polygon arrays) they are made once
    and kept (``KEPT_READINGS`` meshes).

    Parameters
    ----------
    mesh : Mesh
    """
    R = _kept_for((mesh.face_vertices, mesh.face_start),
                  lambda: polygon_readings(mesh.face_vertices, mesh.face_start, mesh.F))
    return R if R.split is mesh.F else replace(R, split=np.asarray(mesh.F, dtype=np.int64))


def readings_with_graph(mesh, split) -> Readings:
    """``readings_of(mesh)`` with another vertex graph ``split`` (triangles of the mesh's vertices: every split of
    its polygons, say) for the checks and moves that spread over it; kept as ``readings_of`` keeps a mesh's (by the
    identity of the arrays), so that what a self-intersection check needs (``Readings.topology``) is made once.

    Parameters
    ----------
    mesh : Mesh
    split : (m,3) int
    """
    return _kept_for((mesh.face_vertices, mesh.face_start, split, _GRAPH),
                     lambda: replace(readings_of(mesh), split=np.asarray(split, dtype=np.int64)))


#: Marks the kept readings of ``readings_with_graph`` apart from the others kept for the same arrays.
_GRAPH = np.zeros(0)


def split_readings(mesh) -> Readings:
    """The readings of one triangulation of a mesh's polygons, its own (``Mesh.F``): its triangles and their edges,
    grouped by the polygon they come from (kept as ``readings_of`` keeps a mesh's).

    A check on them is the check of ``triangle_readings(mesh.F)`` (the same edges and triangles, a pair never
    counted where its edge and triangle share a vertex, which every pair within a polygon does), with the polygons'
    boxes for the bins: half as many boxes as triangles on a quad mesh (a posed MakeHuman body's own crossings in
    0.6 times the time).

    Parameters
    ----------
    mesh : Mesh
    """
    return _kept_for((mesh.face_vertices, mesh.face_start, mesh.F), lambda: _split_readings(mesh))


def _split_readings(mesh) -> Readings:
    order = stable_order(np.asarray(mesh.tri_to_face, dtype=np.int64))
    return polygon_triangles_readings(np.asarray(mesh.F, dtype=np.int64)[order],
                                      np.asarray(mesh.tri_to_face, dtype=np.int64)[order], mesh.F,
                                      mesh.face_vertices, mesh.face_start)


def polygon_triangles_readings(F, face, split, face_vertices, face_start) -> Readings:
    """``Readings`` of some triangles of a mesh's polygons (one split, or those of every split kept by a test)
    and of their edges, binned by polygon: each edge owned by the polygon of a triangle it is a side of, whose box
    holds it. No edge is taken for a diagonal (``diagonal_of`` -1): the checks leave out every pair whose edge and
    triangle share a vertex, as each such pair within a polygon does.

    Parameters
    ----------
    F : (t,3) int
        The triangles, grouped by polygon.
    face : (t,) int
        Each one's polygon (non-decreasing).
    split : (m,3) int
        The vertex graph and the surface (``Readings.split``).
    face_vertices, face_start : (k,), (p+1,) int
        The polygons.
    """
    F = np.asarray(F, dtype=np.int64)
    face = np.asarray(face, dtype=np.int64)
    n = int(F.max()) + 1 if F.size else 1
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    key, first = np.unique(e[:, 0] * n + e[:, 1], return_index=True)
    return Readings(F, face, np.stack([key // n, key % n], axis=1), np.full(key.shape[0], -1, np.int64),
                    np.tile(face, 3)[first], np.asarray(split, dtype=np.int64),
                    np.asarray(face_vertices, dtype=np.int64), np.asarray(face_start, dtype=np.int64))


def kept_triangle_readings(F) -> Readings:
    """``triangle_readings(F)``, kept as ``readings_of`` keeps a mesh's (by the identity of the array ``F``): the
    poses of one character share their triangle arrays, so what a self-intersection check needs of them
    (``Readings.topology``) is made once."""
    return _kept_for((F,), lambda: triangle_readings(F))


def _kept_for(arrays, make) -> Readings:
    """The readings kept for these very arrays (by identity), else ``make()``, kept for the next time."""
    for kept, R in _kept:
        if len(kept) == len(arrays) and all(a is b for a, b in zip(kept, arrays)):
            return R
    R = make()
    _kept.insert(0, (arrays, R))
    del _kept[KEPT_READINGS:]
    return R


#: How many readings ``readings_of`` and ``kept_triangle_readings`` keep (their arrays are held with them).
KEPT_READINGS = 8
_kept = []


def as_readings(F) -> Readings:
    """``F`` itself when it is ``Readings``; a triangle array (m,3) as one reading."""
    return F if isinstance(F, Readings) else triangle_readings(F)


def merge_readings(parts) -> Readings:
    """One ``Readings`` of several meshes: parts is a list of (number of vertices, Readings); each part's
    indices are offset by the vertices and polygons before it."""
    vb = fb = 0
    F, face, E, diag, owner, split, fv, fs = [], [], [], [], [], [], [], [np.zeros(1, np.int64)]
    for n, R in parts:
        F.append(R.F + vb)
        face.append(R.face + fb)
        E.append(R.E + vb)
        diag.append(np.where(R.diagonal_of >= 0, R.diagonal_of + fb, -1))
        owner.append(R.owner + fb)
        split.append(R.split + vb)
        fv.append(R.face_vertices + vb)
        fs.append(R.face_start[1:] + fs[-1][-1])
        vb += int(n)
        fb += R.n_faces
    return Readings(*(np.concatenate(x) for x in (F, face, E, diag, owner, split, fv, fs)))
