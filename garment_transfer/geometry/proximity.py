"""Closest points on a triangle mesh and signed distance to it.

The search is libigl's axis-aligned bounding-box tree (``igl.AABB``): a branch-and-bound over
boxes, so the triangle it returns is the closest one by construction, not a likely candidate. The
closest point and its barycentric coordinates are then computed here, on that triangle, with the
same formula (Ericson) that a brute-force search over all triangles uses: both answers agree to
rounding, and barycentric coordinates are exact zeros on edges and at corners.

The sign comes from angle-weighted pseudonormals (Baerentzen & Aanaes 2005) at the closest point:
face normal inside a face, the mean of the two face normals on an edge, the angle-weighted vertex
normal at a corner. This is exact for closed meshes and degrades gracefully on open ones (eye
sockets, neck holes): a point is judged by the surface nearest to it, not by ray parity or a
winding number that a hole would spoil.

Outward is decided by the mesh, not by its face winding: a body whose faces all point inward (an
OBJ file written with the other winding, an object mirrored by a negative scale) encloses a
negative signed volume, and its normals are then turned around (``TriangleSurface.orientation``).
The volume is taken about the mesh's centroid, so an open body's holes only add a small error and
the sign of a mostly closed surface still decides. A surface that encloses next to no volume (a
sheet) is taken as wound.

Where the closest point lies on an edge or a corner, several triangles hold it; the one with the
lowest index is returned, so the answer does not depend on the tree's layout: a moved or rotated
scene gives the same triangles (a binding made on them carries the same way), and the points of
one corner region all get one triangle.

Queries limited to a band around the surface (``within=``) stop searching as soon as no box is
nearer than the band, which makes them several times cheaper for points far from the mesh: the
penetration fix only needs the garment vertices near the body. Their tree is built over only the
triangles that can be that near a query point, for only the points that can be that near a triangle
(``near_boxes``): a garment is near a small part of the body.
"""

from __future__ import annotations

import hashlib
import os
import threading
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import igl
import numpy as np
import scipy.sparse as sp

from .mesh import (Mesh, common_polygons, cross_rows, faces_split, faces_turned, same_mesh, triangle_normals,
                   turned_around)

#: Threads for the numpy part of a query (per-point work on the found triangles); libigl's tree
#: search runs on all cores by itself.
THREADS = max(1, os.cpu_count() or 1)
#: Below this many points the numpy part runs in one piece (threads cost more than they save).
THREAD_MIN = 8192


def closest_on_triangles(P, A, B, C):
    """Closest points of P on triangles ABC, pairwise (Ericson, Real-Time Collision Detection 5.1.5).

    Parameters
    ----------
    P, A, B, C : (k,3) float

    Returns
    -------
    Q : (k,3) float64
        Closest points.
    bary : (k,3) float64
        Barycentric coordinates of Q in (A, B, C); exact zeros on edges and corners.
    """
    ab, ac = B - A, C - A
    ap, bp, cp = P - A, P - B, P - C
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2

    def ratio(num, den):
        return np.divide(num, den, out=np.zeros_like(num), where=den != 0)

    denom = va + vb + vc
    bary = np.empty_like(P)
    # The regions in reverse order of precedence: a point in several takes the last one's answer.
    # Each region's answer is computed on its own points only.
    edge_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    edge_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    corner_c = (d6 >= 0) & (d5 <= d6)
    edge_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    corner_b = (d3 >= 0) & (d4 <= d3)
    corner_a = (d1 <= 0) & (d2 <= 0)
    face = ~(edge_bc | edge_ac | corner_c | edge_ab | corner_b | corner_a)
    if face.any():
        # Inside the face all three are >= 0 but for rounding: clipped, so coordinates never go negative.
        f = np.stack([va[face], vb[face], vc[face]], axis=1)
        f = ratio(f, denom[face, None]).clip(0.0, None)
        total = f.sum(axis=1)
        bary[face] = f / np.where(total > 0, total, 1.0)[:, None]
    m = edge_bc
    t = ratio((d4 - d3)[m], (d4 - d3)[m] + (d5 - d6)[m])
    bary[m] = np.stack([np.zeros_like(t), 1 - t, t], axis=1)
    m = edge_ac
    t = ratio(d2[m], d2[m] - d6[m])
    bary[m] = np.stack([1 - t, np.zeros_like(t), t], axis=1)
    bary[corner_c] = (0.0, 0.0, 1.0)
    m = edge_ab
    t = ratio(d1[m], d1[m] - d3[m])
    bary[m] = np.stack([1 - t, t, np.zeros_like(t)], axis=1)
    bary[corner_b] = (0.0, 1.0, 0.0)
    bary[corner_a] = (1.0, 0.0, 0.0)
    # va + vb + vc = |ab x ac|^2: a (nearly) flat triangle is three segments, whose regions the
    # rules above cannot tell apart.
    flat = denom <= 1e-14 * np.einsum("ij,ij->i", ab, ab) * np.einsum("ij,ij->i", ac, ac)
    if flat.any():
        bary[flat] = _closest_on_segments(P[flat], A[flat], B[flat], C[flat])
    Q = bary[:, :1] * A + bary[:, 1:2] * B + bary[:, 2:] * C
    return Q, bary


