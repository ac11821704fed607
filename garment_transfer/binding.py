"""Points bound to a body surface, carried to another shape of the same body.

Each garment vertex is bound to its closest point on the source body (triangle and barycentric
coordinates) plus its offset, expressed in that triangle's frame ``[e1 e2 n]``. On a target body of
the same topology the point is rebuilt from the same triangle's frame: the offset turns, stretches
and scales with the body under it. This is how MakeHuman fits clothes to bodies and close to what
Blender's Surface Deform does; here it places the transferred garment on the target body.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gradients import inverse_3x3, triangle_frames
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
    tris = body_F[binding.triangle]
    surface_point = np.einsum("pk,pkj->pj", binding.bary, body_V[tris])
    Y, _ = triangle_frames(body_V, tris)
    return surface_point + np.einsum("pij,pj->pi", Y, binding.local)


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
