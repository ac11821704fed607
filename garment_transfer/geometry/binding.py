"""Points bound to a body surface, carried to another shape of the same body.

Each garment vertex is bound to its closest point on the source body (triangle and barycentric
coordinates) plus its offset, expressed in that triangle's frame ``[e1 e2 n]``. On a target body of
the same topology the point is rebuilt from the same triangle's frame: the offset turns, stretches
and scales with the body under it. This is how MakeHuman fits clothes to bodies and close to what
Blender's Surface Deform does; here it places the transferred garment on the target body.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .gradients import inverse_3x3, triangle_frames
from .mesh import cross_rows
from .proximity import TriangleSurface


@dataclass
class Binding:
    """Points bound to a body.

    Attributes
    ----------
    triangle : (p,) int64
    bary : (p,3) float64
    local : (p,3) float64
        The offset from the surface point in the triangle's frame.
    distance : (p,) float64
        Distance from the surface at binding time.
    """

    triangle: np.ndarray
    bary: np.ndarray
    local: np.ndarray
    distance: np.ndarray
    _linear: tuple | None = field(default=None, repr=False, compare=False)

    def linear_part(self, body_F, n_vertices):
        """The part of ``carry`` that is linear in the body's vertices, as a sparse (p, n) matrix.

        A bound point is ``sum_k bary_k x_k + l1 (x2 - x1) + l2 (x3 - x1) + l3 n`` over the corners
        x1, x2, x3 of its triangle: every term but the normal's is a fixed combination of three body
        vertices, so it is built once per binding (kept for the last body triangles it was asked for)
        and every shape of the body is then one sparse product.
        """
        if self._linear is not None and self._linear[0] is body_F and self._linear[1] == n_vertices:
            return self._linear[2]
        tri, off = self.triangle, self.local
        w = self.bary.copy()
        w[:, 0] -= off[:, 0] + off[:, 1]
        w[:, 1] += off[:, 0]
        w[:, 2] += off[:, 1]
        p = tri.shape[0]
        M = sp.csr_matrix((w.reshape(-1), body_F[tri].reshape(-1), np.arange(0, 3 * p + 1, 3)),
                          shape=(p, n_vertices))
        self._linear = (body_F, n_vertices, M)
        return M


def bind(points, body_V, body_F, surface=None) -> Binding:
    """Bind points to the body surface (V, F).

    Parameters
    ----------
    points : (p,3) float
    body_V : (n,3) float
    body_F : (m,3) int
    surface : TriangleSurface, optional
        The body prepared for queries, to reuse.
    """
    surface = surface or TriangleSurface(body_V, body_F)
    points = np.asarray(points, dtype=np.float64)
    closest, dist, tri, bary = surface.closest(points)
    X, _ = triangle_frames(body_V, body_F[tri])
    Xinv, det = inverse_3x3(X)
    local = np.einsum("pij,pj->pi", Xinv, points - closest)
    local[~np.isfinite(local).all(axis=1) | (np.abs(det) == 0)] = 0.0
    return Binding(tri, bary, local, dist)


def carry(binding: Binding, body_V, body_F):
    """Positions of bound points on another shape (same topology) of the body.

    Parameters
    ----------
    binding : Binding
    body_V : (n,3) float
        The body in its new shape.
    body_F : (m,3) int
        The body's triangles (as used for binding).

    Returns
    -------
    P : (p,3) float64
    """
    body_V = np.asarray(body_V, dtype=np.float64)
    tri = binding.triangle
    P = binding.linear_part(body_F, body_V.shape[0]) @ body_V
    # The scaled normals (``triangle_frames``), once per body triangle when there are more points
    # than triangles.
    many = tri.shape[0] > body_F.shape[0]
    F = body_F if many else body_F[tri]
    x1 = body_V[F[:, 0]]
    c = cross_rows(body_V[F[:, 1]] - x1, body_V[F[:, 2]] - x1)
    dbl = np.linalg.norm(c, axis=1)
    n = np.divide(c, np.sqrt(dbl)[:, None], out=np.zeros_like(c), where=dbl[:, None] > 0)
    P += binding.local[:, 2:] * (n[tri] if many else n)
    return P


def follow_nearest_vertex(points, body_V, body_V_new):
    """Points moved by the displacement of their nearest body vertex (a coarse, fast way to follow a body
    that changes shape: Blender's cloth solver uses it for pinned vertices).

    Parameters
    ----------
    points : (p,3) float
    body_V, body_V_new : (n,3) float
        The body's vertices before and after (same vertex order).

    Returns
    -------
    P : (p,3) float64
    """
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=np.float64)
    if points.shape[0] == 0:
        return points.copy()
    body_V = np.asarray(body_V, dtype=np.float64)
    _, idx = cKDTree(body_V).query(points)
    return points + (np.asarray(body_V_new, dtype=np.float64)[idx] - body_V[idx])