#: A surface whose enclosed volume is below this share of ``area ** 1.5`` encloses nothing to turn
#: around (a sphere: 0.094; the MakeHuman bodies: about 0.03).
ENCLOSING_VOLUME_SHARE = 1e-3


def signed_volume(V, F) -> float:
    """Volume enclosed by triangles F over V, positive when their normals point outward.

    Taken about the vertices' centroid (for an open surface, the volume of the cone from it).

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int
    """
    V = np.asarray(V, dtype=np.float64)
    c = V.mean(axis=0)
    a, b, d = (V[F[:, k]] - c for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, d)).sum() / 6.0)


def orientation(V, F) -> int:
    """+1 if the faces F over V point outward (or enclose no volume), -1 if they point inward."""
    vol = signed_volume(V, F)
    area = float(triangle_normals(np.asarray(V, dtype=np.float64), F)[1].sum())
    return _orientation(vol, area)


def facing_outward(mesh: Mesh) -> Mesh:
    """``mesh`` itself when its faces point outward (``orientation``), else the mesh turned around."""
    return mesh if orientation(mesh.V, mesh.F) == 1 else turned_around(mesh)


def as_same_mesh(a: Mesh, b: Mesh):
    """``b`` as a shape of ``a``'s mesh, or None when it is another mesh.

    ``b`` itself when the two are one mesh (``same_mesh``). When ``b`` has ``a``'s polygons each turned the
    other way round (an OBJ written with the other winding), or split into smaller ones (written triangulated:
    ``mesh.faces_split``), or both, ``b``'s vertices with ``a``'s faces, provided that its shape read with
    ``a``'s faces encloses a volume of the sign ``a``'s does: the vertex order then keeps left and right, and
    the faces alone differ. Otherwise, ``b`` is ``a``'s mirror image by its vertex order (one of two objects
    mirrored in Blender): None, as for another mesh.

    A split ``b`` is the surface of ``a``'s polygons read along one of their diagonals, which every check of
    the project reads already (``readings``: every split of a polygon).

    Parameters
    ----------
    a, b : Mesh

    Returns
    -------
    Mesh or None
    """
    if same_mesh(a, b):
        return b
    if a.n_vertices != b.n_vertices or not (faces_turned(a, b) or faces_split(a, b)
                                            or faces_split(turned_around(a), b)):
        return None
    if orientation(b.V, a.F) != orientation(a.V, a.F):
        return None
    return a.with_vertices(b.V, name=b.name)


def common_mesh(a: Mesh, b: Mesh):
    """``a``'s vertices with the polygons that ``a`` and ``b`` both split (``mesh.common_polygons``: either of them
    or both written triangulated, one along other diagonals than the other, in either winding), or None when they
    are other meshes, or when ``b``'s shape read with those faces encloses a volume of another sign than ``a``'s
    (``b`` is ``a``'s mirror image by its vertex order). Every split of its polygons holds ``a``'s and ``b``'s
    own faces (``readings``)."""
    common = common_polygons(a, b)
    if common is None or orientation(b.V, common.F) != orientation(a.V, common.F):
        return None
    return common


def one_mesh(a: Mesh, b: Mesh) -> bool:
    """True when ``a`` and ``b`` are shapes of one mesh written with the same faces or others (``common_mesh``):
    their vertices correspond one to one."""
    return same_mesh(a, b) or common_mesh(a, b) is not None


