"""Closest points on a triangle mesh and signed distance to it.

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
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy.spatial import cKDTree

from .mesh import triangle_normals

#: Points per batch in closest-point queries, and batches run at once.
BATCH = 4096
THREADS = max(1, min(4, os.cpu_count() or 1))


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
    v = ratio(vb, denom)
    w = ratio(vc, denom)
    bary = np.stack([1.0 - v - w, v, w], axis=1)
    # Regions in reverse order of precedence: each later rule overrides the earlier ones.
    rules = []
    m = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    t = ratio(d4 - d3, (d4 - d3) + (d5 - d6))
    rules.append((m, np.stack([np.zeros_like(t), 1 - t, t], axis=1)))
    m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    t = ratio(d2, d2 - d6)
    rules.append((m, np.stack([1 - t, np.zeros_like(t), t], axis=1)))
    m = (d6 >= 0) & (d5 <= d6)
    rules.append((m, np.array([0.0, 0.0, 1.0])))
    m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    t = ratio(d1, d1 - d3)
    rules.append((m, np.stack([1 - t, t, np.zeros_like(t)], axis=1)))
    m = (d3 >= 0) & (d4 <= d3)
    rules.append((m, np.array([0.0, 1.0, 0.0])))
    m = (d1 <= 0) & (d2 <= 0)
    rules.append((m, np.array([1.0, 0.0, 0.0])))
    for mask, value in rules:
        bary = np.where(mask[:, None], value, bary)
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
    return -1 if vol < -ENCLOSING_VOLUME_SHARE * area ** 1.5 else 1


class TriangleSurface:
    """A triangle mesh prepared for closest-point and signed-distance queries.

    ``orientation`` is -1 when the faces point inward; the normals (``face_normals`` and the
    pseudonormals) are then the turned-around ones, so inside and outside do not depend on winding.

    Parameters
    ----------
    V : (n,3) float
    F : (m,3) int
    """

    def __init__(self, V, F):
        self.V = np.asarray(V, dtype=np.float64)
        self.F = np.asarray(F, dtype=np.int64)
        corners = self.V[self.F]
        self.centroids = corners.mean(axis=1)
        radii = np.max(np.linalg.norm(corners - self.centroids[:, None], axis=2), axis=1)
        self.radius = float(radii.max()) if radii.size else 0.0
        self.tree = cKDTree(self.centroids)
        self.face_normals, self.areas = triangle_normals(self.V, self.F)
        self.orientation = orientation(self.V, self.F)
        self.face_normals *= self.orientation
        self.vertex_normals = self._vertex_pseudonormals()
        self.tri_edges, self.edge_normals = self._edge_pseudonormals()

    def _vertex_pseudonormals(self):
        V, F = self.V, self.F
        N = np.zeros_like(V)
        for k in range(3):
            a = V[F[:, (k + 1) % 3]] - V[F[:, k]]
            b = V[F[:, (k + 2) % 3]] - V[F[:, k]]
            na = np.linalg.norm(a, axis=1)
            nb = np.linalg.norm(b, axis=1)
            cos = np.einsum("ij,ij->i", a, b) / np.maximum(na * nb, 1e-300)
            angle = np.arccos(np.clip(cos, -1.0, 1.0))
            np.add.at(N, F[:, k], angle[:, None] * self.face_normals)
        return _normalize(N)

    def _edge_pseudonormals(self):
        F = self.F
        m = F.shape[0]
        # Edge opposite corner j of triangle t is (F[t, j+1], F[t, j+2]).
        a = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
        b = np.concatenate([F[:, 2], F[:, 0], F[:, 1]])
        key = np.minimum(a, b) * self.V.shape[0] + np.maximum(a, b)
        uniq, inv = np.unique(key, return_inverse=True)
        EN = np.zeros((uniq.shape[0], 3))
        np.add.at(EN, inv, np.tile(self.face_normals, (3, 1)))
        return inv.reshape(3, m).T, _normalize(EN)

    def closest(self, P, k=16, verify=False):
        """Closest points of P on the surface.

        Candidates are the k triangles with the nearest centroids. On the bodies and garments here,
        k=16 finds the same triangles as a search over 128 (the tests check against brute force);
        ``verify=True`` proves every answer and searches wider where it cannot.

        Parameters
        ----------
        P : (p,3) float
        k : int
        verify : bool

        Returns
        -------
        closest : (p,3) float64
        distance : (p,) float64
        triangle : (p,) int64
        bary : (p,3) float64
        """
        P = np.asarray(P, dtype=np.float64)
        # Small batches keep the candidate arrays in cache (measured 4.5x faster than one batch of
        # 78K points) and bound the memory for any mesh size; batches run on all cores, as the tree
        # queries and large array operations release the GIL.
        batches = [P[i:i + BATCH] for i in range(0, P.shape[0], BATCH)] or [P]
        if len(batches) == 1 or THREADS == 1:
            parts = [self._closest(b, k, verify) for b in batches]
        else:
            with ThreadPoolExecutor(THREADS) as pool:
                parts = list(pool.map(lambda b: self._closest(b, k, verify), batches))
        return tuple(np.concatenate(x) for x in zip(*parts))

    def _closest(self, P, k, verify):
        p = P.shape[0]
        closest = np.zeros((p, 3))
        dist = np.full(p, np.inf)
        tri = np.zeros(p, np.int64)
        bary = np.zeros((p, 3))
        todo = np.arange(p)
        m = self.F.shape[0]
        while todo.size:
            kk = min(k, m)
            dc, cand = self.tree.query(P[todo], k=kk)
            dc, cand = dc.reshape(todo.size, kk), cand.reshape(todo.size, kk)
            self._best_of(P, todo, cand, closest, dist, tri, bary)
            if not verify or kk == m:
                break
            # Any triangle closer than the best found has its centroid within best + radius of P.
            todo = todo[dist[todo] + self.radius >= dc[:, -1]]
            k *= 4
        return closest, dist, tri, bary

    def _best_of(self, P, todo, cand, closest, dist, tri, bary):
        """Evaluate triangles ``cand[i, :]`` for point ``todo[i]``; keep improvements."""
        kk = cand.shape[1]
        T = cand.reshape(-1)
        Pr = np.repeat(P[todo], kk, axis=0)
        c = self.V[self.F[T]]
        Q, B = closest_on_triangles(Pr, c[:, 0], c[:, 1], c[:, 2])
        d = np.linalg.norm(Pr - Q, axis=1).reshape(-1, kk)
        j = np.argmin(d, axis=1)
        sel = np.arange(todo.size) * kk + j
        dj = d[np.arange(todo.size), j]
        better = dj < dist[todo]
        r, sel = todo[better], sel[better]
        closest[r] = Q[sel]
        dist[r] = dj[better]
        tri[r] = T[sel]
        bary[r] = B[sel]

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
        zero = bary <= 0.0
        nzero = zero.sum(axis=1)
        N = self.face_normals[tri].copy()
        on_edge = nzero == 1
        if on_edge.any():
            j = np.argmax(zero[on_edge], axis=1)
            N[on_edge] = self.edge_normals[self.tri_edges[tri[on_edge], j]]
        on_corner = nzero == 2
        if on_corner.any():
            j = np.argmax(~zero[on_corner], axis=1)
            N[on_corner] = self.vertex_normals[self.F[tri[on_corner], j]]
        return N

    def signed_distance(self, P, k=16):
        """Signed distance of P to the surface: negative inside.

        Returns
        -------
        sd : (p,) float64
        closest : (p,3) float64
        normal : (p,3) float64
            Outward pseudonormal at the closest point.
        triangle : (p,) int64
        """
        P = np.asarray(P, dtype=np.float64)
        closest, dist, tri, bary = self.closest(P, k)
        N = self.normals_at(tri, bary)
        side = np.einsum("ij,ij->i", P - closest, N)
        sd = np.where(side < 0, -dist, dist)
        return sd, closest, N, tri


def _normalize(X):
    n = np.linalg.norm(X, axis=1, keepdims=True)
    return np.divide(X, n, out=np.zeros_like(X), where=n > 0)