def _orientation(volume, area) -> int:
    return -1 if volume < -ENCLOSING_VOLUME_SHARE * area ** 1.5 else 1


def _closest_on_segments(P, A, B, C):
    """Barycentric coordinates of the closest point of P on the three edges of (flat) triangles ABC."""
    corners = (A, B, C)
    best = np.full(P.shape[0], np.inf)
    bary = np.zeros((P.shape[0], 3))
    for i, j in ((0, 1), (1, 2), (2, 0)):
        a, b = corners[i], corners[j]
        ab = b - a
        ll = np.einsum("ij,ij->i", ab, ab)
        t = np.clip(np.divide(np.einsum("ij,ij->i", P - a, ab), ll, out=np.zeros_like(ll), where=ll > 0),
                    0.0, 1.0)
        d = np.linalg.norm(P - (a + t[:, None] * ab), axis=1)
        better = d < best
        best[better] = d[better]
        bary[better] = 0.0
        bary[better, i] = 1.0 - t[better]
        bary[better, j] = t[better]
    return bary


#: The grid of ``near_boxes`` has at most this many cells along its longest side.
NEAR_GRID_CELLS = 128
#: A bounded search (``TriangleSurface.closest(P, within)``) whose points are at least this share near the surface
#: asks the surface's own tree instead of building one over the near triangles: a garment that lies on the body (a
#: MakeHuman suit, 8,426 vertices: 51 ms with the tree built against 83 ms, the query alone) gains nothing from the
#: bound, and the tree serves the later queries on the same body (the pose fit's penetration fix 0.9x its time; a
#: transfer's the same); a loose dress (40% of its points near) keeps the bound.
FULL_SEARCH_SHARE = 0.75


def near_boxes(P, V, F, within):
    """Which triangles and which points can be closer than ``within`` to each other.

    A triangle closer than ``within`` to a point has its bounding box, grown by ``within``, around the
    point. On a grid of cells at least ``within`` wide over the points: a triangle is kept when its
    grown box covers a cell holding a point, and a point when its cell is covered by a kept triangle's
    grown box. Both tests only ever keep too much (the boxes are grown a little more for rounding), so
    every triangle-point pair closer than ``within`` is among the kept ones.

    Parameters
    ----------
    P : (p,3) float64
    V : (n,3) float64
    F : (m,3) int64
    within : float

    Returns
    -------
    faces : (k,) int64
        Increasing triangle indices.
    points : (q,) int64
        Increasing point indices.
    """
    pad = within * (1.0 + 1e-6)
    # Column by column: numpy's reductions along the first axis of an (n,3) array are several times
    # slower.
    lo = np.array([P[:, c].min() for c in range(3)]) - pad
    extent = max(float(P[:, c].max() + pad - lo[c]) for c in range(3))
    if not np.isfinite(extent):
        # NaN points are near nothing; measuring the rest is the caller's concern.
        ok = np.flatnonzero(np.isfinite(P).all(axis=1))
        faces, points = near_boxes(P[ok], V, F, within) if ok.size else (np.zeros(0, np.int64),) * 2
        return faces, ok[points]
    cell = max(pad, extent / NEAR_GRID_CELLS)
    # P - lo >= pad > 0: truncation is the floor.
    k = ((P - lo) / cell).astype(np.int64)
    dims = np.array([k[:, c].max() for c in range(3)]) + 1
    # Cells holding a point, summed from the corner (one cell of zeros before each axis).
    S = np.zeros(tuple(dims + 1), np.int32)
    shape = np.array(S.shape)
    S.reshape(-1)[((k[:, 0] + 1) * shape[1] + k[:, 1] + 1) * shape[2] + k[:, 2] + 1] = 1
    S = S.cumsum(axis=0).cumsum(axis=1).cumsum(axis=2)
    x0, x1, x2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    # Truncated, not floored: below the grid both give cells clipped to its first one (b takes one
    # cell more there, which only keeps more).
    a = ((np.minimum(np.minimum(x0, x1), x2) - pad - lo) / cell).astype(np.int64)
    b = ((np.maximum(np.maximum(x0, x1), x2) + pad - lo) / cell).astype(np.int64) + 1
    np.maximum(a, 0, out=a)
    np.minimum(a, dims, out=a)
    np.maximum(b, 0, out=b)
    np.minimum(b, dims, out=b)
    faces = np.flatnonzero(_box_sums(S, a, b) > 0)
    if faces.size == 0:
        return faces, np.zeros(0, np.int64)
    # Cells covered by a kept triangle's box: +1 and -1 at the corners of each box, summed up.
    a, b = a[faces], b[faces]
    D = np.zeros(tuple(dims + 1), np.int32)
    for corner in range(8):
        pick = [(b if corner >> axis & 1 else a)[:, axis] for axis in range(3)]
        sign = -1 if bin(corner).count("1") % 2 else 1
        np.add.at(D, tuple(pick), sign)
    covered = D.cumsum(axis=0).cumsum(axis=1).cumsum(axis=2).reshape(-1) > 0
    points = np.flatnonzero(covered[(k[:, 0] * shape[1] + k[:, 1]) * shape[2] + k[:, 2]])
    return faces, points


def _box_sums(S, a, b):
    """Sums over the cells ``a <= cell < b`` (per row) from the corner sums S."""
    x0, y0, z0 = a.T
    x1, y1, z1 = b.T
    return (S[x1, y1, z1] - S[x0, y1, z1] - S[x1, y0, z1] - S[x1, y1, z0]
            + S[x0, y0, z1] + S[x0, y1, z0] + S[x1, y0, z0] - S[x0, y0, z0])


def _check_points(P):
    P = np.ascontiguousarray(P, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"query points P must have shape (p, 3), got {P.shape}")
    return P


@dataclass
class Topology:
    """What a surface's queries need from its triangles alone, shared by every shape of one mesh.

    Attributes
    ----------
    tri_edges : (m,3) int64
        The edge opposite corner j of triangle t.
    faces_per_edge : (e,) int64
    rim : (m,) bool
        Triangles with a corner on an open rim (an edge of one triangle).
    corners : (n, 3m) scipy.sparse.csr_matrix
        Vertex i by corner (t, k) (column ``3 t + k``): 1 where ``F[t, k] == i``.
    fan_start : (n+1,) int64
    fan : (3m,) int64
        The triangles around vertex i, in increasing order: ``fan[fan_start[i]:fan_start[i+1]]``.
    """

    tri_edges: np.ndarray
    faces_per_edge: np.ndarray
    rim: np.ndarray
    corners: sp.csr_matrix
    fan_start: np.ndarray
    fan: np.ndarray


#: Topologies of recent surfaces, by the digest of their triangles: a garment goes to many shapes of
#: one body (targets, shape keys, a catalogue), and each shape would otherwise sort its edges again.
_TOPOLOGIES: OrderedDict = OrderedDict()
_TOPOLOGIES_KEPT = 8
_TOPOLOGIES_LOCK = threading.Lock()


def topology(n, F) -> Topology:
    """The ``Topology`` of triangles F over n vertices (kept for the last few meshes)."""
    F = np.ascontiguousarray(F, dtype=np.int64)
    key = (n, F.shape[0], hashlib.blake2b(F.tobytes(), digest_size=20).digest())
    with _TOPOLOGIES_LOCK:
        if key in _TOPOLOGIES:
            _TOPOLOGIES.move_to_end(key)
            return _TOPOLOGIES[key]
    m = F.shape[0]
    # Edge opposite corner j of triangle t is (F[t, j+1], F[t, j+2]).
    a = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    b = np.concatenate([F[:, 2], F[:, 0], F[:, 1]])
    _, inv, count = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_inverse=True, return_counts=True)
    tri_edges = inv.reshape(3, m).T
    rim_vertex = np.zeros(n, bool)
    ends = np.stack([F[:, [1, 2]], F[:, [2, 0]], F[:, [0, 1]]], axis=1)
    rim_vertex[ends[count[tri_edges] == 1].reshape(-1)] = True
    flat = F.reshape(-1)
    corners = sp.csr_matrix((np.ones(3 * m), (flat, np.arange(3 * m))), shape=(n, 3 * m))
    order = np.argsort(flat, kind="stable")
    fan_start = np.searchsorted(flat[order], np.arange(n + 1))
    top = Topology(tri_edges, count, rim_vertex[F].any(axis=1), corners, fan_start, order // 3)
    with _TOPOLOGIES_LOCK:
        _TOPOLOGIES[key] = top
        while len(_TOPOLOGIES) > _TOPOLOGIES_KEPT:
            _TOPOLOGIES.popitem(last=False)
    return top


def made_of(made, V, F=None) -> bool:
    """Whether something made of a body's positions (a ``TriangleSurface``, an ``obstacle.Obstacle``; None: not
    made) is of these very positions V (and, given ``F``, of these very triangles: a ``TriangleSurface``'s)."""
    return (made is not None and made.V.shape == np.shape(V) and np.array_equal(made.V, V)
            and (F is None or np.array_equal(made.F, F)))


class TriangleSurface:
    """A triangle mesh prepared for closest-point and signed-distance queries.

    ``orientation`` is -1 when the faces point inward; the normals (``face_normals`` and the
    pseudonormals) are then the turned-around ones, so inside and outside do not depend on winding.

    The search tree and the pseudonormals are built on first use and kept.

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int
        At least one triangle.
    """

    def __init__(self, V, F):
        self.V = np.ascontiguousarray(V, dtype=np.float64)
        self.F = np.ascontiguousarray(F, dtype=np.int64)
        if self.V.ndim != 2 or self.V.shape[1] != 3:
            raise ValueError(f"V must have shape (n, 3), got {self.V.shape}")
        if self.F.ndim != 2 or self.F.shape[1] != 3 or self.F.shape[0] == 0:
            raise ValueError(f"F must have shape (m, 3) with m >= 1, got {self.F.shape}")
        if self.F.min() < 0 or self.F.max() >= self.V.shape[0]:
            raise ValueError(f"F refers to vertices outside 0..{self.V.shape[0] - 1}")
        self._tree = None
        self._normals = None
        self._vertex_normals = None
        self._orientation = None
        self._topology = None

    @property
    def tree(self):
        """libigl's AABB tree over the triangles."""
        if self._tree is None:
            tree = igl.AABB()
            tree.init(self.V, self.F)
            self._tree = tree
        return self._tree

    @property
    def orientation(self) -> int:
        """+1 when the faces point outward (or enclose no volume), -1 when they point inward."""
        if self._orientation is None:
            self._face_parts()
        return self._orientation

    def _face_parts(self):
        """The edge vectors ``x1-x0, x2-x1, x0-x2`` (3,m,3), the cross products ``(x1-x0) x (x2-x0)``
        (m,3) and their norms (m,), twice the areas; sets the orientation, which needs the same
        products (not kept: ``_pseudonormals`` uses them once)."""
        x0, x1, x2 = (self.V[self.F[:, k]] for k in range(3))
        edges = np.stack([x1 - x0, x2 - x1, x0 - x2])
        # As ``triangle_normals`` computes it (negation is exact).
        cross = cross_rows(edges[0], -edges[2])
        dbl = np.linalg.norm(cross, axis=1)
        if self._orientation is None:
            # ``signed_volume`` (about the centroid), from the same cross products.
            volume = float(np.einsum("ij,ij->", x0 - self.V.mean(axis=0), cross)) / 6.0
            self._orientation = _orientation(volume, 0.5 * float(dbl.sum()))
        return edges, cross, dbl

    @property
    def topology(self) -> Topology:
        if self._topology is None:
            self._topology = topology(self.V.shape[0], self.F)
        return self._topology

    def _pseudonormals(self):
        """Face normals (m,3), twice the areas (m,), ``tri_edges`` and edge normals (e,3); the vertex
        normals are computed apart (``vertex_normals``, or ``_vertex_normals_of`` for a few)."""
        if self._normals is None:
            top = self.topology
            _, cross, dbl = self._face_parts()
            face = np.divide(cross, dbl[:, None], out=np.zeros_like(cross), where=dbl[:, None] > 0)
            face *= self._orientation
            edge = _edge_pseudonormals(top, face)
            self._normals = face, dbl, top.tri_edges, edge
        return self._normals

    @property
    def face_normals(self):
        """(m,3) float64 unit normals (zero for degenerate triangles)."""
        return self._pseudonormals()[0]

    @property
    def vertex_normals(self):
        """(n,3) float64 angle-weighted vertex pseudonormals."""
        if self._vertex_normals is None:
            face = self._pseudonormals()[0]
            edges, _, dbl = self._face_parts()
            self._vertex_normals = _vertex_pseudonormals(edges, dbl, face, self.topology.corners)
        return self._vertex_normals

    def _vertex_normals_of(self, v):
        """``vertex_normals[v]`` for the vertices v (k,) int, from their own triangles only: a query
        needs the normals of the few vertices its closest points lie on."""
        if self._vertex_normals is not None:
            return self._vertex_normals[v]
        face, dbl, _, _ = self._pseudonormals()
        top = self.topology
        ptr, fan = top.fan_start, top.fan
        deg = ptr[v + 1] - ptr[v]
        k = np.arange(int(deg.max()) if v.size else 0)
        ok = k < deg[:, None]
        t = fan[np.minimum(ptr[v][:, None] + k, ptr[v + 1][:, None] - 1)]
        corners = self.F[t]
        # The corner of v in each triangle, and the edges x1-x0, x2-x1, x0-x2 (as ``_face_parts``).
        c = np.argmax(corners == v[:, None, None], axis=2)
        x = self.V[corners]
        e = x[:, :, [1, 2, 0]] - x
        idx = np.indices(c.shape)
        cosine = -np.einsum("abj,abj->ab", e[idx[0], idx[1], c], e[idx[0], idx[1], (c + 2) % 3])
        angle = np.where(ok, np.arctan2(dbl[t], cosine), 0.0)
        return _normalize(np.einsum("ab,abj->aj", angle, face[t]))

    @property
    def tri_edges(self):
        """(m,3) int64: the edge opposite corner j of triangle t, an index into ``edge_normals``."""
        return self._pseudonormals()[2]

    @property
    def edge_normals(self):
        """(e,3) float64 edge pseudonormals (the normalised sum of the adjacent face normals)."""
        return self._pseudonormals()[3]

    def closest(self, P, within=None):
        """Closest points of P on the surface, exact.

        Parameters
        ----------
        P : (p,3) float
        within : float, optional
            Only points closer than this are answered; the others get distance ``inf``, triangle
            -1 and NaN points and coordinates. Far points cost almost nothing then.

        Returns
        -------
        closest : (p,3) float64
        distance : (p,) float64
        triangle : (p,) int64
        bary : (p,3) float64
            Barycentric coordinates of ``closest`` in ``triangle``.
        """
        P = _check_points(P)
        p = P.shape[0]
        if p == 0:
            return np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 3))
        if within is None:
            _, tri, _ = self.tree.squared_distance(self.V, self.F, P)
            return self._on_triangles(P, tri)
        if not within > 0:
            raise ValueError(f"within must be > 0, got {within}")
        closest = np.full((p, 3), np.nan)
        dist = np.full(p, np.inf)
        triangle = np.full(p, -1, np.int64)
        bary = np.full((p, 3), np.nan)
        faces, points = near_boxes(P, self.V, self.F, float(within))
        if faces.size == 0 or points.size == 0:
            return closest, dist, triangle, bary
        if points.size >= FULL_SEARCH_SHARE * p:
            _, tri, _ = self.tree.squared_distance(self.V, self.F, P[points])
            c, d, t, w = self._on_triangles(P[points], tri)
            found = d < within
            near = points[found]
            closest[near], dist[near], triangle[near], bary[near] = c[found], d[found], t[found], w[found]
            return closest, dist, triangle, bary
        # libigl's bounded search answers NaN beyond the bound. It builds a tree of its own, here over
        # the triangles that can be that near (a garment is near a small part of the body), for the
        # points that can be that near.
        d, tri, _, _ = igl.signed_distance(P[points], self.V, self.F[faces], igl.SIGNED_DISTANCE_TYPE_UNSIGNED,
                                           0.0, float(within))
        found = np.isfinite(d) & (tri >= 0) & (tri < faces.size)
        near = points[found]
        if near.size:
            closest[near], dist[near], triangle[near], bary[near] = self._on_triangles(P[near], faces[tri[found]])
        return closest, dist, triangle, bary

    def _on_triangles(self, P, tri):
        """Closest points of P on the given triangles, on threads for large queries."""
        tri = np.asarray(tri, dtype=np.int64)
        n = P.shape[0]
        if n < THREAD_MIN or THREADS == 1:
            return self._on_triangles_one(P, tri)
        step = -(-n // THREADS)
        parts = [(P[i:i + step], tri[i:i + step]) for i in range(0, n, step)]
        # numpy's array operations release the GIL: the pieces run at once.
        with ThreadPoolExecutor(len(parts)) as pool:
            done = list(pool.map(lambda a: self._on_triangles_one(*a), parts))
        return tuple(np.concatenate(x) for x in zip(*done))

    def _on_triangles_one(self, P, tri):
        c = self.V[self.F[tri]]
        Q, bary = closest_on_triangles(P, c[:, 0], c[:, 1], c[:, 2])
        shared = np.flatnonzero((bary <= 0.0).any(axis=1))
        if shared.size:
            tri = tri.copy()
            canon = self._canonical(P[shared], tri[shared], bary[shared])
            change = canon != tri[shared]
            if change.any():
                s = shared[change]
                tri[s] = canon[change]
                c = self.V[self.F[tri[s]]]
                Q[s], bary[s] = closest_on_triangles(P[s], c[:, 0], c[:, 1], c[:, 2])
        return Q, np.linalg.norm(P - Q, axis=1), tri, bary

    def _canonical(self, P, tri, bary):
        """Among the triangles holding the closest point (on an edge or corner of ``tri``), the one
        with the lowest index."""
        ptr, fan = self.topology.fan_start, self.topology.fan
        corners = self.F[tri]
        held = bary > 0.0
        v = corners[np.arange(tri.shape[0]), np.argmax(bary, axis=1)]
        deg = ptr[v + 1] - ptr[v]
        k = np.arange(int(deg.max()))
        cand = fan[np.minimum(ptr[v][:, None] + k, ptr[v + 1][:, None] - 1)]
        ok = k < deg[:, None]
        cf = self.F[cand]
        for j in range(3):
            # Every vertex that holds the closest point must be a corner of the candidate.
            has = (cf == corners[:, j, None, None]).any(axis=2)
            ok &= has | ~held[:, j, None]
        # Fans list their triangles in increasing order: the first one allowed is the lowest.
        return cand[np.arange(tri.shape[0]), np.argmax(ok, axis=1)]

    def normals_at(self, tri, bary):
        """Pseudonormals at surface points given by triangle and barycentric coordinates.

        Parameters
        ----------
        tri : (p,) int
        bary : (p,3) float

        Returns
        -------
        N : (p,3) float64
        """
        face, _, tri_edges, edge = self._pseudonormals()
        zero = bary <= 0.0
        nzero = zero.sum(axis=1)
        N = face[tri]
        on_edge = nzero == 1
        if on_edge.any():
            j = np.argmax(zero[on_edge], axis=1)
            N[on_edge] = edge[tri_edges[tri[on_edge], j]]
        on_corner = nzero == 2
        if on_corner.any():
            j = np.argmax(~zero[on_corner], axis=1)
            v = self.F[tri[on_corner], j]
            unique, back = np.unique(v, return_inverse=True)
            N[on_corner] = self._vertex_normals_of(unique)[back]
        return N

    def inside(self, P):
        """(p,) bool: P inside the surface by the generalised winding number (> 1/2), which small
        holes do not spoil away from them. For points off the surface; P : (p,3) float."""
        P = _check_points(P)
        if P.shape[0] == 0:
            return np.zeros(0, bool)
        return self.orientation * igl.fast_winding_number(self.V, self.F, P) > 0.5

    def _inside_few(self, P):
        """``inside`` for a few points off the surface: the side of the pseudonormal at the exact
        closest point (right on a closed surface; Baerentzen and Aanaes 2005), and the winding number
        only where the closest triangle touches an open rim. The winding number builds a tree of its
        own on every call (50 ms on a 27K-triangle body); the search tree is kept."""
        closest, _, tri, bary = self.closest(P)
        inside = np.einsum("ij,ij->i", P - closest, self.normals_at(tri, bary)) < 0
        # Where the closest triangle touches an open rim, the pseudonormal does not decide the side.
        rim = self.topology.rim[tri]
        if rim.any():
            inside[rim] = self.inside(P[rim])
        return inside

    def signed_distance(self, P, within=None, graph=None):
        """Signed distance of P to the surface: negative inside.

        Parameters
        ----------
        P : (p,3) float
        within : float, optional
            Points farther than this from the surface are not measured: their distance is
            ``+inf`` outside and ``-inf`` inside (the side from ``inside``), their closest point
            and normal NaN and their triangle -1.
        graph : (p,p) sparse, optional
            Edges between the points (a garment's vertex adjacency), with ``within``. Two far
            points joined by an edge no longer than ``2 * within`` are on one side (the surface
            would have to pass within ``within`` of one of them), so the side of far points is
            decided once per connected group, by the majority of up to 32 of its points.

        Returns
        -------
        sd : (p,) float64
        closest : (p,3) float64
        normal : (p,3) float64
            Outward pseudonormal at the closest point.
        triangle : (p,) int64
        """
        P = _check_points(P)
        closest, dist, tri, bary = self.closest(P, within)
        near = tri >= 0
        N = np.full(P.shape, np.nan)
        sd = dist.copy()
        if near.any():
            N[near] = self.normals_at(tri[near], bary[near])
            side = np.einsum("ij,ij->i", P[near] - closest[near], N[near])
            sd[near] = np.where(side < 0, -dist[near], dist[near])
        far = np.flatnonzero(~near)
        if far.size:
            inside = self._far_inside(P, far, within, graph)
            sd[far] = np.where(inside, -np.inf, np.inf)
        return sd, closest, N, tri

    def _far_inside(self, P, far, within, graph, votes=32):
        if graph is None or within is None:
            return self.inside(P[far])
        import scipy.sparse as sp
        from scipy.sparse.csgraph import connected_components

        G = sp.csr_matrix(graph)
        # Each edge once, between far points (no sparse fancy indexing: it copies the graph twice).
        row = np.repeat(np.arange(G.shape[0]), np.diff(G.indptr))
        col = G.indices
        is_far = np.zeros(P.shape[0], bool)
        is_far[far] = True
        keep = (row < col) & is_far[row] & is_far[col]
        row, col = row[keep], col[keep]
        d = P[row] - P[col]
        short = np.einsum("ij,ij->i", d, d) <= (2.0 * within) ** 2
        number = np.empty(P.shape[0], np.int64)
        number[far] = np.arange(far.size)
        H = sp.coo_matrix((np.ones(int(short.sum())), (number[row[short]], number[col[short]])),
                          shape=(far.size, far.size))
        count, label = connected_components(H, directed=False)
        order = np.argsort(label, kind="stable")
        start = np.searchsorted(label[order], np.arange(count + 1))
        size = np.diff(start)
        # Up to ``votes`` points spread over each group.
        k = np.minimum(size, votes)
        group = np.repeat(np.arange(count), k)
        rank = np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k)
        pick = order[start[group] + (rank * size[group]) // k[group]]
        vote = self._inside_few(P[far[pick]])
        share = np.bincount(group, weights=vote, minlength=count) / k
        return (share > 0.5)[label]


def _vertex_pseudonormals(edges, dbl, face_normals, corners):
    """Angle-weighted vertex normals.

    ``edges``: the edge vectors ``x1-x0, x2-x1, x0-x2`` (3,m,3); ``dbl``: twice the triangle areas
    (m,), the norm of the cross product of the two edges at any corner; ``corners``: ``Topology.corners``.
    """
    # The angle at corner k, between edge k and the reversed edge k-1, from its sine and cosine
    # (arctan2 is exact at 0 and pi).
    cosine = -np.einsum("kij,kij->ik", edges, edges[[2, 0, 1]])
    angle = np.arctan2(dbl[:, None], cosine)
    W = angle[:, :, None] * face_normals[:, None, :]
    return _normalize(corners @ W.reshape(-1, 3))


def _edge_pseudonormals(top: Topology, face_normals):
    """Edge normals (the normalised sum of the adjacent face normals), (e,3)."""
    inv = top.tri_edges.T.reshape(-1)
    fn = np.tile(face_normals, (3, 1))
    e = top.faces_per_edge.shape[0]
    return _normalize(np.stack([np.bincount(inv, weights=fn[:, c], minlength=e) for c in range(3)], axis=1))


def _normalize(X):
    n = np.linalg.norm(X, axis=1, keepdims=True)
    return np.divide(X, n, out=np.zeros_like(X), where=n > 0)
